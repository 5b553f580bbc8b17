"""What a report says, shared by the PDF and report.json: controller state, tracking, headline figures (steady
cycles only), acceptance verdicts and the whole JSON (``report_json``). Numerics come from sim/ (metrics,
protocols, identification); nothing is recomputed here that sim/ provides.
"""

from __future__ import annotations

from datetime import UTC, datetime

import numpy as np

from .data import (
    ESTIMATE_COLUMNS,
    clean_json,
    earthquake_kind,
    earthquake_of,
    event_text,
    isolator_of,
    protocol_of,
    rig_of,
    run_of,
    tracking_verdict_of,
)
from .identification import identified_bouc_wen

STEADY = "steady"  # sim.tracking.STEADY (not imported here: sim.tracking imports the rig model and numba)


def _last_finite(column: np.ndarray):
    finite = np.nonzero(np.isfinite(column))[0]
    return float(column[finite[-1]]) if finite.size else None


def protocol_acceptance(record: dict, cycles: list[dict], lab=None) -> dict | None:
    """A protocol test's acceptance (``acceptance``, with the check against the design values under the lab's
    tolerances: ``lab.tolerances``) and each level's figures (``levels``, from ``headline``) from its record and
    stored cycles alone (no samples needed), or None for a test that did not run a protocol."""
    from .data import ReportBundle
    from .design import tolerances_for

    protocol, _note = protocol_of(record)
    if protocol is None:
        return None
    bundle = ReportBundle(record=record, samples=np.empty((0, 0)), cycles=cycles)
    out = acceptance(bundle, run_of(bundle), tolerances_for(lab, protocol.name))
    out["levels"] = headline(bundle, protocol)["levels"]
    return out


def controller_state(bundle) -> dict:
    """Controller name, the options the test set, every option in force (value, unit, meaning: sim.controllers
    OPTIONS) and what it adapts under the names and units it declares (sim.controllers ADAPTED) with the final
    values (the last finite ar_hat, ay_hat, as_hat)."""
    record = bundle.record
    scenario = record.get("scenario") or {}
    s = bundle.samples
    adapted = {}
    if len(s):
        for column in ESTIMATE_COLUMNS:
            value = _last_finite(s[column])
            if value is not None:
                adapted[column] = value
    name = record.get("controller") or scenario.get("controller")
    options = scenario.get("controller_options") or {}
    in_force = scenario.get("controller_options_in_force") or options
    parameters = {}
    specs, declared = {}, ()
    if name:
        try:  # the controller's effective parameters: its defaults overridden by the test's options
            from sim.controllers import ADAPTED, DESIGNED, OPTIONS, make_controller
            from sim.rig import DEFAULT_RIG

            specs = {**OPTIONS.get(name, {}), **DESIGNED.get(name, {})}
            declared = ADAPTED.get(name, ())
            rig = DEFAULT_RIG.with_changes(**(scenario.get("rig_changes") or {}))  # the lab's rig, as the test ran
            parameters = {k: v for k, v in make_controller(name, rig=rig, **in_force).options.items()
                          if isinstance(v, (int, float, str, bool))}
        except (ImportError, ValueError, TypeError):
            parameters = {}
    options_in_force = [{"name": k, "value": v, "unit": specs[k].unit if k in specs else None,
                         "set_for_test": k in options, "meaning": specs[k].meaning if k in specs else ""}
                        for k, v in parameters.items()]
    adapted_out = [{"column": a.column, "name": a.name, "unit": a.unit, "meaning": a.meaning,
                    "final": adapted.get(a.column)} for a in declared if a.column in ESTIMATE_COLUMNS]
    labels = {a["column"]: f"{a['name']} ({a['unit']})" for a in adapted_out}
    return {"name": name, "options": options, "parameters": parameters, "options_in_force": options_in_force,
            "adapted": adapted_out, "final_adapted": adapted,
            "adapted_labels": {k: labels[k] for k in adapted if k in labels}}


