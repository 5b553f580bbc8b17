"""The closed loop: one control period, the same compiled code for the offline engine and the live worker.

Each period ``control_period`` takes the rig's measurement, takes the target r(t) from the sine blocks
(sim.profiles) or from a table of (r, r', r'') per period (a time history, or a hybrid simulation's commands
written one period ahead),
steps the controller (sim.controllers), saturates the command at the rig's limit (a non-finite command
becomes 0 V: the only saturation and NaN guard of the project) and writes the period's row (sim.samples).
``ClosedLoop`` holds what a test's loop needs (profile, controller and its state, command limit, period
count) and the two ways a test ends early, both above any rig driver so that every driver gets them:

- ``ramp_out()``: the operator's stop. The running sine block tapers to zero over ``taper_cycles`` (at
  least one cycle) from the next whole cycle; the controller stays in the loop. A table's target fades out
  over ``FADE_S`` with a raised cosine instead.
- ``begin_command_ramp()``: a controlled stop after a limit trip. The controller is no longer trusted:
  the command ramps linearly from its last value to zero over ``COMMAND_RAMP_S`` (open loop, no target).

The offline engine runs many periods in one compiled call (sim.plant); a real rig runs them one at a time
through ``ClosedLoop.step(measurement)``. Both call ``control_period``.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from .controllers import Controller, controller_step
from .controllers.base import (
    M_HOLD_LEARNING,
    M_LOAD_PRESSURE,
    M_POSITION,
    M_SUPPLY_PRESSURE,
    M_TARGET,
    M_TARGET_RATE,
    M_TIME,
    N_MEAS,
    N_REPORT,
)
from .measurement import (
    FLAG_BRAKE,
    FLAG_GUARD,
    FLAG_LEARNING_HELD,
    FLAG_LOST,
    FLAG_OPEN_LOOP,
    FLAG_PREDICTED,
    Measurement,
)
from .profiles import (
    B_CYCLES,
    B_FREQUENCY,
    B_START,
    B_TAPER,
    N_BLOCK_COLUMNS,
    SineProfile,
    pack_profile,
    profile_duration_s,
    target,
)
from .samples import (
    _AR,
    _AS,
    _AY,
    _FLAGS,
    _FLOW,
    _FORCE,
    _MODEL,
    _PL,
    _PS,
    _TARGET,
    _TIME,
    _U,
    _URAW,
    _VALVE,
    _VEL,
    _Y,
    _YMEAS,
    N_FIELDS,
    Samples,
)

CONTROL_PERIOD_S = 1.0e-3
COMMAND_RAMP_S = 0.1  # controlled stop: the valve command ramps from its last value to zero in this time
FADE_S = 1.0  # an operator's stop of a time history: the target fades to zero over this time
NO_TABLE = np.zeros((0, 3))
NO_BLOCKS = np.zeros((1, N_BLOCK_COLUMNS))

BRAKE_HOLD_S = 0.5  # a controlled stop holds the table at rest this long, under control, before the test ends
BRAKE_MIN_ACCELERATION_M_PER_S2 = 0.5  # the braking deceleration is at least this ...
BRAKE_TARGET_FACTOR = 2.0  # ... and at least this many times the test's own largest target acceleration
BRAKE_HARDEST_FACTOR = 8.0  # to stay within a bound, a stop brakes up to this many times harder

# Loop parameters and state (packed for compiled code).
L_DT, L_ULIM, L_GUARD_M, L_BRAKE_A, L_ERROR_DECAY = range(5)  # L_ERROR_DECAY: exp(-dt / RECENT_ERROR_S)
N_LOOP_PARAMS = 5
(LS_MODE, LS_RAMP_U0, LS_RAMP_K0, LS_RAMP_N, LS_LAST_U, LS_BRAKE_K0, LS_BRAKE_R0, LS_BRAKE_V0, LS_BRAKE_N,
 LS_RECENT_ERROR, LS_HOME_M, LS_RETURN_N, LS_LAST_ERROR, LS_HOLD_UNTIL, LS_LOST_RUN) = range(15)
N_LOOP_STATE = 15
#: a run of n periods lost (the host stalled, the link went silent: the rig held the last command, the controller ran
#: on predicted readings) holds the controller's learning for 5 n periods after it: the table's error then is the
#: stall's, and the learning law took it for the cycle's. 15 periods lost every 0.7 s (sim path, 10 mm 2 Hz): last
#: two cycles 0.47 % -> 0.27 %. A command that was only late (COMMAND_MISSED without a lost measurement: a round
#: trip longer than a period flags every period) holds nothing
HELD_PERIODS_PER_LOST = 5.0
RETURN_SPEED_M_PER_S = 0.01  # a stop that brings the table home moves it at most this fast ...
RETURN_MIN_S = 0.5  # ... and takes at least this long
RECENT_ERROR_S = 0.5  # the guard's margin: the recent peak |y - r|, forgotten with this time constant ...
GUARD_MIN_MARGIN_M = 2e-5  # ... and at least this (what a braking servo overshoots its rest point by)
MODE_CLOSED, MODE_RAMP, MODE_BRAKE = 0.0, 1.0, 2.0


@njit(cache=True, error_model="numpy")
def brake_periods(v0, a, dt):
    """Periods of a braking stop from speed |v0| at peak deceleration a: the speed falls as a raised cosine
    over T = pi |v0| / (2 a) (its peak deceleration), rounded up to whole periods."""
    if a <= 0.0:
        return 1
    return max(1, int(math.ceil(math.pi * abs(v0) / (2.0 * a) / dt - 1e-9)))


@njit(cache=True, error_model="numpy")
def brake_rest_m(r0, v0, n, dt):
    """Where a braking stop from (r0, v0) over n periods comes to rest: r0 + v0 n dt / 2."""
    return r0 + 0.5 * v0 * n * dt


@njit(cache=True, error_model="numpy")
def brake_target(k, ls, dt):
    """The target of a braking stop in period k: speed v0 (1 + cos(pi j / n)) / 2 for j = k - k0 in [0, n], the
    position its integral; at rest from n on. Continuous in position and speed with the target it replaced."""
    j = k - ls[LS_BRAKE_K0]
    n = ls[LS_BRAKE_N]
    r0, v0 = ls[LS_BRAKE_R0], ls[LS_BRAKE_V0]
    if j >= n:
        rest = brake_rest_m(r0, v0, n, dt)
        m = ls[LS_RETURN_N]
        if m <= 0.0:
            return rest, 0.0
        i = j - n  # then home along a raised cosine over m periods
        if i >= m:
            return ls[LS_HOME_M], 0.0
        d = ls[LS_HOME_M] - rest
        x = math.pi * i / m
        return rest + 0.5 * d * (1.0 - math.cos(x)), 0.5 * d * math.pi / (m * dt) * math.sin(x)
    x = math.pi * j / n
    return r0 + v0 * (0.5 * j * dt + n * dt / (2.0 * math.pi) * math.sin(x)), 0.5 * v0 * (1.0 + math.cos(x))


@njit(cache=True, error_model="numpy")
def begin_brake(k, r0, v0, a, ls, dt):
    ls[LS_MODE] = MODE_BRAKE
    ls[LS_BRAKE_K0] = k
    ls[LS_BRAKE_R0] = r0
    ls[LS_BRAKE_V0] = v0
    ls[LS_BRAKE_N] = brake_periods(v0, a, dt)


@njit(cache=True, error_model="numpy")
def guard_trips(r, rdot, lp, margin_m):
    """The displacement guard: would a braking stop that begins one period from now bring the target to rest
    closer than ``margin_m`` (the table's recent tracking error) to +-L_GUARD_M, or beyond? Then the stop
    must begin now: the table, which follows the target within that error, stays within the limit."""
    guard, a, dt = lp[L_GUARD_M], lp[L_BRAKE_A], lp[L_DT]
    if not (a > 0.0 and np.isfinite(guard)):
        return False
    ahead = r + rdot * dt
    return abs(brake_rest_m(ahead, rdot, brake_periods(rdot, a, dt), dt)) > guard - margin_m


@njit(cache=True, error_model="numpy")
def note_error(position_m, r, ls, decay):
    """Keep the recent peak |y - r| (LS_RECENT_ERROR): it decays by ``decay`` (exp(-dt / RECENT_ERROR_S), computed
    once per loop, not per period) each period."""
    e = abs(position_m - r)
    decayed = ls[LS_RECENT_ERROR] * decay
    ls[LS_RECENT_ERROR] = e if e > decayed else decayed


@njit(cache=True, error_model="numpy")
def hold_learning(k, status, ls):
    """1.0 while period k is within a run of lost periods or its settling (HELD_PERIODS_PER_LOST per period of the
    run), else 0.0."""
    if status & FLAG_LOST:
        ls[LS_LOST_RUN] += 1.0
        ls[LS_HOLD_UNTIL] = max(ls[LS_HOLD_UNTIL], k + 1.0 + HELD_PERIODS_PER_LOST * ls[LS_LOST_RUN])
    else:
        ls[LS_LOST_RUN] = 0.0
    return 1.0 if k < ls[LS_HOLD_UNTIL] else 0.0


@njit(cache=True, error_model="numpy")
def saturate(u_raw, limit):
    """The command applied: u_raw clipped to +-limit; a non-finite command becomes 0 V."""
    if not np.isfinite(u_raw):
        return 0.0
    return min(max(u_raw, -limit), limit)


@njit(cache=True, error_model="numpy", inline="always")
def control_period(k, position_m, force_n, load_pressure_pa, supply_pressure_pa, status, lp, ls, kind, cparams,
                   cstate, blocks, table, meas, report, row):
    """One control period k from a measurement; fills ``row`` and returns the command in volts.

    The target comes from ``table`` (rows r, r', r'' per period; the last row holds beyond its end) when it
    has rows, else from the sine ``blocks``.

    ``row`` receives the controller's side of the period (time, target, model, command, adapted
    parameters) and the measurement; the plant-only fields (velocity, flow, valve) are left NaN and the
    displacement is the reading, for the caller to overwrite where the true state is known.
    """
    dt = lp[L_DT]
    t = k * dt
    flags = status
    if ls[LS_MODE] == MODE_RAMP:
        j = k - ls[LS_RAMP_K0] + 1.0
        n = ls[LS_RAMP_N]
        u_raw = ls[LS_RAMP_U0] * (1.0 - j / n) if j < n else 0.0
        r = np.nan
        for i in range(N_REPORT):
            report[i] = np.nan
        flags |= FLAG_OPEN_LOOP
    else:
        if ls[LS_MODE] == MODE_BRAKE:
            r, rdot = brake_target(k, ls, dt)
            flags |= FLAG_BRAKE
        else:
            if table.shape[0] > 0:
                i = k if k < table.shape[0] else table.shape[0] - 1
                r = table[i, 0]
                rdot = table[i, 1]
            else:
                r, rdot = target(t, blocks)
            if np.isfinite(position_m) and np.isfinite(r) and not status & FLAG_PREDICTED:
                note_error(position_m, r, ls, lp[L_ERROR_DECAY])
            # the target would carry the table past the limit: brake now
            if guard_trips(r, rdot, lp, ls[LS_RECENT_ERROR] + GUARD_MIN_MARGIN_M):
                begin_brake(k, r, rdot, lp[L_BRAKE_A], ls, dt)
                flags |= FLAG_BRAKE | FLAG_GUARD
        seen = position_m
        if status & FLAG_PREDICTED:  # a lost period: the target less the last measured error, not the old reading
            seen = r - ls[LS_LAST_ERROR]
        elif np.isfinite(position_m) and np.isfinite(r):
            ls[LS_LAST_ERROR] = r - position_m
        meas[M_TIME] = t
        meas[M_TARGET] = r
        meas[M_TARGET_RATE] = rdot
        meas[M_POSITION] = seen
        meas[M_LOAD_PRESSURE] = load_pressure_pa
        meas[M_SUPPLY_PRESSURE] = supply_pressure_pa
        meas[M_HOLD_LEARNING] = hold_learning(k, status, ls)
        if meas[M_HOLD_LEARNING]:
            flags |= FLAG_LEARNING_HELD
        u_raw = controller_step(kind, cparams, cstate, meas, dt, report)
    u = saturate(u_raw, lp[L_ULIM])
    ls[LS_LAST_U] = u
    row[_TIME] = t
    row[_TARGET] = r
    row[_MODEL] = report[0]
    row[_Y] = position_m
    row[_U] = u
    row[_FORCE] = force_n
    row[_PL] = load_pressure_pa
    row[_AR] = report[1]
    row[_AY] = report[2]
    row[_AS] = report[3]
    row[_VEL] = np.nan
    row[_FLOW] = np.nan
    row[_URAW] = u_raw
    row[_VALVE] = np.nan
    row[_YMEAS] = position_m
    row[_PS] = supply_pressure_pa
    row[_FLAGS] = flags
    return u


def ramp_out_profile(blocks: np.ndarray, t_now_s: float, dt_s: float = CONTROL_PERIOD_S) -> tuple[np.ndarray, int]:
    """The packed profile with the running sine block ending smoothly from now, and the new end period.

    The block's cycle count is cut to the first whole cycle at least one taper (>= 1 cycle) after now (or
    kept, if the block is already tapering out), and later blocks are dropped; the raised-cosine taper-out
    of sim.profiles does the rest, so the target and its rate stay continuous. Returns ``(blocks, total_periods)``.
    """
    for i in range(blocks.shape[0]):
        f = blocks[i, B_FREQUENCY]
        end = blocks[i, B_START] + blocks[i, B_CYCLES] / f
        if t_now_s < end:
            tau = (t_now_s - blocks[i, B_START]) * f
            taper = blocks[i, B_TAPER]
            if taper < 1.0 and tau >= 1.0:
                taper = 1.0  # an untapered block still ramps out over one cycle
            cycles = math.ceil(tau + max(taper, 1.0) - 1e-9)
            if cycles >= blocks[i, B_CYCLES]:  # already inside this block's own taper-out: finish it
                cycles, taper = blocks[i, B_CYCLES], blocks[i, B_TAPER]
            new = blocks[: i + 1].copy()
            new[i, B_CYCLES] = cycles
            new[i, B_TAPER] = taper
            return new, int(round((blocks[i, B_START] + cycles / f) / dt_s))
    total = int(round((blocks[-1, B_START] + blocks[-1, B_CYCLES] / blocks[-1, B_FREQUENCY]) / dt_s))
    return blocks, total


def fade_table(table: np.ndarray, k0: int, n: int, period_s: float = CONTROL_PERIOD_S) -> None:
    """Multiply the target of ``table`` from row k0 by a raised cosine that falls from 1 to 0 over n rows (and
    zero after), keeping r' and r'' the derivatives of the faded r (product rule). In place."""
    n = max(1, int(n))
    k1 = min(table.shape[0], k0 + n)
    if k0 >= table.shape[0]:
        return
    x = (np.arange(k0, k1) - k0 + 1) / n  # the fade's last row is exactly 0
    rate = 1.0 / (n * period_s)
    w = 0.5 * (1.0 + np.cos(np.pi * x))
    dw = -0.5 * np.pi * np.sin(np.pi * x) * rate
    ddw = -0.5 * np.pi ** 2 * np.cos(np.pi * x) * rate ** 2
    r, rd, rdd = table[k0:k1, 0].copy(), table[k0:k1, 1].copy(), table[k0:k1, 2].copy()
    table[k0:k1, 0] = w * r
    table[k0:k1, 1] = w * rd + dw * r
    table[k0:k1, 2] = w * rdd + 2.0 * dw * rd + ddw * r
    table[k1:] = 0.0


