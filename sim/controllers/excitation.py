"""The commissioning excitation: a bounded motion that shows the rig's valve, oil column and table.

Not a test controller (it is not offered for tests): ``isorig identify rig`` (sim.commission) runs it through
the same closed loop, detectors and stop paths as a test, then fits the rig's parameters to what it
measured. It assumes nothing about the valve: the declared dead zone, gain and null may be wrong by a volt or
a factor, so it finds them first, with the table moving slowly.

Phases (the target r is the table's resting position y0, held constant; the guard bounds are around it):

0. **Valve null.** A valve's null is not at 0 V: a coil bias of 0.1-0.2 V on an underlapped valve, whose
   small-signal gain is high, runs a table off at 10-40 mm/s with 0 V commanded (foreign rigs 2, 12, 51, 54:
   the old sweeps, which began at 0 V, were stopped at the velocity or stroke bound within 0.02-0.4 s). A gentle
   position hold (``null_gain_v_per_m``, its integral ``null_integral_per_s`` and a velocity damping
   ``null_damping_v_s_per_m``, low enough for the most sensitive valve the campaign met) holds the table where
   it rested until it has been still for ``null_still_s`` (or ``null_max_s`` have passed); its integral is then
   the command at which the table rests, and the sweeps start there instead of at 0 V.
1. **Valve sweeps.** The command ramps from inside the dead zone outwards, at ``ramp_v_per_s``, until the
   measured velocity (the position's difference over 5 periods, what the velocity detector reads) reaches this
   sweep's level, or the table is ``guard_m`` from y0, or the command reaches ``max_command_v``. Then the
   command steps back inside the dead zone and the next sweep goes the other way, at the next level. Once
   the table has rested 20 ms (it rings as the last sweep's valve closes), the command at which it started
   to move (``velocity_start_m_per_s``) is the valve's opening edge in
   that direction; the next sweep in that direction starts just inside it. Once the valve is open the ramp
   is ``open_ramp_share`` times faster (the velocity rises quickly; the table stays within the guard).
   A run whose sweeps do not find the valve both ways rests at the last command where the table rested.
   The sweeps learn the rig as they go: where the table went on past a sweep's level after the sweep ended, the
   next levels are lowered so that the same overshoot stays within the bound (``_sweep_level``).
2. **Dither**, until ``sweep_max_s + dither_s`` (it takes the time the sweeps did not need): a position hold
   (``hold_gain_per_s``) plus a multisine velocity demand (log-spaced lines, whole multiples of the lowest;
   Schroeder phases, so its peak is low) through the valve inverse the sweeps found (edges and slopes each
   way). It begins with 0.3 s of closed valve (the last sweep may end moving, at the guard) and the hold's demand
   limited as the return's while the dither fades in. A gate scales the dither: it halves whenever the measured
   velocity passes the gate's share of the velocity bound or the table passes the guard, and recovers over
   ``gate_recovery_s`` only while both stay below 85 % of those.
3. **Return.** The hold alone brings the table back to y0 (the velocity demand limited) and keeps it there
   to the end of the run. If the sweeps could not find the valve both ways, the command rests instead.

Report: model_m = y0; ar_hat = the dither's gate (0-1); ay_hat = half the distance between the two edges
found (the dead zone seen from the command, V); as_hat = the phase (4 valve null, 0 sweeps, 1 dither, 2 return,
3 rest: the codes 0-3 came first).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from .base import (
    M_POSITION,
    M_TARGET,
    M_TIME,
    R_AR,
    R_AS,
    R_AY,
    R_MODEL,
    Adapted,
    Controller,
    Option,
    check_options,
)

KIND = 4
MAX_LINES = 64
MAX_SWEEPS = 16

(P_GUARD, P_RAMP, P_OPEN_SHARE, P_VSTART, P_UMAX, P_NSWEEP, P_MARGIN, P_HOLD, P_T_DITHER, P_T_RETURN,
 P_GATE_V, P_GATE_REC, P_RET_V, P_DZ_RAMP_V, P_NLINES, P_SWEEP_MAX_S, P_NULL_KP, P_NULL_KI, P_NULL_KD, P_NULL_MAX_S,
 P_NULL_STILL) = range(21)
P_VMAX = 21  # max_velocity_m_per_s (m/s)
P_LEVELS = 22  # MAX_SWEEPS velocity levels (m/s), one per sweep
P_FREQ = P_LEVELS + MAX_SWEEPS  # line frequencies (Hz)
P_AMP = P_FREQ + MAX_LINES  # line velocity amplitudes (m/s)
P_PHASE = P_AMP + MAX_LINES  # line phases (rad)
N_PARAMS = P_PHASE + MAX_LINES

(S_STARTED, S_PHASE, S_DIR, S_SWEEP, S_U, S_OPENED, S_EDGE_P, S_EDGE_N, S_UHI_P, S_UHI_N, S_VHI_P, S_VHI_N,
 S_GATE, S_T_PHASE, S_LAST_CUT, S_HEAD, S_HOLD) = range(17)  # S_HOLD: 1 once the valve is known (the rest holds)
S_QUIET = 17  # periods the table has been at rest since this sweep began
S_RING = 18  # the last 6 position readings (velocity over 5 periods)
S_U_REST = S_RING + 6  # the last command at which the table rested (where a run whose valve is not known rests)
S_NULL = S_U_REST + 1  # the valve null's integral: the command at which the table rests (V)
S_T_SWEEP = S_NULL + 1  # when this sweep began (s)
S_RAMPING = S_T_SWEEP + 1  # 1 once this sweep's ramp has begun
# what the sweeps learn of the rig (``_sweep_level``): the level and direction of the sweep that ended last, the
# peak velocity the table reached that way after it ended (m/s), and the largest peak over level seen so far
S_LEVEL_ENDED, S_DIR_ENDED, S_PEAK, S_OVERSHOOT = S_RAMPING + 1, S_RAMPING + 2, S_RAMPING + 3, S_RAMPING + 4
N_STATE = S_OVERSHOOT + 1

PHASE_SWEEP, PHASE_DITHER, PHASE_RETURN, PHASE_REST, PHASE_NULL = 0.0, 1.0, 2.0, 3.0, 4.0

OPTIONS = {
    "guard_m": Option(0.0015, 1e-5, 0.05, "m", meaning="the sweeps and the dither keep the table within this of "
                      "where it rested"),
    "max_velocity_m_per_s": Option(0.02, 1e-4, 0.5, "m/s", meaning="the largest velocity the excitation aims at; "
                                   "the sweep levels and the gate are shares of it"),
    "ramp_v_per_s": Option(1.0, 0.01, 20.0, "V/s", meaning="how fast a sweep's command ramps before the valve opens"),
    "open_ramp_share": Option(3.0, 1.0, 20.0, "-", meaning="... and this many times faster once it has opened (times "
                              "max_velocity_m_per_s / 20 mm/s below 20 mm/s: the velocity must not outrun the guard)"),
    "velocity_start_share": Option(0.05, 0.005, 0.5, "-", meaning="the table has started to move (the valve's edge) "
                                   "when its measured velocity passes this share of max_velocity_m_per_s"),
    "max_command_v": Option(4.0, 0.1, 10.0, "V", meaning="a sweep never commands more than this"),
    "null_gain_v_per_m": Option(100.0, 0.0, 1e4, "V/m", meaning="valve null: the hold's command per metre the table "
                                "is off where it rested"),
    "null_integral_per_s": Option(4.0, 0.0, 100.0, "1/s", meaning="valve null: the hold's integral rate (the "
                                  "command it adds per second, per volt of its proportional command)"),
    "null_damping_v_s_per_m": Option(3.0, 0.0, 100.0, "V s/m", meaning="valve null: the hold's command per m/s of "
                                     "the table's measured velocity, against it"),
    "null_still_s": Option(0.2, 0.0, 5.0, "s", meaning="valve null: it ends once the table has been still this long "
                           "(below the velocity at which a sweep takes an edge, within a fifth of the guard)"),
    "null_max_s": Option(2.0, 0.0, 10.0, "s", meaning="valve null: it ends after this time at the latest"),
    "sweeps": Option(6, 2, MAX_SWEEPS, "-", "int", "valve sweeps, alternately each way"),
    "edge_margin_v": Option(0.15, 0.0, 2.0, "V", meaning="a sweep starts this far inside the edge found before"),
    "hold_gain_per_s": Option(8.0, 0.1, 100.0, "1/s", meaning="position hold: velocity demand per metre of error"),
    "dither_s": Option(10.0, 0.0, 60.0, "s", meaning="duration of the dither when the sweeps take all of "
                       "sweep_max_s (it runs longer when they end sooner)"),
    "return_s": Option(1.0, 0.1, 10.0, "s", meaning="duration of the return to where the table rested"),
    "gate_velocity_share": Option(0.6, 0.1, 1.0, "-", meaning="the dither halves when the measured velocity passes "
                                  "this share of max_velocity_m_per_s"),
    "gate_recovery_s": Option(2.0, 0.01, 60.0, "s", meaning="the dither's gate recovers from 0 to 1 in this time"),
    "return_velocity_share": Option(0.3, 0.01, 1.0, "-", meaning="the return's velocity demand is limited to this "
                                    "share of max_velocity_m_per_s"),
    "dead_zone_ramp_share": Option(0.02, 1e-4, 1.0, "-", meaning="the valve inverse crosses from one edge to the "
                                   "other over +-this share of max_velocity_m_per_s"),
    "sweep_max_s": Option(8.0, 0.5, 60.0, "s", meaning="the sweeps end after this time at the latest"),
    "dither_min_hz": Option(1.0, 0.05, 50.0, "Hz", meaning="lowest line of the dither (its period is 1 / this)"),
    "dither_max_hz": Option(100.0, 1.0, 400.0, "Hz", meaning="highest line of the dither"),
    "dither_lines": Option(32, 1, MAX_LINES, "-", "int", "number of lines, log-spaced"),
    "dither_corner_hz": Option(10.0, 0.1, 400.0, "Hz", meaning="above this the lines' velocity falls as 1 / f (less "
                               "energy where an oil column may ring)"),
    "dither_velocity_share": Option(0.35, 0.01, 1.0, "-", meaning="the dither's peak velocity demand, share of "
                                    "max_velocity_m_per_s"),
}
QUIET_PERIODS = 20  # a sweep takes the valve's edge only after the table rested this long (20 ms)
SETTLE_WAIT_S = 1.0  # before each sweep the null's hold brings the table to rest, for at most this long
REFERENCE_VELOCITY_M_PER_S = 0.02  # the open ramp's share is meant for this velocity bound
REST_RAMP_SHARE = 0.3  # return and rest: the dead zone is crossed over +-this share of their velocity limit
SWEEP_LEVELS = (0.3, 0.3, 0.5, 0.5, 0.7, 0.7)  # shares of max_velocity_m_per_s; later sweeps repeat the last
#: a sweep's level is lowered so that, at the largest overshoot an earlier sweep showed (its peak velocity after it
#: ended, over its level), its peak stays below this share of max_velocity_m_per_s ...
SWEEP_PEAK_SHARE = 0.85
#: ... but not below this share (the slope of the valve inverse is taken at twice velocity_start_share)
SWEEP_LEVEL_FLOOR_SHARE = 0.15
SETTLE_S = 0.3  # the dither begins with the valve closed this long (the last sweep may end moving, at the guard)
GATE_START = 1.0  # the dither's gate at the start (it fades in over 0.5 s); after a cut it grows back only while
GATE_GROW_SHARE = 0.85  # ... the motion stays below this share of the gate's velocity and of the guard
ADAPTED = (
    Adapted("model_m", "hold position", "m", "where the table rested when the excitation began"),
    Adapted("ar_hat", "dither gate", "-", "the share of the dither applied (it halves near a bound)"),
    Adapted("ay_hat", "dead zone seen", "V", "half the distance between the opening edges found each way"),
    Adapted("as_hat", "phase", "-", "0 valve sweeps, 1 dither, 2 return, 3 rest"),
)


def dither_lines(min_hz: float, max_hz: float, n: int, corner_hz: float) -> tuple[np.ndarray, np.ndarray]:
    """Line frequencies (Hz, whole multiples of ``min_hz``, log-spaced, distinct) and relative velocity
    amplitudes (1 up to ``corner_hz``, corner / f above)."""
    k = np.unique(np.round(np.geomspace(1.0, max_hz / min_hz, n)).astype(int))
    f = k * min_hz
    return f, np.minimum(1.0, corner_hz / f)


def schroeder_phases(amplitudes: np.ndarray) -> np.ndarray:
    """Schroeder's low-crest-factor phases for lines of the given power shares."""
    p = amplitudes ** 2 / np.sum(amplitudes ** 2)
    return -2.0 * np.pi * np.cumsum(np.arange(1, p.size + 1) * p)


