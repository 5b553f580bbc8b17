"""Earthquake tests as the service runs them: the API's ``history`` and ``hybrid`` profile forms made into the
rig's target, and the figures of their record (J1-J5, the structure against its reference).

Profile forms (JSON; SI units; ``sim.protocols.profile_from_spec`` hands these kinds to ``earthquake_from_spec``):

- ``{"kind": "history", "ground_motion": <ground motion>, "scale": 1.0, "mass_kg": null, "taper_in_s": 0.5,
  "taper_out_s": 0.5}``: the isolator's displacement demand under the ground motion (``scale`` times its
  acceleration), through a rigid mass ``mass_kg`` on the isolator's Bouc-Wen model
  (``sim.history.isolation_displacement``; default mass: the test's vertical load / g), then made a target
  (``sim.history.prepare_history``: resampled to the control period, tapered in and out).
- ``{"kind": "history", "displacement": {"time_s": [...], "displacement_m": [...]}, "scale": 1.0, ...}``: a
  displacement history given inline (``scale`` multiplies it).
- ``{"kind": "hybrid", "structure": {"base_mass_kg", "masses_kg", "stiffness_n_per_m", "damping_ratio"},
  "ground_motion": <ground motion>, "scale": 1.0, "stability": {"limit_j": 100, "relative_limit": 0.5}}``:
  real-time hybrid simulation (sim.hybrid); the target is computed period by period from the force measured.
  ``target`` here is the prediction the envelope is checked on: the base displacement of the full-numerical
  reference (``sim.hybrid.reference``).

A ground motion is a preset name of ``sim.ground_motion.GROUND_MOTIONS`` or inline
``{"time_s": [...], "acceleration_m_per_s2": [...], "units": "m/s2", "check_units": true}`` (``units`` one of
m/s2, g, cm/s2: the values' unit; a peak outside 0.005-3 g in that unit is refused unless ``check_units`` is
false). Inline arrays hold at most ``MAX_INLINE_SAMPLES`` samples, uniformly sampled (sim.history's checks,
the sample named by its index). Every refusal is a ``sim.history.HistoryError`` (a FieldError) whose
``field`` starts with ``profile.`` and names the culprit.

The same spec always gives the same target (the synthetic motions are seeded; the integrators are
deterministic): the service stores the spec as asked and the worker rebuilds the target from it
(``fingerprint`` checks that it did).
"""

from __future__ import annotations

import hashlib
import json
import math
from collections import OrderedDict
from dataclasses import dataclass, field, replace

import numpy as np

from .errors import FieldError
from .history import (
    UNIT_TO_M_PER_S2,
    HistoryError,
    HistoryTarget,
    check_acceleration_units,
    check_inline_record,
    isolation_displacement,
    prepare_history,
)
from .hybrid_metrics import (
    CRITERIA,
    DEFAULT_ENERGY_LIMIT_J,
    DEFAULT_RELATIVE_ENERGY_LIMIT,
    EnergyMonitor,
    criteria_verdicts,
    tracking_criteria,
)
from .isolator import Isolator
from .loop import CONTROL_PERIOD_S
from .measurement import measured_rows
from .structure import G_M_PER_S2

KINDS = ("history", "hybrid")
MAX_INLINE_SAMPLES = 200_000
DEFAULT_TAPER_S = 0.5
MAX_GROUND_MOTION_SCALE = 10.0
MASS_LIMIT_KG = 1.0e8
MIN_JUDGED_SAMPLES = 500  # J1 searches delays of +-0.1 s: fewer samples than this give no criteria
# the offline integrations a profile needs are done when the test is created (in the request): their work is
# bounded. RK4 substeps x dofs^2 for the hybrid reference (3.5-11 ns each measured: 5e9 is 20-55 s), RK4 substeps
# for the history's demand model (0.11 us each: 2e8 is 22 s). A 45 s record on the 3-storey demo building is
# 7e6 and 9e5 of these.
MAX_REFERENCE_WORK = 5.0e9
MAX_DEMAND_SUBSTEPS = 2.0e8
HISTORY_FIELDS = ("kind", "ground_motion", "displacement", "scale", "mass_kg", "taper_in_s", "taper_out_s")
HYBRID_FIELDS = ("kind", "structure", "ground_motion", "scale", "stability")
INLINE_GROUND_MOTION_FIELDS = ("time_s", "acceleration_m_per_s2", "units", "check_units")
STABILITY_FIELDS = ("limit_j", "relative_limit")
_TARGETS = {key: target for key, _name, target, _unit, _meaning in CRITERIA}
_CACHE: OrderedDict = OrderedDict()  # the last few profiles built (the worker, the service and the API rebuild)
_CACHE_SIZE = 4


