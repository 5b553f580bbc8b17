"""Acceptance against the specimen's design values: K_eff, EDC and xi_eff of each level, within the tolerances
the lab sets per protocol (EN 15129's type-test tolerances when it has set none), with a verdict per level.

The design values of a level are the specimen's declared model (the isolator the test was created with, its
Bouc-Wen parameters as recorded in the scenario) driven through the level's target: the mean of its test cycles
(``sim.protocols.nominal_cycles``). Each measured test cycle is judged against them (``individual`` tolerance)
and so is the mean of the level's measured test cycles (``mean`` tolerance). SI units throughout.
"""

from __future__ import annotations

import json
import math

# EN 15129 type tests of elastomeric (lead-rubber) isolators, as this project reads them: each specimen's
# effective stiffness and damping within +-15 % of the design values, the mean within +-10 % (docs/reports.md)
EN15129_TYPE_TEST = {"k_eff": 0.15, "edc": 0.15, "xi_eff": 0.15, "mean": 0.10}
DEFAULT_SOURCE = "EN 15129 type test (shipped default)"
# the judged quantities: per-cycle key, tolerance key, name
QUANTITIES = (("k_eff_n_per_m", "k_eff", "K_eff"), ("edc_j", "edc", "EDC"), ("xi_eff", "xi_eff", "xi_eff"))
TOLERANCE_KEYS = ("k_eff", "edc", "xi_eff", "mean")
MAX_TOLERANCE = 1.0
_NOMINAL: dict = {}  # the last design values made: (protocol, isolator) -> per level


class ToleranceError(ValueError):
    """Tolerances that cannot be taken; ``field`` names the value."""

    def __init__(self, field: str, detail: str):
        super().__init__(detail)
        self.field = field


def tolerances_for(lab, protocol_name: str | None) -> dict:
    """The tolerances in force for a protocol: the lab's (``lab.tolerances``) or EN 15129's, with ``source``."""
    own = ((getattr(lab, "tolerances", None) or {}).get(protocol_name)) if protocol_name else None
    if own:
        return {**{k: float(own[k]) for k in TOLERANCE_KEYS}, "source": f"set by the lab for {protocol_name}"
                + (f" ({own['updated_by']}, {str(own.get('updated_at') or '')[:10]})" if own.get("updated_by") else "")}
    return {**EN15129_TYPE_TEST, "source": DEFAULT_SOURCE}


def check_tolerances(values: dict) -> dict:
    """The four fractions (each > 0 and <= 1), or ToleranceError naming the one that is not."""
    out = {}
    for key in TOLERANCE_KEYS:
        v = values.get(key)
        if not isinstance(v, (int, float)) or isinstance(v, bool) or not math.isfinite(v) or not 0 < v <= MAX_TOLERANCE:
            raise ToleranceError(key, f"{key} must be a fraction above 0 and at most {MAX_TOLERANCE:g} (0.15 is "
                                      f"+-15 %), not {v!r}")
        out[key] = float(v)
    return out


def stored_tolerances(session) -> dict:
    """The lab's tolerances by protocol, as the database holds them."""
    from sqlalchemy import select

    from ..models import AcceptanceTolerance

    return {t.protocol: {"k_eff": t.k_eff_fraction, "edc": t.edc_fraction, "xi_eff": t.xi_eff_fraction,
                         "mean": t.mean_fraction, "updated_by": t.updated_by,
                         "updated_at": t.updated_at.isoformat() if t.updated_at else None}
            for t in session.scalars(select(AcceptanceTolerance))}


def with_tolerances(session, lab):
    """``lab`` (a LabHeader) with the lab's tolerances from the database."""
    from dataclasses import replace

    return replace(lab, tolerances=stored_tolerances(session))


def set_tolerances(session, protocol: str, values: dict | None, by: str) -> None:
    """Set a protocol's tolerances (fractions), or with None go back to EN 15129's."""
    from ..models import AcceptanceTolerance, utcnow

    row = session.get(AcceptanceTolerance, protocol)
    if values is None:
        if row is not None:
            session.delete(row)
        return
    v = check_tolerances(values)
    if row is None:
        row = AcceptanceTolerance(protocol=protocol)
        session.add(row)
    row.k_eff_fraction, row.edc_fraction, row.xi_eff_fraction, row.mean_fraction = (v["k_eff"], v["edc"],
                                                                                   v["xi_eff"], v["mean"])
    row.updated_at, row.updated_by = utcnow(), by