def make_excitation(rig=None, **options) -> Controller:
    """The commissioning excitation with its bounds (``rig`` is not used: nothing about the valve is assumed)."""
    o = check_options("excitation", OPTIONS, options)
    v_max = o["max_velocity_m_per_s"]
    p = np.zeros(N_PARAMS)
    p[P_GUARD] = o["guard_m"]
    p[P_RAMP] = o["ramp_v_per_s"]
    p[P_OPEN_SHARE] = max(1.0, o["open_ramp_share"] * min(1.0, v_max / REFERENCE_VELOCITY_M_PER_S))
    p[P_VSTART] = o["velocity_start_share"] * v_max
    p[P_UMAX] = o["max_command_v"]
    p[P_NSWEEP] = o["sweeps"]
    p[P_MARGIN] = o["edge_margin_v"]
    p[P_HOLD] = o["hold_gain_per_s"]
    p[P_T_DITHER] = o["null_max_s"] + o["sweep_max_s"] + o["dither_s"]  # when the dither ends
    p[P_NULL_KP] = o["null_gain_v_per_m"]
    p[P_NULL_KI] = o["null_integral_per_s"]
    p[P_NULL_KD] = o["null_damping_v_s_per_m"]
    p[P_NULL_MAX_S] = o["null_max_s"]
    p[P_NULL_STILL] = o["null_still_s"]
    p[P_T_RETURN] = o["return_s"]
    p[P_GATE_V] = o["gate_velocity_share"] * v_max
    p[P_GATE_REC] = o["gate_recovery_s"]
    p[P_RET_V] = o["return_velocity_share"] * v_max
    p[P_DZ_RAMP_V] = o["dead_zone_ramp_share"] * v_max
    p[P_SWEEP_MAX_S] = o["sweep_max_s"]
    p[P_VMAX] = v_max
    for i in range(MAX_SWEEPS):
        p[P_LEVELS + i] = SWEEP_LEVELS[min(i, len(SWEEP_LEVELS) - 1)] * v_max
    f, rel = dither_lines(o["dither_min_hz"], o["dither_max_hz"], o["dither_lines"], o["dither_corner_hz"])
    phases = schroeder_phases(rel)
    t = np.arange(int(round(1.0 / o["dither_min_hz"] / 1e-4))) * 1e-4  # one period at 0.1 ms: the peak
    peak = np.max(np.abs(np.sum(rel[:, None] * np.cos(2 * np.pi * f[:, None] * t[None, :] + phases[:, None]),
                                axis=0)))
    amp = rel * o["dither_velocity_share"] * v_max / peak
    n = f.size
    p[P_NLINES] = n
    p[P_FREQ:P_FREQ + n] = f
    p[P_AMP:P_AMP + n] = amp
    p[P_PHASE:P_PHASE + n] = phases
    state = np.zeros(N_STATE)
    state[S_EDGE_P] = state[S_EDGE_N] = state[S_UHI_P] = state[S_UHI_N] = np.nan
    state[S_OVERSHOOT] = 1.0
    return Controller("excitation", KIND, p, state, o)


