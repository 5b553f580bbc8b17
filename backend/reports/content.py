"""What a report says, shared by the PDF and report.json: controller state, tracking, acceptance verdicts and
the whole JSON (``report_json``). Numerics come from sim/ (metrics, protocols, identification); nothing is
recomputed here that sim/ provides.
"""

from __future__ import annotations

from datetime import UTC, datetime

import numpy as np

from .data import clean_json, isolator_of, limit_trips, num, protocol_of
from .identification import identified_bouc_wen


def _last_finite(column: np.ndarray):
    finite = np.nonzero(np.isfinite(column))[0]
    return float(column[finite[-1]]) if finite.size else None


def controller_state(bundle) -> dict:
    """Controller name, options and the final adapted parameters (last finite ar_hat, ay_hat, as_hat)."""
    record = bundle.record
    scenario = record.get("scenario") or {}
    s = bundle.samples
    adapted = {}
    if len(s):
        for name in ("ar_hat", "ay_hat", "as_hat"):
            value = _last_finite(s[name])
            if value is not None:
                adapted[name] = value
    name = record.get("controller") or scenario.get("controller")
    options = scenario.get("controller_options") or {}
    parameters = {}
    if name:
        try:  # the controller's effective parameters: its defaults overridden by the test's options
            from sim.controllers import make_controller

            parameters = {k: v for k, v in make_controller(name, **options).options.items()
                          if isinstance(v, (int, float, str, bool))}
        except (ImportError, ValueError, TypeError):
            parameters = {}
    try:
        from sim.controllers import ADAPTED_LABELS

        labels = ADAPTED_LABELS.get(name, {})
    except ImportError:
        labels = {}
    return {"name": name, "options": options, "parameters": parameters, "final_adapted": adapted,
            "adapted_labels": {k: labels[k] for k in adapted if k in labels}}


def acceptance(bundle) -> dict:
    """Verdicts of the test's protocol (sim.protocols.evaluate_acceptance) and their summary."""
    protocol, note = protocol_of(bundle.record)
    if protocol is None:
        return {"protocol": None, "note": note or "no acceptance rules: the test ran a plain sine profile",
                "summary": {"passed": None, "verdicts": 0, "failed": 0, "failed_rules": []}, "verdicts": []}
    from sim.protocols import acceptance_summary, evaluate_acceptance

    metrics = [{k: v for k, v in c.items() if k not in ("displacement_m", "force_n")} for c in bundle.cycles]
    verdicts = evaluate_acceptance(protocol, metrics, isolator=isolator_of(bundle.record))
    return {"protocol": protocol.name, "title": protocol.title, "rules": [r.text() for r in protocol.rules],
            "rule_names": [r.name for r in protocol.rules], "summary": acceptance_summary(verdicts),
            "verdicts": verdicts}


def tracking(bundle) -> dict:
    s = bundle.samples
    if not len(s):
        return {}
    closed = np.isfinite(s["target_m"])  # the three columns only: copying whole rows cost 0.35 s at 600 000
    if not closed.any():
        return {}
    e = s["displacement_m"][closed] - s["target_m"][closed]
    u = s["voltage_v"][closed]
    return {"rms_y_minus_r_m": float(np.sqrt(np.mean(e * e))), "peak_abs_y_minus_r_m": float(np.max(np.abs(e))),
            "peak_abs_voltage_v": num(float(np.nanmax(np.abs(u)))) if np.isfinite(u).any() else None}


def report_json(bundle, identify: bool = True, meta: dict | None = None, identification: dict | None = None) -> dict:
    """All metrics of a test: header, per-cycle metrics, acceptance, identification, tracking, events.

    ``identify=False`` skips the Bouc-Wen fit (the slowest part: seconds); ``identification`` is one already
    made (identified_bouc_wen's answer). ``meta`` (lab, rig, operator) fills in what the record does not hold.
    """
    record = {**bundle.record, **{k: v for k, v in (meta or {}).items() if v}}
    cycles = [{k: v for k, v in c.items() if k not in ("displacement_m", "force_n")} for c in bundle.cycles]
    iso = isolator_of(record)
    out = {
        "report_version": 1,
        "generated_at": datetime.now(UTC).isoformat(timespec="seconds"),
        "test": {k: record.get(k) for k in ("id", "label", "status", "reason", "created_at", "started_at",
                                            "ended_at", "isolator", "supply_bar", "controller", "profile",
                                            "duration_s", "samples_stored", "lab", "rig", "operator", "source")
                 if k in record},
        "isolator_nominal": iso.to_dict() if iso else None,
        "controller": controller_state(bundle),
        "tracking": tracking(bundle),
        "cycles": cycles,
        "acceptance": acceptance(bundle),
        "identification": identification if identification is not None else identified_bouc_wen(bundle)
        if identify else {"available": False, "nominal": iso.to_dict() if iso else None,
                          "note": "identification not requested"},
        "events": bundle.events,
        "limit_trips": limit_trips(bundle.events),
    }
    return clean_json(out)
