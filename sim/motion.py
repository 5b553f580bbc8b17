"""Manual motion: the table moved from where it rests to a position, at a safe speed, under control.

The target is a minimum-jerk move (quintic: r = r0 + (r1 - r0)(10 s^3 - 15 s^4 + 6 s^5), s = t / T), whose
velocity and acceleration start and end at zero, followed by ``HOLD_S`` at the new position so the loop
settles before the valve closes. Its peak velocity is 1.875 |r1 - r0| / T, so T = 1.875 |r1 - r0| / v_max.
The result is a ``sim.history.HistoryTarget``: the loop runs it as it runs a time history. Its arrays are sized
by distance / speed, so the speed is bounded below as well as above (``MIN_SPEED_M_PER_S`` to
``MAX_SPEED_M_PER_S``) and a move lasts at most ``MAX_DURATION_S``: ``check_move`` (the service, ``isorig move``)
and ``move_target`` itself refuse anything else with a MotionError naming the field and what is allowed.

A move begins where the table reads when the rig is armed (``move_target`` from that reading: the worker plans it
again there), never from an older reading, so it starts at rest with no error to close. ``MoveGuard`` stops a
table that runs away from its move anyway (an uncommissioned rig whose loop is unstable): a measured velocity
beyond ``move_guard_m_per_s`` (MOVE_GUARD_FACTOR times the move's speed plus MOVE_GUARD_ALLOWANCE_M_PER_S) closes
the valve at once, with the reason recorded, long before the rig's own velocity limit.
"""

from __future__ import annotations

import math

import numpy as np

from .errors import FieldError
from .follow import ADVICE
from .history import HistoryTarget
from .loop import CONTROL_PERIOD_S
from .measurement import FLAG_OPEN_LOOP
from .safety import VELOCITY_SPAN_PERIODS, Trip, measured_velocity, velocity_readings

HOLD_S = 0.5  # the target rests at the new position this long before the move ends
DEFAULT_SPEED_M_PER_S = 0.005  # 5 mm/s: a jog speed at which an operator can follow the table by eye
MIN_SPEED_M_PER_S = 0.001  # 1 mm/s: slower asks for a target table sized by distance / speed (1e-178 m/s: 500)
MAX_SPEED_M_PER_S = 0.05  # manual motion is never faster than 50 mm/s
MIN_DURATION_S = 0.2  # even a tiny move lasts this long (a step would hit the oil column)
MAX_DURATION_S = 600.0  # and no move lasts longer (its target holds r, r', r'' per period: 14 MB at 1 kHz)
SPEED_RANGE = (f"[{MIN_SPEED_M_PER_S:g}, {MAX_SPEED_M_PER_S:g}] m/s "
               f"({MIN_SPEED_M_PER_S * 1e3:g} to {MAX_SPEED_M_PER_S * 1e3:g} mm/s)")
PEAK_VELOCITY_FACTOR = 1.875  # max of d/ds (10 s^3 - 15 s^4 + 6 s^5), at s = 1/2
#: a move's velocity guard: a table measured faster than this many times the move's speed ...
MOVE_GUARD_FACTOR = 2.0
#: ... plus this has run away from its move. A table that follows its move peaks within a few % of the speed
#: (5.05 mm/s on a 5 mm/s move, the commissioned lab rig through the emulator); the allowance covers the readings'
#: noise and resolution over the velocity's 5 ms (0.3 um of noise is 0.1 mm/s) and a table that settles as the
#: move begins. A 5 mm/s move is stopped at 15 mm/s (an uncommissioned foreign rig reached 146.7 mm/s, past its
#: 139 mm/s limit, before anything stopped it)
MOVE_GUARD_ALLOWANCE_M_PER_S = 0.005
MOVE_GUARD = "move_guard"  # the guard's detector name in a trip


class MotionError(FieldError):
    """A requested motion is outside what manual motion allows; names field, value and limit."""


