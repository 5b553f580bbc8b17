"""Manual motion: the table moved from where it rests to a position, at a safe speed, under control.

The target is a minimum-jerk move (quintic: r = r0 + (r1 - r0)(10 s^3 - 15 s^4 + 6 s^5), s = t / T), whose
velocity and acceleration start and end at zero, followed by ``HOLD_S`` at the new position so the loop
settles before the valve closes. Its peak velocity is 1.875 |r1 - r0| / T, so T = 1.875 |r1 - r0| / v_max.
The result is a ``sim.history.HistoryTarget``: the loop runs it as it runs a time history. Its arrays are sized
by distance / speed, so the speed is bounded below as well as above (``MIN_SPEED_M_PER_S`` to
``MAX_SPEED_M_PER_S``) and a move lasts at most ``MAX_DURATION_S``: ``check_move`` (the service, ``isorig move``)
and ``move_target`` itself refuse anything else with a MotionError naming the field and what is allowed.
"""

from __future__ import annotations

import math

import numpy as np

from .errors import FieldError
from .history import HistoryTarget
from .loop import CONTROL_PERIOD_S

HOLD_S = 0.5  # the target rests at the new position this long before the move ends
DEFAULT_SPEED_M_PER_S = 0.005  # 5 mm/s: a jog speed at which an operator can follow the table by eye
MIN_SPEED_M_PER_S = 0.001  # 1 mm/s: slower asks for a target table sized by distance / speed (1e-178 m/s: 500)
MAX_SPEED_M_PER_S = 0.05  # manual motion is never faster than 50 mm/s
MIN_DURATION_S = 0.2  # even a tiny move lasts this long (a step would hit the oil column)
MAX_DURATION_S = 600.0  # and no move lasts longer (its target holds r, r', r'' per period: 14 MB at 1 kHz)
SPEED_RANGE = (f"[{MIN_SPEED_M_PER_S:g}, {MAX_SPEED_M_PER_S:g}] m/s "
               f"({MIN_SPEED_M_PER_S * 1e3:g} to {MAX_SPEED_M_PER_S * 1e3:g} mm/s)")
PEAK_VELOCITY_FACTOR = 1.875  # max of d/ds (10 s^3 - 15 s^4 + 6 s^5), at s = 1/2


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