def design_values(protocol, isolator) -> list[dict]:
    """Per level: the declared model's K_eff, EDC and xi_eff, the mean of its test cycles at that level."""
    key = (json.dumps(protocol.to_dict(), sort_keys=True, default=str),
           json.dumps(isolator.to_dict(), sort_keys=True, default=str))
    if _NOMINAL.get("key") == key:
        return _NOMINAL["values"]
    from sim.protocols import nominal_cycles

    nominal = {c["cycle"]: c for c in nominal_cycles(protocol, isolator)}
    out = []
    for i, lv in enumerate(protocol.levels, start=1):
        test = [nominal.get(p["cycle"]) for p in protocol.cycle_plan() if p["level"] == i and p["test"]]
        test = [c for c in test if c is not None]
        values = {}
        for q, _k, _n in QUANTITIES:
            xs = [c[q] for c in test if isinstance(c.get(q), (int, float)) and math.isfinite(c[q])]
            values[q] = sum(xs) / len(xs) if xs else None
        out.append({"level": i, "label": lv.label, "amplitude_m": lv.amplitude_m, "frequency_hz": lv.frequency_hz,
                    **values})
    _NOMINAL.update(key=key, values=out)
    return out


def _check(value, design, tolerance) -> tuple[float | None, str]:
    if value is None or design is None or not math.isfinite(value) or design == 0:
        return None, "missing"
    dev = value / design - 1.0
    return dev, "pass" if abs(dev) <= tolerance else "fail"


def design_acceptance(protocol, cycles: list[dict], isolator, tolerances: dict) -> dict:
    """Every level's test cycles (steady metrics, matched by time as sim.protocols does) and their mean against
    the design values; a verdict per level (PASSED, FAILED, INCOMPLETE: some test cycles not measured, NOT
    REACHED: none) and ``passed`` over all (None without design values)."""
    from sim.protocols import _match  # the same matching of measured to planned cycles as the rules

    tol = {k: tolerances[k] for k in TOLERANCE_KEYS}
    base = {"tolerances": tol, "source": tolerances.get("source"), "basis": "the declared isolator model "
            "(its Bouc-Wen parameters as recorded with the test) through each level's target"}
    if isolator is None:
        return {**base, "levels": [], "passed": None, "note": "no design values: the isolator model is not known"}
    design = design_values(protocol, isolator)
    plan = protocol.cycle_plan()
    measured = _match(plan, cycles)
    levels = []
    for d in design:
        tests = [p for p in plan if p["level"] == d["level"] and p["test"]]
        checks, means, mean_checks = [], {}, []
        got = [measured.get(p["cycle"]) for p in tests]
        for q, key, name in QUANTITIES:
            for p, m in zip(tests, got, strict=True):
                value = None if m is None else m.get(q)
                dev, status = _check(value, d[q], tol[key])
                checks.append({"quantity": q, "name": name, "level_cycle": p["level_cycle"], "cycle": p["cycle"],
                               "value": value, "design": d[q], "deviation_fraction": dev,
                               "tolerance_fraction": tol[key], "status": status})
            xs = [m[q] for m in got if m is not None and isinstance(m.get(q), (int, float)) and math.isfinite(m[q])]
            means[q] = sum(xs) / len(xs) if xs else None
            dev, status = _check(means[q], d[q], tol["mean"])
            if status == "pass" and len(xs) < len(tests):
                status = "missing"  # a mean of fewer cycles than planned is not the level's mean
            mean_checks.append({"quantity": q, "name": name, "value": means[q], "design": d[q], "cycles": len(xs),
                                "deviation_fraction": dev, "tolerance_fraction": tol["mean"], "status": status})
        n_measured = sum(1 for m in got if m is not None)
        every = checks + mean_checks
        if n_measured == 0:
            verdict = "NOT REACHED"
        elif any(c["status"] == "fail" for c in every):
            verdict = "FAILED"
        elif any(c["status"] == "missing" for c in every):
            verdict = "INCOMPLETE"
        else:
            verdict = "PASSED"
        levels.append({"level": d["level"], "label": d["label"], "amplitude_m": d["amplitude_m"],
                       "frequency_hz": d["frequency_hz"], "design": {q: d[q] for q, _k, _n in QUANTITIES},
                       "measured_mean": means, "test_cycles": len(tests), "measured_cycles": n_measured,
                       "checks": checks, "mean_checks": mean_checks, "verdict": verdict,
                       "failed": sum(1 for c in every if c["status"] == "fail"),
                       "missing": sum(1 for c in every if c["status"] == "missing")})
    passed = all(lv["verdict"] == "PASSED" for lv in levels) if levels else None
    return {**base, "levels": levels, "passed": passed}
