"""Test protocols: a sequence of sine levels with acceptance rules, kept as editable data (JSON or TOML).

A protocol has a design displacement and levels (e.g. 3 cycles at each of 0.25, 0.5, 0.67 and 1.0 of it, in
the spirit of EN 15129 type tests). Each level becomes one ``SineProfile`` block: ``taper_cycles`` ramp cycles,
the level's test cycles, ``taper_cycles`` ramp cycles. Only test cycles are judged. Acceptance rules are
tolerances on a per-cycle quantity of ``sim.metrics`` against

- ``"cycle"``: the same level's N-th test cycle (``reference_cycle``, e.g. the 3rd);
- ``"value"``: nominal values written in the protocol (``value``, or ``values`` with one per level);
- ``"isolator"``: the isolator's nominal Bouc-Wen model (eq. 4) run through the same displacement profile.

Shipped protocols live in ``sim/protocol_data/`` (package data). The file format is in docs/metrics.md.
"""

from __future__ import annotations

import json
import math
import re
import tomllib
from dataclasses import asdict, dataclass, replace
from pathlib import Path

import numpy as np

from .metrics import METRIC_KEYS, cycle_metrics
from .profiles import SineProfile

DATA_DIR = Path(__file__).with_name("protocol_data")
SHIPPED_PROTOCOLS: tuple[str, ...] = tuple(sorted(p.stem for p in DATA_DIR.glob("*.json")))

QUANTITIES = tuple(k for k in METRIC_KEYS) + ("f_peak_max_n", "f_peak_min_n")
REFERENCES = ("cycle", "value", "isolator")
NAME_PATTERN = re.compile(r"^[A-Za-z0-9_.\-]{1,64}$")
PROTOCOL_FIELDS = {"name", "title", "description", "design_displacement_m", "frequency_hz", "taper_cycles",
                   "levels", "acceptance"}
LEVEL_FIELDS = {"fraction", "amplitude_m", "cycles", "frequency_hz", "taper_cycles", "label"}
RULE_FIELDS = {"name", "quantity", "reference", "tolerance_fraction", "reference_cycle", "value", "values",
               "levels", "description"}
MAX_LEVELS = 50
MAX_CYCLES = 1000


class ProtocolError(ValueError):
    """A protocol definition is malformed; ``field`` names the offending field."""

    def __init__(self, field: str, message: str):
        super().__init__(message)
        self.field = field


@dataclass(frozen=True)
class Level:
    """One amplitude level: ``cycles`` test cycles between ``taper_cycles`` ramp cycles on each side."""

    amplitude_m: float
    frequency_hz: float
    cycles: int
    taper_cycles: int
    fraction: float | None = None
    label: str = ""

    @property
    def block(self) -> SineProfile:
        return SineProfile(self.amplitude_m, self.frequency_hz, self.cycles + 2 * self.taper_cycles,
                           self.taper_cycles)


@dataclass(frozen=True)
class Rule:
    """Tolerance on a per-cycle quantity: |value / reference - 1| <= tolerance_fraction."""

    name: str
    quantity: str
    reference: str
    tolerance_fraction: float
    reference_cycle: int = 3
    values: tuple[float | None, ...] | None = None
    levels: tuple[int, ...] | None = None  # 1-based levels the rule applies to (None: all)
    description: str = ""

    def applies_to(self, level: int) -> bool:
        return self.levels is None or level in self.levels

    def text(self) -> str:
        ref = {"cycle": f"the level's test cycle {self.reference_cycle}", "value": "the protocol's nominal value",
               "isolator": "the isolator's nominal model"}[self.reference]
        return f"{self.quantity} within +-{100 * self.tolerance_fraction:g} % of {ref}"