def _number(value) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)


def check_speed(speed_m_per_s: float) -> float:
    """``speed_m_per_s`` if it is a number in [MIN_SPEED, MAX_SPEED] m/s, else a MotionError saying so."""
    if not (_number(speed_m_per_s) and MIN_SPEED_M_PER_S <= speed_m_per_s <= MAX_SPEED_M_PER_S):
        raise MotionError("speed_m_per_s", speed_m_per_s, SPEED_RANGE,
                          f"speed_m_per_s = {speed_m_per_s!r} m/s is outside what manual motion allows: "
                          f"{SPEED_RANGE}")
    return speed_m_per_s


def check_move(start_m: float, end_m: float, speed_m_per_s: float, stroke_m: float) -> None:
    """A clear MotionError unless both positions lie within the stroke, the speed in [MIN_SPEED, MAX_SPEED] and
    the move lasts at most MAX_DURATION_S."""
    for name, value in (("position_m", end_m), ("start_m", start_m)):
        if not _number(value) or abs(value) > stroke_m:
            raise MotionError(name, value, f"within +-{stroke_m:g} m (the stroke)",
                              f"{name} = {value!r} m is outside the rig's stroke of +-{stroke_m:g} m")
    check_speed(speed_m_per_s)
    distance_m = abs(end_m - start_m)
    if move_duration_s(start_m, end_m, speed_m_per_s) > MAX_DURATION_S:
        fastest = max(MIN_SPEED_M_PER_S, PEAK_VELOCITY_FACTOR * distance_m / MAX_DURATION_S)
        raise MotionError("speed_m_per_s", speed_m_per_s, f">= {fastest:.3g} m/s for a move of {distance_m:g} m",
                          f"a move of {distance_m * 1e3:g} mm at {speed_m_per_s * 1e3:g} mm/s would last "
                          f"{move_duration_s(start_m, end_m, speed_m_per_s):.0f} s, longer than the "
                          f"{MAX_DURATION_S:g} s a manual move may last: at least {fastest * 1e3:.3g} mm/s "
                          "for this distance")


def move_guard_m_per_s(speed_m_per_s: float) -> float:
    """The measured |velocity| beyond which a move at ``speed_m_per_s`` has run away: factor x speed + allowance."""
    return MOVE_GUARD_FACTOR * speed_m_per_s + MOVE_GUARD_ALLOWANCE_M_PER_S


class MoveGuardTrip(Trip):
    """The move guard's trip: the valve closes at once (the loop that ran the table away is not trusted to ramp
    its own command down)."""

    @property
    def close_at_once(self) -> bool:
        return True