def excitation_duration_s(options: dict) -> float:
    """The excitation's duration (valve null and sweeps at their longest, dither, return) plus a rest of 0.2 s:
    the length of the run's target table."""
    o = check_options("excitation", OPTIONS, options)
    return o["null_max_s"] + o["sweep_max_s"] + o["dither_s"] + o["return_s"] + 0.2


@njit(cache=True, error_model="numpy")
def _ring_velocity(s, y, dt):
    """Push y into the ring of the last 6 readings; the velocity over 5 periods (0 until the ring is full)."""
    head = int(s[S_HEAD])
    s[S_RING + head % 6] = y
    s[S_HEAD] = head + 1
    if head < 5:
        return 0.0
    return (y - s[S_RING + (head - 5) % 6]) / (5.0 * dt)


@njit(cache=True, error_model="numpy")
def _inverse(p, s, v_ff, v_fb):
    """The command for a velocity demand v_ff + v_fb through the valve the sweeps found: each side's slope (V per
    m/s, from the commands at which the table started and at which it reached the sweep's level) and its edge
    (that line taken to zero velocity). The dead zone is crossed over +-P_DZ_RAMP_V of the feed-forward v_ff (the
    dither: sharp) plus +-REST_RAMP_SHARE of the return's velocity of the feedback v_fb (the hold: gentle, else
    the hold's small errors throw the spool across the dead zone, a relay that rings a soft oil column)."""
    v = v_ff + v_fb
    slope_p = (s[S_UHI_P] - s[S_EDGE_P]) / max(s[S_VHI_P] - p[P_VSTART], 1e-6)
    slope_n = (s[S_UHI_N] - s[S_EDGE_N]) / min(s[S_VHI_N] + p[P_VSTART], -1e-6)
    e_p = s[S_EDGE_P] - slope_p * p[P_VSTART]
    e_n = s[S_EDGE_N] + slope_n * p[P_VSTART]
    if e_p < e_n:  # no dead zone: both lines cross zero velocity at their mean
        e_p = e_n = 0.5 * (e_p + e_n)
    x = min(1.0, max(-1.0, v_ff / p[P_DZ_RAMP_V] + v_fb / (REST_RAMP_SHARE * p[P_RET_V])))
    mid = 0.5 * (e_p + e_n)
    half = 0.5 * (e_p - e_n)
    if v >= 0.0:
        return mid + half * x + slope_p * v
    return mid + half * x + slope_n * v