@dataclass(frozen=True)
class Protocol:
    name: str
    levels: tuple[Level, ...]
    rules: tuple[Rule, ...]
    design_displacement_m: float | None = None
    title: str = ""
    description: str = ""

    @property
    def blocks(self) -> list[SineProfile]:
        """The engine profile: one tapered sine block per level."""
        return [lv.block for lv in self.levels]

    @property
    def duration_s(self) -> float:
        return sum(b.duration_s for b in self.blocks)

    def cycle_plan(self) -> list[dict]:
        """Every target cycle: number (1-based), level (1-based), level_cycle (1-based test cycle, None in a
        taper), test (judged or not), t_start_s, t_end_s."""
        plan, t0, number = [], 0.0, 0
        for li, lv in enumerate(self.levels, start=1):
            period = 1.0 / lv.frequency_hz
            for k in range(lv.cycles + 2 * lv.taper_cycles):
                number += 1
                j = k - lv.taper_cycles + 1
                test = 1 <= j <= lv.cycles
                plan.append({"cycle": number, "level": li, "level_cycle": j if test else None, "test": test,
                             "t_start_s": t0 + k * period, "t_end_s": t0 + (k + 1) * period})
            t0 += (lv.cycles + 2 * lv.taper_cycles) * period
        return plan

    def cycle_starts_s(self) -> tuple[list[float], float]:
        """Start time of every target cycle and the protocol's end time (for sim.metrics.cycle_metrics)."""
        plan = self.cycle_plan()
        return [c["t_start_s"] for c in plan], (plan[-1]["t_end_s"] if plan else 0.0)

    def with_design_displacement(self, design_displacement_m: float) -> Protocol:
        """The same protocol scaled to another design displacement (levels given as fractions only)."""
        _number("design_displacement_m", design_displacement_m, 1e-5, 1.0, "m")
        levels = tuple(replace(lv, amplitude_m=lv.fraction * design_displacement_m) if lv.fraction is not None
                       else lv for lv in self.levels)
        return replace(self, levels=levels, design_displacement_m=float(design_displacement_m))

    def with_frequency(self, frequency_hz: float) -> Protocol:
        """The same protocol with every level at ``frequency_hz`` (EN 15129: the specimen's design frequency;
        the cycle plan and the acceptance follow it)."""
        _number("frequency_hz", frequency_hz, 0.0, 10.0, "Hz", lo_open=True)
        return replace(self, levels=tuple(replace(lv, frequency_hz=float(frequency_hz)) for lv in self.levels))

    def to_dict(self) -> dict:
        """The protocol as data, in the file format (round-trips through protocol_from_dict)."""
        out = {"name": self.name, "title": self.title, "description": self.description}
        if self.design_displacement_m is not None:
            out["design_displacement_m"] = self.design_displacement_m
        out["levels"] = []
        for lv in self.levels:
            d = {"cycles": lv.cycles, "frequency_hz": lv.frequency_hz, "taper_cycles": lv.taper_cycles}
            if lv.fraction is not None and self.design_displacement_m is not None:
                d["fraction"] = lv.fraction
            else:
                d["amplitude_m"] = lv.amplitude_m
            if lv.label:
                d["label"] = lv.label
            out["levels"].append(d)
        out["acceptance"] = []
        for r in self.rules:
            d = {k: v for k, v in asdict(r).items() if v is not None and v != ""}
            if r.reference != "cycle":
                d.pop("reference_cycle", None)
            for key in ("values", "levels"):
                if key in d:
                    d[key] = list(d[key])
            out["acceptance"].append(d)
        return out


# --- parsing and validation ---

def _number(field, value, lo, hi, unit, integer=False, lo_open=False):
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise ProtocolError(field, f"{field} = {value!r} is not a finite number (unit {unit})")
    if integer and float(value) != int(value):
        raise ProtocolError(field, f"{field} = {value!r} must be a whole number")
    if not (lo < value <= hi if lo_open else lo <= value <= hi):
        bracket = "(" if lo_open else "["
        raise ProtocolError(field, f"{field} = {value:g} is outside the allowed range {bracket}{lo:g}, {hi:g}] {unit}")
    return int(value) if integer else float(value)


def _unknown(where: str, data: dict, allowed: set[str]) -> None:
    extra = sorted(set(data) - allowed)
    if extra:
        raise ProtocolError(f"{where}.{extra[0]}" if where else extra[0],
                            f"unknown field '{extra[0]}'{' in ' + where if where else ''}; "
                            f"allowed: {', '.join(sorted(allowed))}")


def _text(field, value, limit=400) -> str:
    if value is None:
        return ""
    if not isinstance(value, str):
        raise ProtocolError(field, f"{field} must be a string")
    return value[:limit]