@dataclass(frozen=True, eq=False)
class EarthquakeProfile:
    """A history or hybrid profile, built: the rig's target (history) or the reference's prediction of it
    (hybrid), what the record says about it (``description``: no arrays), and for a hybrid test the building,
    the ground acceleration at every control period and the stability monitor's settings."""

    kind: str
    target: HistoryTarget = field(repr=False)
    description: dict
    building: object | None = None  # sim.structure.ShearBuilding
    ground_acc_m_per_s2: np.ndarray | None = field(default=None, repr=False)
    stability: dict = field(default_factory=dict)

    def new_monitor(self) -> EnergyMonitor:
        return EnergyMonitor(**self.stability)

    def substructure(self, isolator: Isolator):
        """A fresh numerical substructure for a run (sim.hybrid.HybridSubstructure); hybrid only."""
        from .hybrid import HybridSubstructure

        return HybridSubstructure(self.building, isolator, self.ground_acc_m_per_s2, monitor=self.new_monitor())

    @property
    def fingerprint(self) -> str:
        """SHA-256 of the target's samples (and of the ground acceleration of a hybrid test)."""
        h = hashlib.sha256(np.ascontiguousarray(self.target.r_m).tobytes())
        if self.ground_acc_m_per_s2 is not None:
            h.update(np.ascontiguousarray(self.ground_acc_m_per_s2).tobytes())
        return h.hexdigest()


def _error(message: str, fld: str, value=None, limit: str = "") -> HistoryError:
    return HistoryError(message, field=fld, value=value, limit=limit)


def _prefixed(exc: FieldError, prefix: str) -> HistoryError:
    """A refusal from a part (a structure, a ground motion, prepare_history) with its field under ``prefix``."""
    fld = exc.field if exc.field.startswith(prefix) else f"{prefix}.{exc.field}"
    text = str(exc)
    return HistoryError(text if text.startswith(prefix) else f"{prefix}: {text}", field=fld, value=exc.value,
                        limit=exc.limit)


def _number(spec: dict, key: str, default, lo: float, hi: float, unit: str, lo_open: bool = True,
            allow_none: bool = False, where: str = "profile"):
    value = spec.get(key, default)
    if value is None and allow_none:
        return None
    ok = not isinstance(value, bool) and isinstance(value, (int, float)) and math.isfinite(value) \
        and (lo < value if lo_open else lo <= value) and value <= hi
    if not ok:
        bracket = "(" if lo_open else "["
        bounds = f"{bracket}{lo:g}, {hi:g}]" + (f" {unit}" if unit else "")
        raise _error(f"{where}.{key} = {value!r} must be a number in {bounds}", f"{where}.{key}", value, bounds)
    return float(value)


def _known(spec: dict, allowed: tuple[str, ...], where: str) -> None:
    unknown = [k for k in spec if k not in allowed]
    if unknown:
        raise _error(f"unknown field(s) {', '.join(map(repr, unknown))} in {where}; allowed: {', '.join(allowed)}",
                     f"{where}.{unknown[0]}", spec[unknown[0]], "one of " + ", ".join(allowed))


def _clean(spec: dict) -> dict:
    return {k: v for k, v in spec.items() if v is not None}  # null = absent, as a JSON API sends it