@njit(cache=True, error_model="numpy")
def _null_hold(p, s, error_m, v5, dt):
    """The valve null's hold: proportional, integral and velocity damping; counts the periods the table has been
    still (S_QUIET). The integral is kept within the command the sweeps may use."""
    s[S_NULL] = min(p[P_UMAX], max(-p[P_UMAX], s[S_NULL] + p[P_NULL_KI] * p[P_NULL_KP] * error_m * dt))
    if abs(v5) < p[P_VSTART] and abs(error_m) < 0.2 * p[P_GUARD]:
        s[S_QUIET] += 1.0
    else:
        s[S_QUIET] = 0.0
    return min(p[P_UMAX], max(-p[P_UMAX], s[S_NULL] + p[P_NULL_KP] * error_m - p[P_NULL_KD] * v5))


@njit(cache=True, error_model="numpy")
def _start_sweep(s, direction, t):
    """A sweep begins: the null's hold first (S_RAMPING 0), then the ramp from ``_ramp_start``."""
    s[S_DIR] = direction
    s[S_T_SWEEP] = t
    s[S_RAMPING] = 0.0
    s[S_OPENED] = 0.0
    s[S_QUIET] = 0.0


@njit(cache=True, error_model="numpy")
def _ramp_start(p, s, direction):
    """Where a sweep's ramp starts: the null if this side's edge is not known yet, else just inside that edge;
    never beyond the other side's edge, nor beyond the null where it lies between the two (an underlapped
    valve's edges lie closer to it than the margin)."""
    edge = s[S_EDGE_P] if direction > 0 else s[S_EDGE_N]
    other = s[S_EDGE_N] if direction > 0 else s[S_EDGE_P]
    if np.isnan(edge):
        s[S_U] = s[S_NULL]
    else:
        u = edge - direction * p[P_MARGIN]
        if not np.isnan(other):  # never start beyond the other side's edge
            u = max(u, other) if direction > 0 else min(u, other)
            if min(edge, other) <= s[S_NULL] <= max(edge, other):
                u = max(u, s[S_NULL]) if direction > 0 else min(u, s[S_NULL])
        s[S_U] = u