def protocol_from_dict(data: dict) -> Protocol:
    """Validate a protocol given as data; raise ProtocolError naming the bad field."""
    if not isinstance(data, dict):
        raise ProtocolError("protocol", "a protocol must be a JSON object with 'name', 'levels' and 'acceptance'")
    _unknown("", data, PROTOCOL_FIELDS)
    name = data.get("name")
    if not isinstance(name, str) or not NAME_PATTERN.match(name):
        raise ProtocolError("name", f"name = {name!r} is invalid: use 1-64 letters, digits, '_', '-' or '.'")
    design = data.get("design_displacement_m")
    if design is not None:
        design = _number("design_displacement_m", design, 0.0, 1.0, "m", lo_open=True)
    frequency = _number("frequency_hz", data.get("frequency_hz", 0.5), 0.0, 10.0, "Hz", lo_open=True)
    taper = _number("taper_cycles", data.get("taper_cycles", 1), 0, 100, "cycles", integer=True)
    raw_levels = data.get("levels")
    if not isinstance(raw_levels, list) or not raw_levels:
        raise ProtocolError("levels", "levels must be a non-empty list of {fraction or amplitude_m, cycles}")
    if len(raw_levels) > MAX_LEVELS:
        raise ProtocolError("levels", f"levels has {len(raw_levels)} entries; at most {MAX_LEVELS} are allowed")
    levels = []
    for i, lv in enumerate(raw_levels, start=1):
        where = f"levels[{i}]"
        if not isinstance(lv, dict):
            raise ProtocolError(where, f"{where} must be an object with fraction or amplitude_m and cycles")
        _unknown(where, lv, LEVEL_FIELDS)
        if ("fraction" in lv) == ("amplitude_m" in lv):
            raise ProtocolError(where, f"{where} needs exactly one of fraction (of design_displacement_m) "
                                       "or amplitude_m")
        fraction = None
        if "fraction" in lv:
            if design is None:
                raise ProtocolError(f"{where}.fraction", f"{where} gives a fraction but the protocol has no "
                                                         "design_displacement_m")
            fraction = _number(f"{where}.fraction", lv["fraction"], 0.0, 2.0, "-", lo_open=True)
            amplitude = fraction * design
        else:
            amplitude = _number(f"{where}.amplitude_m", lv["amplitude_m"], 0.0, 1.0, "m", lo_open=True)
        cycles = _number(f"{where}.cycles", lv.get("cycles"), 1, MAX_CYCLES, "cycles", integer=True)
        levels.append(Level(
            amplitude_m=amplitude,
            frequency_hz=_number(f"{where}.frequency_hz", lv.get("frequency_hz", frequency), 0.0, 10.0, "Hz",
                                 lo_open=True),
            cycles=cycles,
            taper_cycles=_number(f"{where}.taper_cycles", lv.get("taper_cycles", taper), 0, 100, "cycles",
                                 integer=True),
            fraction=fraction,
            label=_text(f"{where}.label", lv.get("label"), 64),
        ))
    raw_rules = data.get("acceptance", [])
    if not isinstance(raw_rules, list):
        raise ProtocolError("acceptance", "acceptance must be a list of rules")
    rules, names = [], set()
    for i, r in enumerate(raw_rules, start=1):
        where = f"acceptance[{i}]"
        if not isinstance(r, dict):
            raise ProtocolError(where, f"{where} must be an object with name, quantity, reference, "
                                       "tolerance_fraction")
        _unknown(where, r, RULE_FIELDS)
        rname = r.get("name")
        if not isinstance(rname, str) or not NAME_PATTERN.match(rname) or rname in names:
            raise ProtocolError(f"{where}.name", f"{where}.name = {rname!r} must be a unique identifier "
                                                 "(letters, digits, '_', '-', '.')")
        names.add(rname)
        quantity = r.get("quantity")
        if quantity not in QUANTITIES:
            raise ProtocolError(f"{where}.quantity", f"{where}.quantity = {quantity!r}; allowed: "
                                                     f"{', '.join(QUANTITIES)}")
        reference = r.get("reference")
        if reference not in REFERENCES:
            raise ProtocolError(f"{where}.reference", f"{where}.reference = {reference!r}; allowed: "
                                                      f"{', '.join(REFERENCES)}")
        tol = _number(f"{where}.tolerance_fraction", r.get("tolerance_fraction"), 0.0, 10.0, "-", lo_open=True)
        rule_levels = None
        if r.get("levels") is not None:
            if not isinstance(r["levels"], list) or not r["levels"]:
                raise ProtocolError(f"{where}.levels", f"{where}.levels must be a non-empty list of level numbers")
            rule_levels = tuple(_number(f"{where}.levels", x, 1, len(levels), "level", integer=True)
                                for x in r["levels"])
        ref_cycle = 3
        if reference == "cycle":
            ref_cycle = _number(f"{where}.reference_cycle", r.get("reference_cycle", 3), 1, MAX_CYCLES, "cycle",
                                integer=True)
            for li, lv in enumerate(levels, start=1):
                if (rule_levels is None or li in rule_levels) and ref_cycle > lv.cycles:
                    raise ProtocolError(f"{where}.reference_cycle",
                                        f"{where}.reference_cycle = {ref_cycle} but level {li} has only "
                                        f"{lv.cycles} test cycles")
        values = None
        if reference == "value":
            if ("value" in r) == ("values" in r):
                raise ProtocolError(f"{where}.values", f"{where} with reference 'value' needs exactly one of "
                                                       "value (all levels) or values (one per level, null to skip)")
            if "value" in r:
                v = _number(f"{where}.value", r["value"], -1e12, 1e12, "(unit of the quantity)")
                values = tuple(v for _ in levels)
            else:
                if not isinstance(r["values"], list) or len(r["values"]) != len(levels):
                    raise ProtocolError(f"{where}.values", f"{where}.values must list one value per level "
                                                           f"({len(levels)}), null to skip a level")
                values = tuple(None if v is None else _number(f"{where}.values", v, -1e12, 1e12, "")
                               for v in r["values"])
        rules.append(Rule(rname, quantity, reference, tol, ref_cycle, values, rule_levels,
                          _text(f"{where}.description", r.get("description"))))
    return Protocol(name=name, levels=tuple(levels), rules=tuple(rules), design_displacement_m=design,
                    title=_text("title", data.get("title"), 200), description=_text("description",
                                                                                    data.get("description")))