def steady_cycles(cycles: list[dict]) -> list[dict]:
    """The cycles at the block's amplitude (sim.tracking's phase ``steady``; a cycle without a phase counts)."""
    return [c for c in cycles if c.get("phase", STEADY) == STEADY]


def headline(bundle, protocol=None) -> dict:
    """The headline figures (sim.metrics.headline_figures: means over the steady cycles, the cycles left out by
    phase) and, for a protocol, the same per level."""
    from sim.metrics import headline_figures

    metrics = [{k: v for k, v in c.items() if k not in ("displacement_m", "force_n")} for c in bundle.cycles]
    out = headline_figures(metrics)
    out["cycles"] = len(metrics)
    out["phases_known"] = any("phase" in c for c in metrics) or not metrics
    if protocol is not None:
        level_of = {p["cycle"]: p["level"] for p in protocol.cycle_plan()}
        out["levels"] = []
        for i, lv in enumerate(protocol.levels, start=1):
            of_level = [c for c in metrics if level_of.get(c.get("cycle")) == i]
            figures = headline_figures(of_level)
            out["levels"].append({"level": i, "label": lv.label, "amplitude_m": lv.amplitude_m,
                                  "frequency_hz": lv.frequency_hz, "cycles": len(of_level), **figures})
    return out


def acceptance(bundle, run: dict | None = None, tolerances: dict | None = None) -> dict:
    """Verdicts of the test's protocol (sim.protocols.evaluate_acceptance) on the steady cycles only (a taper or
    the ramp-out of a stop is never judged as a test cycle), their summary, the check against the specimen's
    design values with a verdict per level (``design``: design.design_acceptance under ``tolerances``, default
    EN 15129's), and the verdict in one word over both: PASSED, FAILED, INCOMPLETE (the test ended before its
    end: checks without a measured cycle) or NO VERDICT."""
    protocol, note = protocol_of(bundle.record)
    if protocol is None:
        kind = earthquake_kind(bundle.record)
        if kind is not None and not note:
            note = (f"no acceptance rules: a {'time history' if kind == 'history' else 'hybrid simulation'} is "
                    "judged by the J criteria against their targets (the results and the criteria page)")
        return {"protocol": None, "note": note or "no acceptance rules: the test ran a plain sine profile",
                "summary": {"passed": None, "verdicts": 0, "failed": 0, "failed_rules": []}, "verdicts": [],
                "verdict": "NO VERDICT"}
    from sim.protocols import acceptance_summary, evaluate_acceptance

    from .design import design_acceptance, tolerances_for

    metrics = [{k: v for k, v in c.items() if k not in ("displacement_m", "force_n")}
               for c in steady_cycles(bundle.cycles)]
    verdicts = evaluate_acceptance(protocol, metrics, isolator=isolator_of(bundle.record))
    plan = protocol.cycle_plan()
    rules = {r.name: r for r in protocol.rules}
    for v in verdicts:  # the cycle each reference value came from
        rule = rules.get(v["rule"])
        if rule is not None and rule.reference == "cycle":
            ref = next((p for p in plan if p["level"] == v["level"] and p["level_cycle"] == rule.reference_cycle),
                       None)
            v["reference_cycle"] = ref["cycle"] if ref else None
        else:
            v["reference_cycle"] = None
    summary = acceptance_summary(verdicts)
    missing = sum(1 for v in verdicts if v["status"] == "missing")
    design = design_acceptance(protocol, metrics, isolator_of(bundle.record),
                               tolerances or tolerances_for(None, protocol.name))
    design_missing = sum(lv["missing"] for lv in design["levels"])
    passed = summary["passed"]
    if design["passed"] is not None:
        passed = design["passed"] if passed is None else (passed and design["passed"])
    ended_early = bool(run and run.get("ended_early"))
    if passed is None:
        word = "NO VERDICT"
    elif passed:
        word = "PASSED"
    elif ended_early and (missing or design_missing):
        word = "INCOMPLETE"
    else:
        word = "FAILED"
    return {"protocol": protocol.name, "title": protocol.title, "rules": [r.text() for r in protocol.rules],
            "rule_names": [r.name for r in protocol.rules],
            "rule_details": [{"name": r.name, "text": r.text(), "description": r.description,
                              "quantity": r.quantity, "reference": r.reference,
                              "reference_cycle": r.reference_cycle if r.reference == "cycle" else None,
                              "tolerance_fraction": r.tolerance_fraction,
                              "levels": list(r.levels) if r.levels else None,
                              "passed": sum(1 for v in verdicts if v["rule"] == r.name and v["passed"]),
                              "checks": sum(1 for v in verdicts if v["rule"] == r.name)} for r in protocol.rules],
            "summary": summary, "verdicts": verdicts, "verdict": word, "design": design,
            "checks_missing": missing, "judged_on": "steady cycles only"}