# ---- ground motions --------------------------------------------------------------------------------------
def ground_motion_from_spec(value, fld: str = "profile.ground_motion") -> tuple[np.ndarray, np.ndarray, dict]:
    """(time_s, acceleration_m_per_s2, description) of a preset name or an inline record (module docstring)."""
    from .ground_motion import GROUND_MOTIONS, synthetic_ground_motion

    if isinstance(value, str):
        if value not in GROUND_MOTIONS:
            raise _error(f"{fld} = {value!r} is not a shipped ground motion; use one of {', '.join(GROUND_MOTIONS)} "
                         "or give the record inline ({time_s: [...], acceleration_m_per_s2: [...]})", fld, value,
                         ", ".join(GROUND_MOTIONS))
        t, acc, info = synthetic_ground_motion(value)
        keep = ("name", "description", "seed", "duration_s", "dt_s", "pga_g", "pgv_m_per_s", "pgd_m",
                "significant_duration_s", "method")
        return t, acc, {"preset": value, **{k: info[k] for k in keep if k in info}}
    if not isinstance(value, dict):
        raise _error(f"{fld} must be a preset name ({', '.join(GROUND_MOTIONS)}) or an object {{time_s, "
                     f"acceleration_m_per_s2, units}} (got {type(value).__name__})", fld, None,
                     "a name or an inline record")
    spec = _clean(value)
    _known(spec, INLINE_GROUND_MOTION_FIELDS, fld)
    for key in ("time_s", "acceleration_m_per_s2"):
        if key not in spec:
            raise _error(f"{fld}.{key} is missing: an inline ground motion needs time_s and acceleration_m_per_s2",
                         f"{fld}.{key}", None, "required")
    units = spec.get("units", "m/s2")
    check = spec.get("check_units", True)
    if not isinstance(check, bool):
        raise _error(f"{fld}.check_units must be true or false", f"{fld}.check_units", check, "true or false")
    if units not in UNIT_TO_M_PER_S2:
        raise _error(f"{fld}.units = {units!r}; use one of " + ", ".join(map(repr, UNIT_TO_M_PER_S2)),
                     f"{fld}.units", units, ", ".join(UNIT_TO_M_PER_S2))
    t, acc = check_inline_record(spec["time_s"], spec["acceleration_m_per_s2"], name=fld, what="acceleration",
                                 unit=units, fields=(f"{fld}.time_s", f"{fld}.acceleration_m_per_s2"),
                                 max_samples=MAX_INLINE_SAMPLES)
    how = "given" if "units" in spec else "assumed: no units given"
    if check:
        check_acceleration_units(acc, units, how, name=fld, field=f"{fld}.units")
    acc = acc * UNIT_TO_M_PER_S2[units]
    peak = float(np.max(np.abs(acc)))
    return t - t[0], acc, {"preset": None, "inline": True, "samples": int(t.size),
                           "dt_s": float(np.median(np.diff(t))), "duration_s": float(t[-1] - t[0]), "units": units,
                           "units_how": how, "pga_m_per_s2": peak, "pga_g": peak / G_M_PER_S2}


def _ground_motion_name(info: dict) -> str:
    return info["preset"] if info.get("preset") else (f"an inline record ({info['samples']} samples at "
                                                      f"{info['dt_s']:g} s, {info['units']})")


# ---- building the profile -----------------------------------------------------------------------------------
def structure_weight_n(spec: dict) -> float | None:
    """The weight of a hybrid profile's building (N: its total mass times g), the vertical load a hybrid test
    runs under unless it says otherwise; None for another profile. Raises for a structure that is not one."""
    if not isinstance(spec, dict) or spec.get("kind") != "hybrid":
        return None
    from .structure import ShearBuilding, StructureError

    try:
        return ShearBuilding.from_dict(spec.get("structure")).total_mass_kg * G_M_PER_S2
    except StructureError as exc:
        raise _prefixed(exc, "profile.structure") from None


