"""Safety limit detectors, like the limit and error detectors of a commercial servo-hydraulic controller.

Each block of samples the worker produces is checked before it is released. Operator limits (per test,
``limits`` in ``POST /api/tests``, bounded by the rig's hard limits): displacement (stroke), force, load
pressure, tracking error |y - r|. Built-in detectors: non-finite readings or commands, a fault the rig
reports in its status bits (sensor fault, watchdog, interlock), the supply pressure lost (below
``SUPPLY_LOSS_FRACTION`` of the test's setting) and a frozen position reading (unchanged for
``FROZEN_PERIODS`` periods while the valve command stayed beyond ``FROZEN_COMMAND_V``: the valve is open, so
the table moves, unless the sensor is stuck; a table the controller does not drive may rest). Detectors
read what the rig measures (``measured_displacement_m``), never a simulation's true state.

The first sample that trips ends the test: the loop ramps the valve command to zero (sim.loop), the trip is
recorded with its values and the test ends ``aborted``.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from sim.errors import FieldError
from sim.measurement import RIG_FAULT_BITS, describe_status
from sim.rig import RigParameters
from sim.samples import Samples

DEFAULT_TRACKING_ERROR_M = 0.05  # the paper's MRAC reaches ~31 mm peak |y - r| on IUT_b, 30 mm at 1 Hz
SUPPLY_LOSS_FRACTION = 0.5  # a measured supply pressure below this share of the test's setting trips
FROZEN_PERIODS = 100  # a position reading unchanged this many periods ...
FROZEN_COMMAND_V = 2.0  # ... while |valve command| stayed at least this (20 % of the range): the sensor is stuck


class LimitError(FieldError):
    """A requested limit is outside what the rig allows; names field, value and limit."""


@dataclass(frozen=True)
class SafetyLimits:
    """Trip thresholds (absolute values, SI units)."""

    displacement_m: float
    force_n: float
    load_pressure_pa: float
    tracking_error_m: float

    def to_dict(self) -> dict:
        return asdict(self)


def hard_limits(rig: RigParameters) -> SafetyLimits:
    """The largest limits a test may ask for: the rig's stroke, A_p P_s,max, P_s,max, and twice the stroke."""
    return SafetyLimits(displacement_m=rig.stroke_m, force_n=rig.max_force_n(rig.max_supply_pa),
                        load_pressure_pa=rig.max_supply_pa, tracking_error_m=2 * rig.stroke_m)


def default_limits(rig: RigParameters) -> SafetyLimits:
    hard = hard_limits(rig)
    return SafetyLimits(displacement_m=hard.displacement_m, force_n=hard.force_n,
                        load_pressure_pa=hard.load_pressure_pa, tracking_error_m=DEFAULT_TRACKING_ERROR_M)


UNITS = {"displacement_m": "m", "force_n": "N", "load_pressure_pa": "Pa", "tracking_error_m": "m"}


def make_limits(rig: RigParameters, requested: dict | None) -> SafetyLimits:
    """Defaults overridden by ``requested``; each value must be positive and within the hard limit."""
    values = default_limits(rig).to_dict()
    hard = hard_limits(rig).to_dict()
    for key, value in (requested or {}).items():
        if value is None:
            continue
        if key not in values:
            raise LimitError(f"limits.{key}", value, ", ".join(values), f"limits.{key} is not a limit; "
                             f"allowed: {', '.join(values)}")
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not np.isfinite(value) or value <= 0:
            raise LimitError(f"limits.{key}", value, f"a positive number <= {hard[key]:g} {UNITS[key]}",
                             f"limits.{key} = {value!r} must be a positive number (unit {UNITS[key]})")
        if value > hard[key]:
            raise LimitError(f"limits.{key}", value, f"<= {hard[key]:g} {UNITS[key]}",
                             f"limits.{key} = {value:g} {UNITS[key]} is beyond the rig's hard limit of "
                             f"{hard[key]:g} {UNITS[key]}")
        values[key] = float(value)
    return SafetyLimits(**values)


@dataclass
class Trip:
    """A limit trip: which detector, at which sample, with the values that broke it."""

    detector: str
    index: int
    time_s: float
    message: str
    values: dict


def _values(rows: Samples, i: int) -> dict:
    y, r = rows["measured_displacement_m"][i], rows["target_m"][i]
    return {"time_s": float(rows["time_s"][i]), "displacement_m": float(y), "force_n": float(rows["force_n"][i]),
            "load_pressure_pa": float(rows["load_pressure_pa"][i]),
            "supply_pressure_pa": float(rows["supply_pressure_pa"][i]), "target_m": float(r),
            "tracking_error_m": float(abs(y - r)), "voltage_v": float(rows["voltage_v"][i]),
            "flags": int(np.nan_to_num(rows["flags"][i]))}