def tracking(bundle) -> dict:
    """|y - r| over the closed-loop rows (sim.tracking.closed_loop_error)."""
    from sim.tracking import closed_loop_error

    return closed_loop_error(bundle.samples) if len(bundle.samples) else {}


REFERENCE_NOTE = ("the reference is computed when this report is made (sim.hybrid.reference: the same building "
                  "with the isolator's nominal Bouc-Wen model, RK4 offline), not stored with the test")
_FIGURES: dict = {}  # the last earthquake figures made (the JSON and the PDF of one report share them)


def earthquake_figures(bundle) -> dict | None:
    """A history or hybrid test's figures with the arrays its pages plot (sim.earthquake.record_figures on the
    samples: J1-J3 and, for a hybrid test, the structure replayed from the record against the reference computed
    now, J4-J5, the stability monitor), or None for another test. ``note`` says what could not be done."""
    record = bundle.record
    kind = earthquake_kind(record)
    if kind is None or not len(bundle.samples):
        return None
    key = (id(bundle.samples), len(bundle.samples), record.get("id"), kind)
    if _FIGURES.get("key") == key:
        return _FIGURES["figures"]
    from sim.earthquake import early_end_time_s, record_figures

    profile, note = earthquake_of(record)
    summary = record.get("summary") or {}
    iso = isolator_of(record)
    if kind == "hybrid" and (profile is None or iso is None):
        figures = {"kind": kind, "criteria": {}, "verdicts": [], "note": note or "the isolator is not known",
                   "stored": {k: summary.get(k) for k in ("criteria", "stability") if summary.get(k) is not None}}
    else:
        try:
            figures = record_figures(profile, iso, bundle.samples, kind=kind,
                                     end_time_s=early_end_time_s(bundle.events), stability=summary.get("stability"),
                                     arrays=True)
        except ValueError as exc:  # e.g. too short, non-finite
            figures = {"kind": kind, "criteria": {}, "verdicts": [], "note": f"no criteria: {exc}"}
        if note:
            figures["note"] = note
        if kind == "hybrid":
            figures["reference"] = {**figures.get("reference", {}), "note": REFERENCE_NOTE}
    if profile is not None:
        figures["profile"] = profile.description
    elif isinstance(record.get("profile"), dict):
        figures["profile"] = record["profile"]
    _FIGURES.update(key=key, figures=figures)
    return figures


def earthquake(bundle) -> dict | None:
    """report.json's ``earthquake``: the figures of ``earthquake_figures`` without the arrays."""
    figures = earthquake_figures(bundle)
    if figures is None:
        return None
    return {k: v for k, v in figures.items() if k != "arrays"}