def too_heavy_for_the_jack(weight_n: float, max_vertical_load_n: float) -> str | None:
    """Why a hybrid test cannot run under its building's weight (``weight_n``) on a jack of ``max_vertical_load_n``
    (N), in words with both in kN and how to set the vertical load instead; None when the jack can carry it."""
    if 0.0 <= weight_n <= max_vertical_load_n:
        return None
    return (f"the building weighs {weight_n / 1e3:.4g} kN (its total mass {weight_n / G_M_PER_S2 / 1e3:.4g} t x g) "
            f"and the vertical jack carries at most {max_vertical_load_n / 1e3:.4g} kN: a hybrid test runs under the "
            "building's weight unless the vertical load is set. Set it, 0 to "
            f"{max_vertical_load_n:.6g} N, with vertical_load_n (the API; the console's vertical load) or "
            "--vertical-load-n (isorig hybrid), or use a lighter building")


def earthquake_from_spec(spec: dict, isolator: Isolator, vertical_load_n: float,
                         dt_s: float = CONTROL_PERIOD_S) -> EarthquakeProfile:
    """The profile a ``history`` or ``hybrid`` form describes (module docstring), for ``isolator`` under
    ``vertical_load_n`` (N; the mass of a ground motion's demand model is this / g unless ``mass_kg`` is given).
    Deterministic; the last few are kept (rebuilding one is then free)."""
    if not isinstance(spec, dict):
        raise _error("profile must be an object with kind 'history' or 'hybrid'", "profile", None, "an object")
    key = hashlib.sha256(json.dumps([spec, isolator.to_dict(), vertical_load_n, dt_s], sort_keys=True,
                                    default=repr).encode()).hexdigest()
    if key in _CACHE:
        _CACHE.move_to_end(key)
        return _CACHE[key]
    spec = _clean(spec)
    kind = spec.get("kind")
    if kind == "history":
        profile = _history(spec, isolator, vertical_load_n, dt_s)
    elif kind == "hybrid":
        profile = _hybrid(spec, isolator, dt_s)
    else:
        raise _error(f"profile kind {kind!r}; the earthquake kinds are history and hybrid", "profile.kind", kind,
                     ", ".join(KINDS))
    _CACHE[key] = profile
    while len(_CACHE) > _CACHE_SIZE:
        _CACHE.popitem(last=False)
    return profile


