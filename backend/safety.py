"""Safety limit detectors, like the limit and error detectors of a commercial servo-hydraulic controller.

Each block of samples the worker produces is checked before it is released: displacement (stroke),
force, load pressure, tracking error |y - r| and non-finite values. The first sample that breaks a limit
trips the test: the worker ramps the valve command to zero, records the trip with its values and ends the
test ``aborted``. Limits are per test (``limits`` in ``POST /api/tests``), bounded by the rig's hard limits.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from sim.engine import C_FORCE, C_PL, C_TARGET, C_TIME, C_U, C_Y
from sim.errors import FieldError
from sim.rig import RigParameters

DEFAULT_TRACKING_ERROR_M = 0.05  # the paper's MRAC reaches ~31 mm peak |y - r| on IUT_b, 30 mm at 1 Hz
COMMAND_RAMP_S = 0.1  # controlled stop: the valve command ramps from its last value to zero in this time


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


def check_block(rows: np.ndarray, limits: SafetyLimits) -> Trip | None:
    """The first sample of ``rows`` (engine COLUMNS layout) that breaks a limit, or None."""
    if rows.shape[0] == 0:
        return None
    y, f, pl, r, u = rows[:, C_Y], rows[:, C_FORCE], rows[:, C_PL], rows[:, C_TARGET], rows[:, C_U]
    err = np.abs(y - r)
    checks = (
        ("non_finite", ~(np.isfinite(y) & np.isfinite(f) & np.isfinite(pl) & np.isfinite(u)), None, None),
        ("displacement", np.abs(y) > limits.displacement_m, "displacement_m", limits.displacement_m),
        ("force", np.abs(f) > limits.force_n, "force_n", limits.force_n),
        ("load_pressure", np.abs(pl) > limits.load_pressure_pa, "load_pressure_pa", limits.load_pressure_pa),
        # rows without a target (open-loop ramp) have r = NaN and are not checked for tracking
        ("tracking_error", np.isfinite(r) & (err > limits.tracking_error_m), "tracking_error_m",
         limits.tracking_error_m),
    )
    first = None
    for name, mask, key, limit in checks:
        hits = np.flatnonzero(mask)
        if hits.size and (first is None or hits[0] < first[1]):
            first = (name, int(hits[0]), key, limit)
    if first is None:
        return None
    name, i, key, limit = first
    row = rows[i]
    values = {"time_s": float(row[C_TIME]), "displacement_m": float(row[C_Y]), "force_n": float(row[C_FORCE]),
              "load_pressure_pa": float(row[C_PL]), "target_m": float(row[C_TARGET]),
              "tracking_error_m": float(err[i]), "voltage_v": float(row[C_U])}
    if key is None:
        message = f"non-finite rig state at t = {row[C_TIME]:.3f} s"
    else:
        values["limit"] = limit
        values["limit_name"] = key
        measured = values[key]
        unit = UNITS[key]
        message = (f"{name.replace('_', ' ')} limit tripped at t = {row[C_TIME]:.3f} s: |{key}| = "
                   f"{abs(measured):.6g} {unit} > limit {limit:.6g} {unit}")
    return Trip(name, i, float(row[C_TIME]), message, values)


def command_ramp(u0_v: float, duration_s: float, period_s: float) -> np.ndarray:
    """Valve commands from u0 down to zero, linearly, one per control period (the last is 0)."""
    n = max(1, int(round(duration_s / period_s)))
    return u0_v * (1.0 - np.arange(1, n + 1) / n)