def load_protocol(name_or_path: str | Path) -> Protocol:
    """A shipped protocol by name, or a protocol file (.json or .toml)."""
    key = str(name_or_path)
    if key in SHIPPED_PROTOCOLS:
        path = DATA_DIR / f"{key}.json"
    else:
        path = Path(key)
        if path.suffix not in (".json", ".toml") or not path.exists():
            raise ProtocolError("protocol", f"unknown protocol {key!r}: use one of {', '.join(SHIPPED_PROTOCOLS)} "
                                            "or a path to a .json or .toml file")
    try:
        text = path.read_text()
    except (OSError, UnicodeDecodeError) as exc:
        raise ProtocolError("protocol", f"cannot read protocol file {key}: {exc}") from None
    try:
        data = tomllib.loads(text) if path.suffix == ".toml" else json.loads(text)
    except json.JSONDecodeError as exc:
        raise ProtocolError("protocol", f"protocol file {key} is not valid JSON: {exc.msg} at line {exc.lineno}") \
            from None
    except tomllib.TOMLDecodeError as exc:
        raise ProtocolError("protocol", f"protocol file {key} is not valid TOML: {exc}") from None
    return protocol_from_dict(data)


def sine_from_dict(spec: dict) -> SineProfile:
    """A sine block from the API form {"kind": "sine", amplitude_m, frequency_hz, cycles, taper_cycles, offset_m,
    start_m} (numbers checked here; the rig envelope is checked by sim.profiles.validate_profile)."""
    allowed = {"kind", "amplitude_m", "frequency_hz", "cycles", "taper_cycles", "offset_m", "start_m"}
    _unknown("profile", spec, allowed)
    for key in ("amplitude_m", "frequency_hz", "cycles"):
        if key not in spec:
            raise ProtocolError(f"profile.{key}", f"a sine profile needs {key}")
    return SineProfile(
        amplitude_m=_number("amplitude_m", spec["amplitude_m"], 0.0, 1.0, "m", lo_open=True),
        frequency_hz=_number("frequency_hz", spec["frequency_hz"], 0.0, 10.0, "Hz", lo_open=True),
        cycles=_number("cycles", spec["cycles"], 1, 100_000, "cycles", integer=True),
        taper_cycles=_number("taper_cycles", spec.get("taper_cycles", 1), 0, 100_000, "cycles", integer=True),
        offset_m=_number("offset_m", spec.get("offset_m", 0.0), -1.0, 1.0, "m"),
        start_m=_number("start_m", spec.get("start_m", 0.0), -1.0, 1.0, "m"),
    )