def _history(spec: dict, isolator: Isolator, vertical_load_n: float, dt_s: float) -> EarthquakeProfile:
    _known(spec, HISTORY_FIELDS, "profile")
    if ("ground_motion" in spec) == ("displacement" in spec):
        raise _error("a history profile needs exactly one of ground_motion (a preset name or an inline "
                     "acceleration record, through the isolator's demand model) or displacement (an inline "
                     "displacement history {time_s, displacement_m})", "profile.ground_motion", None,
                     "exactly one of ground_motion, displacement")
    taper_in = _number(spec, "taper_in_s", DEFAULT_TAPER_S, 0.0, 600.0, "s", lo_open=False)
    taper_out = _number(spec, "taper_out_s", DEFAULT_TAPER_S, 0.0, 600.0, "s", lo_open=False)
    description = {"kind": "history", "taper_in_s": taper_in, "taper_out_s": taper_out}
    if "displacement" in spec:
        if "mass_kg" in spec:
            raise _error("profile.mass_kg applies to a ground motion only (the mass of the demand model), not to "
                         "a displacement history", "profile.mass_kg", spec["mass_kg"], "with ground_motion only")
        scale = _number(spec, "scale", 1.0, -100.0, 100.0, "(non-zero)", lo_open=False)
        if scale == 0.0:
            raise _error("profile.scale must not be 0", "profile.scale", 0.0, "0 < |scale| <= 100")
        disp = spec["displacement"]
        fld = "profile.displacement"
        if not isinstance(disp, dict):
            raise _error(f"{fld} must be an object {{time_s: [...], displacement_m: [...]}}", fld, None,
                         "an object")
        _known(disp, ("time_s", "displacement_m"), fld)
        for k in ("time_s", "displacement_m"):
            if k not in disp:
                raise _error(f"{fld}.{k} is missing", f"{fld}.{k}", None, "required")
        t, d = check_inline_record(disp["time_s"], disp["displacement_m"], name=fld, what="displacement_m",
                                   unit="m", fields=(f"{fld}.time_s", f"{fld}.displacement_m"),
                                   max_samples=MAX_INLINE_SAMPLES)
        source = f"an inline displacement history ({t.size} samples at {np.median(np.diff(t)):g} s)"
        try:
            target = prepare_history(t, d, dt_s, scale, taper_in, taper_out, source=source)
        except HistoryError as exc:
            raise _prefixed(exc, "profile") from None
        description.update(displacement={"inline": True, "samples": int(t.size),
                                         "dt_s": float(np.median(np.diff(t))), "duration_s": float(t[-1] - t[0])},
                           scale=scale)
    else:
        scale = _number(spec, "scale", 1.0, 0.0, MAX_GROUND_MOTION_SCALE, "")
        t, acc, info = ground_motion_from_spec(spec["ground_motion"])
        mass = _number(spec, "mass_kg", None, 0.0, MASS_LIMIT_KG, "kg", allow_none=True)
        if mass is None:
            if not (isinstance(vertical_load_n, (int, float)) and vertical_load_n > 0):
                raise _error("a ground motion needs a mass for the isolator's demand model: the vertical load is "
                             f"{vertical_load_n!r} N; give vertical_load_n > 0 or profile.mass_kg",
                             "profile.mass_kg", None, "> 0 kg")
            mass = float(vertical_load_n) / G_M_PER_S2
            mass_how = "the vertical load / g"
        else:
            mass_how = "given"
        _check_demand_work(t, isolator, mass)
        d = isolation_displacement(t, scale * acc, isolator, mass)
        if not np.all(np.isfinite(d)):
            raise _error("the isolator's displacement demand under this ground motion is not finite (a numerical "
                         "overflow): check the ground motion's scale and units", "profile.ground_motion", None,
                         "a finite response")
        source = (f"ground motion {_ground_motion_name(info)} x {scale:g} through {isolator.name} under {mass:.0f} kg "
                  "(rigid mass on the isolator's Bouc-Wen model)")
        try:
            target = prepare_history(t, d, dt_s, 1.0, taper_in, taper_out, source=source)
        except HistoryError as exc:
            raise _prefixed(exc, "profile") from None
        target = replace(target, ground_motion_scale=scale)
        description.update(ground_motion=info, scale=scale, mass_kg=mass, mass_from=mass_how)
    description.update(_target_figures(target))
    return EarthquakeProfile("history", target, description)


def _hybrid(spec: dict, isolator: Isolator, dt_s: float) -> EarthquakeProfile:
    from .hybrid import ground_at_periods, predicted_history, reference
    from .structure import ShearBuilding, StructureError

    _known(spec, HYBRID_FIELDS, "profile")
    for k in ("structure", "ground_motion"):
        if k not in spec:
            raise _error(f"profile.{k} is missing: a hybrid profile needs structure and ground_motion",
                         f"profile.{k}", None, "required")
    try:
        building = ShearBuilding.from_dict(spec["structure"])
    except StructureError as exc:
        raise _prefixed(exc, "profile.structure") from None
    scale = _number(spec, "scale", 1.0, 0.0, MAX_GROUND_MOTION_SCALE, "")
    stability = spec.get("stability") or {}
    if not isinstance(stability, dict):
        raise _error("profile.stability must be an object {limit_j, relative_limit}", "profile.stability",
                     None, "an object")
    stability = _clean(stability)
    _known(stability, STABILITY_FIELDS, "profile.stability")
    options = {"limit_j": DEFAULT_ENERGY_LIMIT_J, "relative_limit": DEFAULT_RELATIVE_ENERGY_LIMIT, **stability}
    for k, hi, unit in (("limit_j", 1.0e9, "J"), ("relative_limit", 100.0, "")):
        _number(options, k, None, 0.0, hi, unit, lo_open=False, where="profile.stability")
    options = {k: float(v) for k, v in options.items()}
    t, acc, info = ground_motion_from_spec(spec["ground_motion"])
    ag = ground_at_periods(t, scale * acc, dt_s)
    if ag.size < MIN_JUDGED_SAMPLES:
        raise _error(f"the ground motion lasts {ag.size * dt_s:g} s: a hybrid test needs at least "
                     f"{MIN_JUDGED_SAMPLES * dt_s:g} s", "profile.ground_motion", float(t[-1]),
                     f">= {MIN_JUDGED_SAMPLES * dt_s:g} s")
    _check_reference_work(building, isolator, ag.size, dt_s)
    ref = reference(building, isolator, ag, dt_s)
    base = ref["base_displacement_m"]
    if not np.all(np.isfinite(base)):
        raise _error("the structure's reference response is not finite (a numerical overflow): check the ground "
                     "motion's scale and units", "profile.ground_motion", None, "a finite response")
    source = f"hybrid: the reference's base displacement under {_ground_motion_name(info)} x {scale:g}"
    try:
        predicted = predicted_history(ref, dt_s, source)  # the base displacement, then the table rests
    except HistoryError as exc:
        raise _prefixed(exc, "profile") from None
    predicted = replace(predicted, ground_motion_scale=scale)
    description = {"kind": "hybrid", "structure": building.to_dict(),
                   "fixed_base_periods_s": [float(p) for p in building.fixed_base_periods_s()],
                   "total_mass_kg": building.total_mass_kg, "ground_motion": info, "scale": scale,
                   "stability": options, "predicted_peak_base_displacement_m": float(np.max(np.abs(base))),
                   "prediction": "the base displacement of the full-numerical reference (sim.hybrid.reference), "
                                 "then the table's rest after the ground motion (sim.hybrid.rest_tail); the "
                                 "envelope is checked on it"}
    description.update(_target_figures(predicted))
    return EarthquakeProfile("hybrid", predicted, description, building, ag, options)