class MoveGuard:
    """A move's velocity guard, fed the blocks of a move in order (``check``): the first closed-loop period whose
    measured velocity (sim.safety.measured_velocity, across blocks) is beyond ``move_guard_m_per_s`` is a trip that
    closes the valve at once. The periods of a stop's command ramp are not judged (the valve is closing already).
    ``commissioned``: the rig file in force was commissioned (the advice then is not to commission it)."""

    def __init__(self, speed_m_per_s: float, commissioned: bool = False):
        self.speed_m_per_s = check_speed(speed_m_per_s)
        self.limit_m_per_s = move_guard_m_per_s(speed_m_per_s)
        self.commissioned = commissioned
        self._recent = np.zeros(0)

    def check(self, rows) -> MoveGuardTrip | None:
        """The guard's trip in ``rows`` (sim.samples.Samples, the next block of the move), or None."""
        y = velocity_readings(rows)
        velocity = measured_velocity(y, self._recent)
        self._recent = np.concatenate([self._recent, y])[-VELOCITY_SPAN_PERIODS:]
        closed = (np.nan_to_num(rows["flags"]).astype(np.int64) & FLAG_OPEN_LOOP) == 0
        with np.errstate(invalid="ignore"):
            hits = np.flatnonzero(closed & (np.abs(velocity) > self.limit_m_per_s))
        if not hits.size:
            return None
        i = int(hits[0])
        t, v = float(rows["time_s"][i]), float(velocity[i])
        advice = ("the rig was commissioned: check what changed since (a specimen, the valve, the oil) and commission "
                  "it again" if self.commissioned else ADVICE)
        message = (f"move guard tripped at t = {t:.3f} s: the table ran away from the move, |velocity| "
                   f"{abs(v) * 1e3:.4g} mm/s beyond the move's guard of {self.limit_m_per_s * 1e3:.4g} mm/s "
                   f"({MOVE_GUARD_FACTOR:g} x its speed of {self.speed_m_per_s * 1e3:.4g} mm/s + "
                   f"{MOVE_GUARD_ALLOWANCE_M_PER_S * 1e3:g} mm/s); the valve closed at once; {advice}")
        values = {"time_s": t, "displacement_m": float(rows["measured_displacement_m"][i]),
                  "target_m": float(rows["target_m"][i]), "velocity_m_per_s": v,
                  "voltage_v": float(rows["voltage_v"][i]), "move_speed_m_per_s": self.speed_m_per_s,
                  "limit": self.limit_m_per_s, "limit_name": "velocity_m_per_s", "action": "valve_close"}
        return MoveGuardTrip(MOVE_GUARD, i, t, message, values, "valve_close")


def move_duration_s(start_m: float, end_m: float, speed_m_per_s: float) -> float:
    """How long the move itself takes (without the hold): its peak velocity is ``speed_m_per_s``."""
    return max(MIN_DURATION_S, PEAK_VELOCITY_FACTOR * abs(end_m - start_m) / speed_m_per_s)


def move_target(start_m: float, end_m: float, speed_m_per_s: float = DEFAULT_SPEED_M_PER_S,
                dt_s: float = CONTROL_PERIOD_S) -> HistoryTarget:
    """The minimum-jerk move from ``start_m`` to ``end_m`` at peak velocity ``speed_m_per_s``, then HOLD_S at
    ``end_m``: r, r', r'' at every control period. A speed outside what manual motion allows, or a move that
    would last longer than MAX_DURATION_S, is a MotionError (its arrays are sized by distance / speed)."""
    check_speed(speed_m_per_s)
    move_s = move_duration_s(start_m, end_m, speed_m_per_s)
    if not move_s <= MAX_DURATION_S:
        raise MotionError("speed_m_per_s", speed_m_per_s, f"a move of at most {MAX_DURATION_S:g} s",
                          f"a move from {start_m!r} m to {end_m!r} m at {speed_m_per_s:g} m/s would last "
                          f"{move_s:g} s, longer than the {MAX_DURATION_S:g} s a manual move may last")
    n_move = int(math.ceil(move_s / dt_s))
    n = n_move + int(round(HOLD_S / dt_s)) + 1
    s = np.minimum(np.arange(n) * dt_s / move_s, 1.0)
    d = end_m - start_m
    r = start_m + d * (10 * s ** 3 - 15 * s ** 4 + 6 * s ** 5)
    r_dot = d * (30 * s ** 2 - 60 * s ** 3 + 30 * s ** 4) / move_s
    r_ddot = d * (60 * s - 180 * s ** 2 + 120 * s ** 3) / move_s ** 2
    r_ddot[s >= 1.0] = 0.0
    return HistoryTarget(np.ascontiguousarray(r), np.ascontiguousarray(r_dot), np.ascontiguousarray(r_ddot), dt_s,
                         source=f"manual move {start_m * 1e3:.3f} mm -> {end_m * 1e3:.3f} mm at "
                                f"{speed_m_per_s * 1e3:g} mm/s", scale=1.0, taper_in_s=0.0, taper_out_s=0.0,
                         duration_s=n * dt_s, source_dt_s=dt_s, source_samples=n)