@njit(cache=True, error_model="numpy")
def _sweep_level(p, s, k):
    """Sweep k's velocity level: SWEEP_LEVELS' share of the bound, lowered where an earlier sweep overshot its own
    (the valve closes a spool lag and a reading late, and the oil column springs back: on heavy, soft foreign rigs
    with high-gain valves the table went on to 1.5-2.2 times a sweep's level and passed the velocity bound), so that
    the largest overshoot seen keeps its peak at SWEEP_PEAK_SHARE of the bound; never below
    SWEEP_LEVEL_FLOOR_SHARE of it."""
    level = p[P_LEVELS + min(k, MAX_SWEEPS - 1)]
    learned = SWEEP_PEAK_SHARE * p[P_VMAX] / s[S_OVERSHOOT]
    return min(level, max(learned, SWEEP_LEVEL_FLOOR_SHARE * p[P_VMAX]))


@njit(cache=True, error_model="numpy")
def excitation_step(p, s, meas, dt, report):
    t = meas[M_TIME]
    y0 = meas[M_TARGET]
    y = meas[M_POSITION]
    v5 = _ring_velocity(s, y, dt)
    if s[S_STARTED] < 0.5:
        s[S_STARTED] = 1.0
        s[S_PHASE] = PHASE_NULL
        s[S_GATE] = 1.0
        s[S_T_PHASE] = t
        s[S_LAST_CUT] = -1.0
    phase = s[S_PHASE]
    u = 0.0
    if phase == PHASE_NULL:
        u = _null_hold(p, s, y0 - y, v5, dt)
        if s[S_QUIET] * dt >= p[P_NULL_STILL] or t - s[S_T_PHASE] >= p[P_NULL_MAX_S]:
            s[S_PHASE] = PHASE_SWEEP
            s[S_T_PHASE] = t
            s[S_U_REST] = s[S_NULL]
            _start_sweep(s, 1.0, t)
    elif phase == PHASE_SWEEP and s[S_RAMPING] < 0.5:
        # before a sweep the null's hold brings the table back to rest where it rested (an underlapped valve's null
        # moves with the load: at a fixed command the specimen's pull would carry the table off)
        u = _null_hold(p, s, y0 - y, v5, dt)
        s[S_PEAK] = max(s[S_PEAK], s[S_DIR_ENDED] * v5)  # how far the last sweep's motion went on after it ended
        if s[S_QUIET] >= QUIET_PERIODS or t - s[S_T_SWEEP] >= SETTLE_WAIT_S:
            s[S_RAMPING] = 1.0
            if s[S_LEVEL_ENDED] > 0.0:
                s[S_OVERSHOOT] = max(s[S_OVERSHOOT], s[S_PEAK] / s[S_LEVEL_ENDED])
            if s[S_QUIET] >= QUIET_PERIODS:
                s[S_U_REST] = s[S_NULL]
            _ramp_start(p, s, s[S_DIR])
    elif phase == PHASE_SWEEP:
        d = s[S_DIR]
        k = int(s[S_SWEEP])
        # the table rings when the last sweep's valve closes (the oil column and the specimen spring back): an
        # edge is taken only once it has been at rest for QUIET_PERIODS since this sweep began
        if abs(v5) < p[P_VSTART]:
            s[S_QUIET] += 1.0
        elif s[S_QUIET] < QUIET_PERIODS:
            s[S_QUIET] = 0.0
        if s[S_QUIET] == QUIET_PERIODS:
            s[S_U_REST] = s[S_U]
        if s[S_OPENED] < 0.5 and s[S_QUIET] >= QUIET_PERIODS and d * v5 > p[P_VSTART]:
            s[S_OPENED] = 1.0
            if d > 0:
                s[S_EDGE_P] = s[S_U]
            else:
                s[S_EDGE_N] = s[S_U]
        level = _sweep_level(p, s, k)
        ended = d * v5 >= level or d * (y - y0) >= p[P_GUARD] or abs(s[S_U]) >= p[P_UMAX]
        if ended:
            s[S_LEVEL_ENDED] = level
            s[S_DIR_ENDED] = d
            s[S_PEAK] = d * v5
            if s[S_OPENED] > 0.5 and d * v5 > 2.0 * p[P_VSTART]:
                if d > 0:
                    s[S_UHI_P] = s[S_U]
                    s[S_VHI_P] = v5
                else:
                    s[S_UHI_N] = s[S_U]
                    s[S_VHI_N] = v5
            s[S_SWEEP] = k + 1
            both = not (np.isnan(s[S_UHI_P]) or np.isnan(s[S_UHI_N]))
            if (k + 1 >= p[P_NSWEEP] and both) or t - s[S_T_PHASE] >= p[P_SWEEP_MAX_S]:
                if both:
                    s[S_PHASE] = PHASE_DITHER
                else:  # the valve did not open both ways: no dither on a valve not known, rest where it rested
                    s[S_PHASE] = PHASE_REST
                    s[S_HOLD] = 0.0
                s[S_T_PHASE] = t
            else:
                _start_sweep(s, -d, t)
        else:
            rate = p[P_RAMP] * (p[P_OPEN_SHARE] if s[S_OPENED] > 0.5 else 1.0)
            s[S_U] += d * rate * dt
        u = s[S_U]
        if s[S_PHASE] != PHASE_SWEEP:
            u = 0.5 * (s[S_EDGE_P] + s[S_EDGE_N]) if s[S_PHASE] == PHASE_DITHER else s[S_U_REST]
    elif phase == PHASE_DITHER:
        tau = t - s[S_T_PHASE]
        if tau < SETTLE_S:  # the valve closed: the table comes to rest where the last sweep left it
            u = 0.5 * (s[S_EDGE_P] + s[S_EDGE_N])
            s[S_GATE] = GATE_START
        else:
            tau -= SETTLE_S
            if (abs(v5) > p[P_GATE_V] or abs(y - y0) > p[P_GUARD]) and t - s[S_LAST_CUT] > 0.02:
                s[S_GATE] *= 0.5
                s[S_LAST_CUT] = t
            elif abs(v5) < GATE_GROW_SHARE * p[P_GATE_V] and abs(y - y0) < GATE_GROW_SHARE * p[P_GUARD]:
                s[S_GATE] = min(1.0, s[S_GATE] + dt / p[P_GATE_REC])
            ramp_in = min(1.0, tau / 0.5)  # the dither fades in over 0.5 s
            dither = 0.0
            for i in range(int(p[P_NLINES])):
                dither += p[P_AMP + i] * math.cos(2.0 * math.pi * p[P_FREQ + i] * tau + p[P_PHASE + i])
            # the hold's demand limited as the return's while the dither fades in (the last sweep may have left
            # the table at the guard: the hold must not throw it back), then to the gate's velocity
            limit = p[P_RET_V] if tau < 0.5 else p[P_GATE_V]
            hold = min(limit, max(-limit, p[P_HOLD] * (y0 - y)))
            u = _inverse(p, s, s[S_GATE] * ramp_in * dither, hold)
        if t >= p[P_T_DITHER]:
            s[S_PHASE] = PHASE_RETURN
            s[S_T_PHASE] = t
    elif phase == PHASE_RETURN or (phase == PHASE_REST and s[S_HOLD] != 0.0):
        u = _inverse(p, s, 0.0, min(p[P_RET_V], max(-p[P_RET_V], p[P_HOLD] * (y0 - y))))
        if phase == PHASE_RETURN and t - s[S_T_PHASE] >= p[P_T_RETURN]:
            s[S_PHASE] = PHASE_REST
            s[S_T_PHASE] = t
            s[S_HOLD] = 1.0  # the valve is known: the hold goes on
    else:
        u = s[S_U_REST]
    report[R_MODEL] = y0
    report[R_AR] = s[S_GATE] if s[S_PHASE] == PHASE_DITHER else 0.0
    if np.isnan(s[S_EDGE_P]) or np.isnan(s[S_EDGE_N]):
        report[R_AY] = np.nan
    else:
        report[R_AY] = 0.5 * (s[S_EDGE_P] - s[S_EDGE_N])
    report[R_AS] = s[S_PHASE]
    return u