def _rk4_substeps(dt_s: float, omega_max: float) -> int:
    """RK4 substeps per sample of ``dt_s`` (the rule of sim.structure.simulate_isolated_system)."""
    from .structure import REFERENCE_MAX_SUBSTEP_S

    h = min(REFERENCE_MAX_SUBSTEP_S, 0.05 / omega_max if omega_max > 0 else REFERENCE_MAX_SUBSTEP_S)
    return max(1, math.ceil(dt_s / h - 1e-9)) if math.isfinite(dt_s / h) else 2 ** 62


def _check_reference_work(building, isolator: Isolator, n_samples: int, dt_s: float) -> None:
    """Refuse a hybrid profile whose offline reference would take too long to integrate (a very stiff or very
    light structure needs tiny RK4 substeps; many storeys and a long record multiply the work)."""
    from .structure import isolator_tangent_stiffness_n_per_m

    k0 = building.stiffness_matrix().copy()
    k0[0, 0] += isolator_tangent_stiffness_n_per_m(isolator)
    omega = math.sqrt(max(float(np.max(np.linalg.eigvals(k0 / building.mass_vector_kg()[:, None]).real)), 0.0))
    substeps = _rk4_substeps(dt_s, omega)
    work = float(n_samples) * substeps * building.n_dofs ** 2
    if work > MAX_REFERENCE_WORK:
        raise _error(f"the structure's full-numerical reference would take too long to compute: its highest "
                     f"frequency on the isolator's stiffest tangent ({omega / (2 * math.pi):.4g} Hz) needs "
                     f"{substeps:g} RK4 substeps per {dt_s * 1e3:g} ms; times {n_samples} periods and "
                     f"{building.n_dofs} degrees of freedom squared that is {work:.3g}, more than "
                     f"{MAX_REFERENCE_WORK:.3g}; use a shorter ground motion, fewer storeys, or storeys that are "
                     "less stiff for their mass", "profile.structure", work,
                     f"<= {MAX_REFERENCE_WORK:.3g} substep-dof^2")