def profile_from_spec(spec: dict, isolator=None, vertical_load_n: float | None = None):
    """The one parser of the API's profile forms.

    {"kind": "sine", ...}, {"kind": "protocol", "name": "<shipped>"} or {"kind": "protocol", "protocol": {...}}
    (a protocol form may add "design_displacement_m" to rescale the levels) give (sine blocks, the protocol or
    None). The earthquake kinds {"kind": "history", ...} and {"kind": "hybrid", ...} (sim.earthquake) give
    ([], the built ``sim.earthquake.EarthquakeProfile``): they need the ``isolator`` and the test's
    ``vertical_load_n`` (N) to be built (the isolator's demand model, the hybrid reference)."""
    if not isinstance(spec, dict):
        raise ProtocolError("profile", "profile must be an object with kind 'sine', 'protocol', 'history' or "
                                       "'hybrid'")
    spec = {k: v for k, v in spec.items() if v is not None}  # null = absent (as a JSON API sends it)
    kind = spec.get("kind", "sine")
    if kind == "sine":
        return [sine_from_dict(spec)], None
    if kind in ("history", "hybrid"):
        if isolator is None:
            raise ProtocolError("profile", f"a {kind} profile is built for an isolator and a vertical load: "
                                           "profile_from_spec(spec, isolator, vertical_load_n)")
        from .earthquake import earthquake_from_spec

        return [], earthquake_from_spec(spec, isolator, vertical_load_n)
    if kind != "protocol":
        raise ProtocolError("profile.kind", f"profile kind {kind!r}; allowed: sine, protocol, history, hybrid")
    _unknown("profile", spec, {"kind", "name", "protocol", "design_displacement_m", "frequency_hz"})
    if ("name" in spec) == ("protocol" in spec):
        raise ProtocolError("profile", "a protocol profile needs exactly one of name (shipped: "
                                       f"{', '.join(SHIPPED_PROTOCOLS)}) or protocol (inline definition)")
    if "name" in spec:
        if spec["name"] not in SHIPPED_PROTOCOLS:
            raise ProtocolError("profile.name", f"unknown protocol {spec['name']!r}; shipped: "
                                                f"{', '.join(SHIPPED_PROTOCOLS)}")
        protocol = load_protocol(spec["name"])
    else:
        protocol = protocol_from_dict(spec["protocol"])
    try:  # the form's own fields (not the protocol's): named as the form's
        if spec.get("design_displacement_m") is not None:
            protocol = protocol.with_design_displacement(spec["design_displacement_m"])
        if spec.get("frequency_hz") is not None:
            protocol = protocol.with_frequency(spec["frequency_hz"])
    except ProtocolError as exc:
        raise ProtocolError(f"profile.{exc.field}", str(exc)) from None
    return protocol.blocks, protocol


# --- acceptance ---

def nominal_cycles(protocol: Protocol, isolator, dt_s: float = 1e-3) -> list[dict]:
    """Per-cycle metrics of the isolator's nominal Bouc-Wen model (eq. 4) driven by the protocol's target."""
    from .isolator import simulate_loop
    from .profiles import pack_profile, target_series

    t = np.arange(0.0, protocol.duration_s, dt_s)
    d = target_series(pack_profile(protocol.blocks), t)
    f = simulate_loop(isolator, d, dt_s)
    starts, end = protocol.cycle_starts_s()
    return cycle_metrics(t, d, f, starts, end)


def _match(plan: list[dict], cycles: list[dict]) -> dict[int, dict]:
    """Measured cycles by planned cycle number: by the mid time of each cycle if known, else by number."""
    out: dict[int, dict] = {}
    if cycles and all(c.get("t_start_s") is not None and c.get("t_end_s") is not None for c in cycles):
        starts = np.array([p["t_start_s"] for p in plan])
        for c in cycles:
            mid = 0.5 * (c["t_start_s"] + c["t_end_s"])
            k = int(np.searchsorted(starts, mid, side="right")) - 1
            if 0 <= k < len(plan) and mid < plan[k]["t_end_s"]:
                out.setdefault(plan[k]["cycle"], c)
        return out
    for c in cycles:
        if isinstance(c.get("cycle"), int):
            out.setdefault(c["cycle"], c)
    return out