def check_block(rows: Samples, limits: SafetyLimits, supply_pa: float | None = None) -> Trip | None:
    """The first sample of ``rows`` that breaks a limit (stateless detectors), or None.

    ``supply_pa``: the test's supply pressure setting, for the supply-loss detector (skipped if None).
    """
    if len(rows) == 0:
        return None
    y, f, pl, r = (rows["measured_displacement_m"], rows["force_n"], rows["load_pressure_pa"], rows["target_m"])
    ps, u = rows["supply_pressure_pa"], rows["voltage_v"]
    flags = np.nan_to_num(rows["flags"]).astype(np.int64)
    err = np.abs(y - r)
    finite = np.isfinite(y) & np.isfinite(f) & np.isfinite(pl) & np.isfinite(u) & np.isfinite(ps)
    checks = [
        ("non_finite", ~finite, None, None),
        ("rig_fault", (flags & RIG_FAULT_BITS) != 0, None, None),
        ("displacement", np.abs(y) > limits.displacement_m, "displacement_m", limits.displacement_m),
        ("force", np.abs(f) > limits.force_n, "force_n", limits.force_n),
        ("load_pressure", np.abs(pl) > limits.load_pressure_pa, "load_pressure_pa", limits.load_pressure_pa),
        # rows without a target (open-loop ramp) have r = NaN and are not checked for tracking
        ("tracking_error", np.isfinite(r) & (err > limits.tracking_error_m), "tracking_error_m",
         limits.tracking_error_m),
    ]
    if supply_pa is not None:
        floor = SUPPLY_LOSS_FRACTION * supply_pa
        checks.append(("supply_pressure", ps < floor, "supply_pressure_pa", floor))
    first = None
    for name, mask, key, limit in checks:
        hits = np.flatnonzero(mask)
        if hits.size and (first is None or hits[0] < first[1]):
            first = (name, int(hits[0]), key, limit)
    if first is None:
        return None
    name, i, key, limit = first
    values = _values(rows, i)
    t = values["time_s"]
    if name == "non_finite":
        message = f"non-finite rig state or reading at t = {t:.3f} s"
    elif name == "rig_fault":
        message = f"the rig reports a fault at t = {t:.3f} s: {describe_status(values['flags'] & RIG_FAULT_BITS)}"
    elif name == "supply_pressure":
        values.update(limit=limit, limit_name=key)
        message = (f"supply pressure lost at t = {t:.3f} s: {values[key] / 1e5:.4g} bar < {limit / 1e5:.4g} bar "
                   f"({SUPPLY_LOSS_FRACTION:.0%} of the test's {supply_pa / 1e5:.4g} bar)")
    else:
        values.update(limit=limit, limit_name=key)
        unit = UNITS[key]
        message = (f"{name.replace('_', ' ')} limit tripped at t = {t:.3f} s: |{key}| = "
                   f"{abs(values[key]):.6g} {unit} > limit {limit:.6g} {unit}")
    return Trip(name, i, t, message, values)


class SafetyMonitor:
    """Every detector over a test's blocks in order: ``check_block`` plus the frozen-reading detector,
    which needs what came before the block."""

    def __init__(self, limits: SafetyLimits, supply_pa: float | None = None):
        self.limits = limits
        self.supply_pa = supply_pa
        self._last_reading = np.nan
        self._run_periods = 0  # periods the reading has been unchanged, with the valve open, before the block

    def check(self, rows: Samples) -> Trip | None:
        trip = check_block(rows, self.limits, self.supply_pa)
        frozen = self._frozen(rows)
        if frozen is not None and (trip is None or frozen.index < trip.index):
            return frozen
        return trip

    def _frozen(self, rows: Samples) -> Trip | None:
        n = len(rows)
        if n == 0:
            return None
        y = rows["measured_displacement_m"]
        with np.errstate(invalid="ignore"):
            open_valve = np.abs(rows["voltage_v"]) >= FROZEN_COMMAND_V
        changed = np.empty(n, dtype=bool)
        changed[0] = not (y[0] == self._last_reading)
        changed[1:] = y[1:] != y[:-1]
        changed |= ~open_valve  # a run counts only periods with the valve open
        index = np.arange(n)
        start = np.maximum.accumulate(np.where(changed, index, -1))  # where the current run began (-1: before)
        run = np.where(start >= 0, index - start, index + 1 + self._run_periods)
        hits = np.flatnonzero(run >= FROZEN_PERIODS)
        self._last_reading = y[-1]
        self._run_periods = int(run[-1])
        if hits.size == 0:
            return None
        i = int(hits[0])
        values = _values(rows, i)
        values.update(unchanged_periods=int(run[i]), command_at_least_v=FROZEN_COMMAND_V)
        message = (f"position reading frozen at t = {values['time_s']:.3f} s: {values['displacement_m']:.6g} m for "
                   f"{int(run[i])} periods with the valve command beyond +-{FROZEN_COMMAND_V:g} V (a stuck sensor)")
        return Trip("position_frozen", i, values["time_s"], message, values)