def _check_demand_work(time_s: np.ndarray, isolator: Isolator, mass_kg: float) -> None:
    """Refuse a history whose demand model (a rigid mass on the isolator) would take too long to integrate (a
    very light mass: a very high frequency)."""
    from .structure import isolator_tangent_stiffness_n_per_m

    omega = math.sqrt(isolator_tangent_stiffness_n_per_m(isolator) / mass_kg)
    dt = float(np.median(np.diff(time_s)))
    substeps = float(time_s.size) * _rk4_substeps(dt, omega)
    if substeps > MAX_DEMAND_SUBSTEPS:
        raise _error(f"profile.mass_kg = {mass_kg:g} kg on {isolator.name} has a natural frequency of "
                     f"{omega / (2 * math.pi):.4g} Hz: the demand model would need {substeps:.3g} RK4 substeps over "
                     f"the record, more than {MAX_DEMAND_SUBSTEPS:.3g}; give the mass of the isolated structure "
                     "(kg), or a shorter record", "profile.mass_kg", mass_kg, f"<= {MAX_DEMAND_SUBSTEPS:.3g} substeps")


def _target_figures(target: HistoryTarget) -> dict:
    d = target.to_dict()
    return {k: d[k] for k in ("source", "duration_s", "samples", "peak_displacement_m", "peak_velocity_m_per_s",
                              "peak_acceleration_m_per_s2")}


# ---- what a record says -----------------------------------------------------------------------------------
def early_end_time_s(events: list[dict]) -> float | None:
    """When a test began to end early, from its events (dicts as the service stores them): a limit trip (any
    action) or an operator's stop or abort as the worker carried it out (its event, actor ``system``; the
    request's own event, stamped with the last sample the service had, only if the worker's is missing); None
    if none."""
    times = []
    operator: dict[str, list] = {"system": [], "request": []}
    for e in events or ():
        values = e.get("values") or {}
        t = e.get("time_s")
        if not isinstance(t, (int, float)) or isinstance(t, bool) or not math.isfinite(t):
            continue
        if e.get("kind") == "limit_trip":
            times.append(float(t))
        elif e.get("kind") == "operator" and values.get("action") in ("stop", "abort"):
            operator["system" if e.get("actor", "system") == "system" else "request"].append(float(t))
    times += operator["system"] or operator["request"]
    return min(times) if times else None


def _judged_rows(samples, end_time_s: float | None, dt_s: float) -> tuple[int, str]:
    """How many rows from the start the criteria judge, and why they end there: the closed loop (a target and a
    measurement in every row), up to an early end."""
    n = len(samples)
    if n == 0:
        return 0, "no samples"
    ok = np.isfinite(samples["target_m"]) & np.isfinite(samples["displacement_m"])
    end = int(np.argmin(ok)) if not ok.all() else n
    why = "the whole record" if end == n else f"the closed loop up to t = {end * dt_s:.3f} s"
    if end_time_s is not None:
        stop = int(math.floor(end_time_s / dt_s + 1e-9))
        if stop < end:
            end, why = stop, f"up to the early end at t = {end_time_s:.3f} s (a stop or a limit trip)"
    return max(0, end), why