class ClosedLoop:
    """A test's loop: target (sine profile or table), controller and its state, command limit, and where it
    stands.

    ``period`` is the next control period to run. ``step(measurement)`` runs one period (the path of a
    real rig); sim.plant runs many periods in one compiled call on the same arrays. With ``table`` (an
    (n, 3) array of r, r', r'' in m, m/s, m/s2 per period) the target is the table's and the test lasts n
    periods; ``profile`` is then ignored.
    """

    def __init__(self, profile: list[SineProfile], controller: Controller, command_limit_v: float,
                 control_period_s: float = CONTROL_PERIOD_S, table: np.ndarray | None = None):
        if not (math.isfinite(command_limit_v) and command_limit_v > 0):
            raise ValueError(f"command_limit_v = {command_limit_v!r} must be a positive number of volts")
        if table is not None:
            table = np.ascontiguousarray(table, dtype=np.float64)
            if table.ndim != 2 or table.shape[1] != 3 or table.shape[0] == 0:
                raise ValueError(f"a target table has one row (r, r', r'') per period; got shape {table.shape}")
        self.table = NO_TABLE if table is None else table
        self.profile = list(profile) if table is None else []
        self.blocks = pack_profile(self.profile) if table is None else NO_BLOCKS
        self.controller = controller
        self.controller_state = controller.new_state()
        self.control_period_s = float(control_period_s)
        self.params = np.array([self.control_period_s, float(command_limit_v), math.inf, 0.0,
                                math.exp(-self.control_period_s / RECENT_ERROR_S)])
        self.state = np.zeros(N_LOOP_STATE)
        self.period = 0
        self.total_periods = (self.table.shape[0] if table is not None
                              else int(round(profile_duration_s(self.profile) / self.control_period_s)))
        self._stopping = False  # the operator's ramp-out (or a braking stop) is under way
        self.last_measurement: Measurement | None = None
        self._meas = np.empty(N_MEAS)
        self._report = np.full(N_REPORT, np.nan)

    # --- where the loop stands --------------------------------------------------------------------------
    @property
    def command_limit_v(self) -> float:
        return float(self.params[L_ULIM])

    @property
    def time_s(self) -> float:
        return self.period * self.control_period_s

    @property
    def ramping(self) -> bool:
        """A controlled stop (command ramp to zero, open loop) is under way."""
        return self.state[LS_MODE] == MODE_RAMP

    @property
    def stopping(self) -> bool:
        """The test is ending early under control: an operator's ramp-out or a braking stop (the latter may
        begin inside compiled code, at the displacement guard)."""
        return self._stopping or self.braking

    @stopping.setter
    def stopping(self, value: bool) -> None:
        self._stopping = bool(value)

    @property
    def braking(self) -> bool:
        """A braking stop (the target comes to rest, the controller in the loop) is under way."""
        return self.state[LS_MODE] == MODE_BRAKE

    @property
    def end_period(self) -> int:
        if self.ramping:
            return int(self.state[LS_RAMP_K0] + self.state[LS_RAMP_N])
        if self.braking:
            return int(self.state[LS_BRAKE_K0] + self.state[LS_BRAKE_N] + self.state[LS_RETURN_N]) + int(
                round(BRAKE_HOLD_S / self.control_period_s))
        return self.total_periods

    @property
    def done(self) -> bool:
        return self.period >= self.end_period

    def remaining(self, n_periods: int) -> int:
        """How many of the next n periods the loop still runs."""
        return max(0, min(int(n_periods), self.end_period - self.period))

    @property
    def start_target_m(self) -> float:
        """Where the target begins (m): where the table must rest when the loop starts."""
        if self.table.shape[0]:
            return float(self.table[0, 0])
        return float(target(0.0, self.blocks)[0]) if self.blocks.shape[0] else 0.0

    @property
    def last_command_v(self) -> float:
        return float(self.state[LS_LAST_U])

    # --- the two early ends ----------------------------------------------------------------------------
    def ramp_out(self) -> float:
        """Operator stop: taper the target out from the next whole cycle (a table: fade it out over
        ``FADE_S``); returns the new end time in s."""
        if not self.stopping and not self.ramping:
            self.stopping = True
            if self.table.shape[0]:
                n = int(round(FADE_S / self.control_period_s))
                fade_table(self.table, self.period, n, self.control_period_s)
                self.total_periods = min(self.period + n, self.total_periods)
            else:
                self.blocks, total = ramp_out_profile(self.blocks, self.time_s, self.control_period_s)
                self.total_periods = min(total, self.total_periods)
        return self.end_period * self.control_period_s

    @property
    def brake_rest_m(self) -> float:
        """Where the braking stop under way comes to rest (m)."""
        st = self.state
        return float(brake_rest_m(st[LS_BRAKE_R0], st[LS_BRAKE_V0], st[LS_BRAKE_N], self.control_period_s))

    def max_target_acceleration(self) -> float:
        """The largest |r''| the test's target asks for (m/s2): A (2 pi f)^2 over the sine blocks, or the table's."""
        if self.table.shape[0]:
            return float(np.max(np.abs(self.table[:, 2]))) if self.table.shape[0] else 0.0
        return max((b.amplitude_m * (2 * math.pi * b.frequency_hz) ** 2 for b in self.profile), default=0.0)

    def guard_displacement(self, limit_m: float, acceleration_m_per_s2: float | None = None) -> float:
        """From now on, the target never carries the table past +-``limit_m``: when a braking stop that began
        one period later would come to rest beyond it, the stop begins (``brake``; flagged FLAG_GUARD). The
        deceleration: ``acceleration_m_per_s2``, or the larger of BRAKE_MIN_ACCELERATION_M_PER_S2 and
        BRAKE_TARGET_FACTOR times the test's own largest target acceleration (a sine of amplitude A within
        the limit never trips it: its rest point stays within A while the deceleration is at least
        pi A w^2 / 2). Returns the deceleration in m/s2."""
        if not (math.isfinite(limit_m) and limit_m > 0):
            raise ValueError(f"limit_m = {limit_m!r} must be a positive number of metres")
        a = acceleration_m_per_s2 or max(BRAKE_MIN_ACCELERATION_M_PER_S2,
                                         BRAKE_TARGET_FACTOR * self.max_target_acceleration())
        self.params[L_GUARD_M] = float(limit_m)
        self.params[L_BRAKE_A] = float(a)
        return float(a)

    def brake(self, within_m: float = math.inf, home_m: float | None = None) -> float:
        """A controlled stop: from this period on the target comes to rest along a braking curve from where it
        is (position and speed; a sine does not go on) and holds there BRAKE_HOLD_S, the controller in the loop.
        The deceleration is raised where needed so that the rest point stays within +-``within_m`` and the
        displacement guard (less the recent tracking error). ``home_m``: from the rest point the target then
        goes to ``home_m`` (a raised cosine, at most RETURN_SPEED_M_PER_S) before the hold: the service's
        shutdown leaves the table where the test began. A stop already braking only gains the return home.
        Returns the end time in s."""
        if self.braking and home_m is not None and self.state[LS_RETURN_N] == 0.0:
            if self.period > self.state[LS_BRAKE_K0] + self.state[LS_BRAKE_N]:  # already at rest: home from here
                begin_brake(self.period, self.brake_rest_m, 0.0, 1.0, self.state, self.control_period_s)
            self._return_home(home_m)
        if self.ramping or self.braking:
            return self.end_period * self.control_period_s
        k, dt = self.period, self.control_period_s
        if self.table.shape[0]:
            i = min(k, self.table.shape[0] - 1)
            r0, v0 = float(self.table[i, 0]), float(self.table[i, 1])
        elif self.blocks.shape[0]:
            r0, v0 = (float(x) for x in target(k * dt, self.blocks))
        else:
            r0, v0 = 0.0, 0.0
        a = self.params[L_BRAKE_A] or max(BRAKE_MIN_ACCELERATION_M_PER_S2, BRAKE_TARGET_FACTOR *
                                         self.max_target_acceleration())
        guard = min(self.params[L_GUARD_M], within_m)
        if r0 * v0 > 0 and math.isfinite(guard):  # moving outwards: the room left, less the recent error
            room = guard - self.state[LS_RECENT_ERROR] - GUARD_MIN_MARGIN_M - abs(r0)
            if room <= 0.0:
                room = guard - abs(r0)  # the margin cannot be kept: at least the bound
            need = math.pi * v0 * v0 / (4.0 * room) if room > 0.0 else math.inf
            a = max(a, min(need, BRAKE_HARDEST_FACTOR * a))
        begin_brake(k, r0, v0, a, self.state, dt)
        self.stopping = True
        if home_m is not None:
            self._return_home(home_m)
        return self.end_period * dt

    def _return_home(self, home_m: float) -> None:
        distance = abs(float(home_m) - self.brake_rest_m)
        duration_s = max(RETURN_MIN_S, math.pi / 2.0 * distance / RETURN_SPEED_M_PER_S)
        self.state[LS_HOME_M] = float(home_m)
        self.state[LS_RETURN_N] = float(max(1, int(math.ceil(duration_s / self.control_period_s))))

    def set_target(self, period: int, r_m: float, r_dot_m_per_s: float, r_ddot_m_per_s2: float = 0.0) -> None:
        """Write the target of a coming period into the table (a hybrid simulation computes each command one
        period ahead). Only for a loop built with a table."""
        if period < self.period:
            raise ValueError(f"period {period} has run already (the loop is at {self.period})")
        self.table[period] = (r_m, r_dot_m_per_s, r_ddot_m_per_s2)

    def begin_command_ramp(self, duration_s: float = COMMAND_RAMP_S, at_once: bool = False) -> None:
        """Controlled stop: from this period on, the command ramps from its last value to zero, open loop
        (``at_once``: it is zero from this period on; the last value came from a reading not to be trusted)."""
        if self.ramping:
            return
        self.state[LS_MODE] = MODE_RAMP
        self.state[LS_RAMP_U0] = 0.0 if at_once else self.state[LS_LAST_U]
        self.state[LS_RAMP_K0] = self.period
        self.state[LS_RAMP_N] = max(1, int(round(duration_s / self.control_period_s)))

    # --- one period at a time (a real rig) ------------------------------------------------------------
    def step(self, m: Measurement) -> tuple[float, Samples]:
        """The command for the measurement's period and the rows up to it.

        Periods the rig counted but whose measurement never arrived (``m.period`` ahead of the loop) are run
        first, flagged FLAG_LOST | FLAG_PREDICTED: the controller runs on a *predicted* reading, the period's
        target less the last measured tracking error, never on the old reading (which, carried forward, wound
        a controller up to -10 V), so its clock, filters and target history stay in step; the row records the
        last reading held (nothing new was measured). Their commands were never sent.
        """
        if m.period < self.period:
            raise ValueError(f"measurement of period {m.period} is older than the loop's period {self.period}")
        n = m.period - self.period + 1
        rows = np.empty((n, N_FIELDS))
        held = self.last_measurement or m
        for i in range(n - 1):
            self._run_period(held, held.status | FLAG_LOST | FLAG_PREDICTED, rows[i])
        u = self._run_period(m, m.status, rows[n - 1])
        self.last_measurement = m
        return u, Samples(rows)

    def _run_period(self, m: Measurement, status: int, row: np.ndarray) -> float:
        u = control_period(self.period, m.position_m, m.force_n, m.load_pressure_pa, m.supply_pressure_pa,
                           status, self.params, self.state, self.controller.kind, self.controller.params,
                           self.controller_state, self.blocks, self.table, self._meas, self._report, row)
        if math.isfinite(m.true_position_m):  # a simulation knows the true table state
            row[_Y], row[_VEL], row[_FLOW], row[_VALVE] = (m.true_position_m, m.velocity_m_per_s, m.flow_m3_per_s,
                                                           m.valve_v)
        self.period += 1
        return u