def report_json(bundle, identify: bool = True, meta: dict | None = None, identification: dict | None = None,
                lab=None) -> dict:
    """All metrics of a test: header, what it ran, headline figures, per-cycle metrics, acceptance,
    identification, tracking, events (with their text), the approval block.

    ``identify=False`` skips the Bouc-Wen fit (the slowest part: seconds); ``identification`` is one already
    made (identified_bouc_wen's answer). ``meta`` (rig, operator, source) fills in what the record does not
    hold; ``lab`` (lab.LabHeader) is the issuing lab (default: lab_header from ``meta`` and the settings).
    """
    from .design import tolerances_for
    from .lab import lab_header

    meta = meta or {}
    if lab is None:
        lab = lab_header(meta.get("lab_name") or meta.get("lab"), meta.get("lab_address"), meta.get("lab_logo_file"))
    record = {**bundle.record, **{k: v for k, v in meta.items() if v and not k.startswith("lab")}}
    bundle = _with_record(bundle, record)
    cycles = [{k: v for k, v in c.items() if k not in ("displacement_m", "force_n")} for c in bundle.cycles]
    iso = isolator_of(record)
    protocol, _note = protocol_of(record)
    run = run_of(bundle)
    events = [{**e, "text": event_text(e, lab.unit_system)} for e in bundle.events]  # in the lab's units
    out = {
        "report_version": 2,
        "generated_at": datetime.now(UTC).isoformat(timespec="seconds"),
        "lab": lab.to_json(),
        "test": {k: record.get(k) for k in ("id", "label", "status", "reason", "specimen_id", "operator_name",
                                            "notes", "created_at", "started_at", "ended_at", "isolator",
                                            "supply_bar", "vertical_load_n", "controller", "speed", "driver",
                                            "profile", "limits", "duration_s", "time_s", "cycles_total",
                                            "cycles_done", "samples_stored", "archived", "rig", "operator",
                                            "source")
                 if k in record},
        "run": run,
        "rig": rig_of(record),
        "isolator_nominal": iso.to_dict() if iso else None,
        "controller": controller_state(bundle),
        "tracking": tracking(bundle),
        "tracking_verdict": tracking_verdict_of(record),
        "earthquake": earthquake(bundle),
        "headline": headline(bundle, protocol),
        "cycles": cycles,
        "acceptance": acceptance(bundle, run, tolerances_for(lab, protocol.name if protocol else None)),
        "identification": identification if identification is not None else identified_bouc_wen(bundle)
        if identify else {"available": False, "nominal": iso.to_dict() if iso else None,
                          "note": "identification not requested"},
        "events": events,
        "limit_trips": [e for e in events if e.get("kind") == "limit_trip"],
        "limit_indications": (record.get("summary") or {}).get("limit_indications") or {},
        "approval": approval_of(bundle),
        "software": {"isorig": _version()},
    }
    return clean_json(out)


def _version() -> str | None:
    try:
        from importlib.metadata import version

        return version("isorig")
    except Exception:  # not installed as a package (a source tree on PYTHONPATH)
        return None


def _with_record(bundle, record: dict):
    if record is bundle.record:
        return bundle
    from .data import ReportBundle

    return ReportBundle(record=record, samples=bundle.samples, cycles=bundle.cycles, events=bundle.events)


def approval_of(bundle) -> dict:
    """Who tested, reviewed and approved the record, when, and the SHA-256 it was approved with (backend.review):
    the report's approval block. Before an approval only the operator is filled in."""
    record = bundle.record
    review = record.get("review") or {}
    approved = review.get("state") == "approved"
    by, at = (review.get("by"), review.get("at")) if approved else (None, None)
    return {"tested_by": operator_of(bundle), "tested_at": record.get("started_at"),
            "reviewed_by": by, "reviewed_at": at, "approved_by": by, "approved_at": at,
            "state": review.get("state") or "unreviewed", "note": review.get("note"),
            "record_sha256": review.get("record_sha256") if approved else None, "started_by": starter_of(bundle)}


def operator_of(bundle) -> str | None:
    """Who ran the test, by name: the record's operator_name, else a name given for the report (``operator``).
    None when neither is there (the actor of the start event is the token's holder, not a person's name)."""
    r = bundle.record
    for key in ("operator_name", "operator"):
        if r.get(key):
            return str(r[key])
    return None


def starter_of(bundle) -> str | None:
    """The actor of the test's start event (what the service knows when no operator name was recorded)."""
    for e in bundle.events:
        if e.get("kind") == "operator" and (e.get("values") or {}).get("action") == "start" and e.get("actor"):
            return str(e["actor"])
    return None