def record_figures(profile: EarthquakeProfile | None, isolator: Isolator, samples, *,
                   end_time_s: float | None = None, stability: dict | None = None, reference: dict | None = None,
                   arrays: bool = False, kind: str | None = None, dt_s: float = CONTROL_PERIOD_S) -> dict:
    """The figures of a history or hybrid test's record (``samples``, sim.samples), for its summary and report.

    ``criteria``: J1-J3 of the target against the measured displacement over the rows judged (from the start,
    while the loop was closed, up to ``end_time_s``: an early end) and, for a hybrid test, J4-J5 of the
    structure's base displacement (replayed from the record: sim.hybrid.replay) against the full-numerical
    reference (``reference``, else computed now: sim.hybrid.reference); ``verdicts`` (each with its target and
    ``met``); ``peaks``; for a hybrid test the structure's peaks beside the reference's, ``stability`` (the live
    monitor's final state when given, else the replayed one) and ``replay``. ``arrays=True`` adds the time
    series a report plots (under ``arrays``). A record of a history whose spec is not at hand (a CSV) can be
    judged with ``profile=None, kind="history"``."""
    n, why = _judged_rows(samples, end_time_s, dt_s)
    kind = profile.kind if profile is not None else kind
    if kind not in KINDS or (kind == "hybrid" and profile is None):
        raise ValueError(f"record_figures needs a history kind or a hybrid profile (got {kind!r})")
    out: dict = {"kind": kind, "judged": {"samples": n, "until_s": n * dt_s, "what": why},
                 "targets": {k: v for k, v in _TARGETS.items()
                             if kind == "hybrid" or k in ("j1_delay_ms", "j2_rms_percent",
                                                                  "j3_peak_percent")}}
    measured = measured_rows(samples["flags"][:n])
    out["judged"]["lost_periods"] = int(np.count_nonzero(~measured))  # held readings: J2, J3 leave them out
    criteria: dict = {}
    if n >= MIN_JUDGED_SAMPLES:
        criteria.update(tracking_criteria(samples["target_m"][:n], samples["displacement_m"][:n], dt_s,
                                          measured=measured))
    else:
        out["judged"]["note"] = (f"{n} samples judged: at least {MIN_JUDGED_SAMPLES} are needed for the criteria "
                                 "(J1 searches delays of up to 0.1 s)")
    if n:
        out["peaks"] = {"command_m": float(np.max(np.abs(samples["target_m"][:n]))),
                        "measured_m": float(np.max(np.abs(samples["displacement_m"][:n]))),
                        "force_n": float(np.nanmax(np.abs(samples["force_n"][:n])))}
    series: dict = {}
    if kind == "hybrid":
        from .hybrid import compare_with_reference, replay
        from .hybrid import reference as full_reference

        rep = replay(profile.building, isolator, profile.ground_acc_m_per_s2, samples, end_period=n,
                     monitor=profile.new_monitor(), dt_s=dt_s)  # the test's own monitor settings
        ref = reference if reference is not None else full_reference(profile.building, isolator,
                                                                     profile.ground_acc_m_per_s2, dt_s)
        m = rep["periods"]
        channels = rep["channels"]
        if m >= MIN_JUDGED_SAMPLES and np.all(np.isfinite(channels["base_displacement_m"])):
            criteria.update(compare_with_reference(channels, ref))
        peaks = {}
        for name, values in channels.items():
            peaks[name] = {"rths": float(np.max(np.abs(values))) if m else None,
                           "reference": float(np.max(np.abs(ref[name][:m]))) if m else None,
                           "reference_whole": float(np.max(np.abs(ref[name])))}
        out["structure"] = {"channels": list(channels), "periods": m, "until_s": m * dt_s, "peaks": peaks,
                            "residual_base_displacement_m": float(channels["base_displacement_m"][-1]) if m else None}
        out["replay"] = {"periods": m, "command_difference_m": rep["command_difference_m"],
                         "what": "the structure's response rebuilt from the recorded force and position "
                                 "(sim.hybrid.replay), each period's command the recorded target"}
        out["reference"] = {"what": "the same building with the isolator's nominal Bouc-Wen model, integrated "
                                    "offline (sim.hybrid.reference: RK4)", "substeps_per_period": ref.get("substeps")}
        out["stability"] = dict(stability) if stability else {**rep["monitor"], "source": "replayed from the record"}
        with np.errstate(divide="ignore", invalid="ignore"):
            ratio = rep["added_energy_j"] / rep["limit_j"]
        if np.isfinite(ratio).any():  # the largest E_err / limit over the run (the live indicator's peak)
            k = int(np.nanargmax(np.where(np.isfinite(ratio), ratio, -np.inf)))
            out["stability"].update(peak_indicator=float(ratio[k]), peak_indicator_time_s=k * dt_s)
        if arrays:
            series.update(structure=channels, reference={k: ref[k][:max(m, 1)] for k in channels},
                          reference_whole={k: ref[k] for k in channels}, structure_time_s=rep["time_s"],
                          added_energy_j=rep["added_energy_j"], limit_j=rep["limit_j"],
                          ground_acc_m_per_s2=profile.ground_acc_m_per_s2)
    out["criteria"] = criteria
    out["verdicts"] = criteria_verdicts(criteria)
    if arrays:
        out["arrays"] = series
    return out