def evaluate_acceptance(protocol: Protocol, cycles: list[dict], isolator=None) -> list[dict]:
    """One verdict per rule and judged test cycle.

    A verdict: rule, quantity, reference, level, level_cycle, cycle, value, reference_value, deviation_fraction,
    tolerance_fraction, status ("pass", "fail", "missing": no measured cycle or quantity, "not_evaluated": the
    rule needs the isolator's nominal model and none was given), passed (bool) and message (names the rule).
    """
    plan = protocol.cycle_plan()
    measured = _match(plan, cycles)
    nominal = None
    if any(r.reference == "isolator" for r in protocol.rules) and isolator is not None:
        nominal = {c["cycle"]: c for c in nominal_cycles(protocol, isolator)}
    verdicts = []
    for rule in protocol.rules:
        for p in plan:
            if not p["test"] or not rule.applies_to(p["level"]):
                continue
            if rule.reference == "cycle" and p["level_cycle"] == rule.reference_cycle:
                continue  # the reference itself
            v = {"rule": rule.name, "quantity": rule.quantity, "reference": rule.reference, "level": p["level"],
                 "level_cycle": p["level_cycle"], "cycle": p["cycle"], "value": None, "reference_value": None,
                 "deviation_fraction": None, "tolerance_fraction": rule.tolerance_fraction}
            m = measured.get(p["cycle"])
            value = None if m is None else m.get(rule.quantity)
            ref = None
            if rule.reference == "cycle":
                ref_plan = next(q for q in plan
                                if q["level"] == p["level"] and q["level_cycle"] == rule.reference_cycle)
                rm = measured.get(ref_plan["cycle"])
                ref = None if rm is None else rm.get(rule.quantity)
                ref_text = f"level {p['level']} test cycle {rule.reference_cycle} (cycle {ref_plan['cycle']})"
            elif rule.reference == "value":
                ref = rule.values[p["level"] - 1]
                ref_text = "the nominal value"
                if ref is None:
                    continue
            else:
                ref_text = "the isolator's nominal model"
                if nominal is None:
                    verdicts.append({**v, "status": "not_evaluated", "passed": False,
                                     "message": f"{rule.name}: not evaluated, no isolator model given"})
                    continue
                nm = nominal.get(p["cycle"])
                ref = None if nm is None else nm.get(rule.quantity)
            where = f"level {p['level']} cycle {p['level_cycle']} (cycle {p['cycle']})"
            if value is None or ref is None or not math.isfinite(value) or not math.isfinite(ref) or ref == 0:
                what = "no measured cycle" if m is None else (f"no {rule.quantity}" if value is None
                                                              else f"no reference {rule.quantity}")
                verdicts.append({**v, "value": value, "reference_value": ref, "status": "missing", "passed": False,
                                 "message": f"{rule.name} failed at {where}: {what} ({ref_text})"})
                continue
            dev = value / ref - 1.0
            ok = abs(dev) <= rule.tolerance_fraction
            verdicts.append({**v, "value": value, "reference_value": ref, "deviation_fraction": dev,
                             "status": "pass" if ok else "fail", "passed": ok,
                             "message": f"{rule.name} {'passed' if ok else 'failed'} at {where}: {rule.quantity} = "
                                        f"{value:.4g} is {100 * dev:+.1f} % from {ref_text} ({ref:.4g}); "
                                        f"tolerance +-{100 * rule.tolerance_fraction:g} %"})
    return verdicts


def acceptance_summary(verdicts: list[dict]) -> dict:
    """Overall verdict: passed only if every verdict passed (None without verdicts); the failing rules."""
    failed = [v for v in verdicts if not v["passed"]]
    rules: dict[str, dict] = {}
    for v in failed:
        r = rules.setdefault(v["rule"], {"rule": v["rule"], "failures": 0, "cycles": [], "first": v["message"]})
        r["failures"] += 1
        r["cycles"].append(v["cycle"])
    return {"passed": (not failed) if verdicts else None, "verdicts": len(verdicts), "failed": len(failed),
            "failed_rules": list(rules.values())}
