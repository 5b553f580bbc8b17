"""The simulated rig: the fifth-order model (eqs. 2-4) with one isolator, its sensors, stepped per period.

``SimulatedPlant`` is the hardware a simulation stands in for: ``measure()`` reads the sensors at the
start of the current period (sim.sensors), ``advance(command_v)`` holds the command for one period
(zero-order hold, fixed-step RK4 with ``substeps`` steps of the plant). ``run_closed(loop, n)`` runs n
periods of a ``sim.loop.ClosedLoop`` around it in one compiled call: the same ``control_period`` as the
per-period path, the same sensor readings, to the last bit.

The plant step is 0.2 ms (5 RK4 substeps per 1 ms control period). The closed-loop eigenvalues of the rig
model are about -176 +- 180j (valve) and -90 +- 365j (oil column), so RK4 is stable well beyond 1 ms; at
0.2 ms the displacement agrees with a 0.02 ms reference to far below 1 um (scripts/step_size_study.py,
docs/engine.md).
"""

from __future__ import annotations

import numpy as np
from numba import njit

from .controllers.base import N_MEAS, N_REPORT
from .isolator import Isolator
from .loop import CONTROL_PERIOD_S, ClosedLoop, control_period
from .measurement import STATUS_ARMED, Measurement
from .rig import (
    N_STATES,
    P_FRICTION,
    P_KD,
    P_KW,
    P_PLAY_HELD,
    P_SUPPLY,
    X_PL,
    X_V,
    X_VE,
    X_W,
    X_Y,
    RigParameters,
    load_flow,
    pack_plant,
    rk4_steps,
    valve_command,
)
from .samples import _FLOW, _VALVE, _VEL, _Y, N_FIELDS, Samples
from .sensors import new_history, pack_sensors, sense

PLANT_SUBSTEPS = 5  # 0.2 ms RK4 step
SUPPLY_DECAY_S = 0.05  # time constant of the supply pressure after a pump loss (lose_supply)


@njit(cache=True, error_model="numpy", inline="always")
def advance_period(x, v_c, p, substeps, h):
    """Hold the valve voltage v_c for one control period (substeps RK4 steps of h); False if x went non-finite."""
    rk4_steps(x, v_c, p, h, substeps)
    for j in range(N_STATES):
        if not np.isfinite(x[j]):
            return False
    return True


@njit(cache=True, error_model="numpy")
def advance_period_split(x, v_old, v_new, switch, p, substeps, h):
    """One period whose valve voltage changes from v_old to v_new after ``switch`` substeps (a command that
    arrived within the period, as the rig emulator applies it); False if x went non-finite."""
    rk4_steps(x, v_old, p, h, switch)
    rk4_steps(x, v_new, p, h, substeps - switch)
    for j in range(N_STATES):
        if not np.isfinite(x[j]):
            return False
    return True


@njit(cache=True, error_model="numpy")
def run_closed(x, p, substeps, sp, history, lp, ls, kind, cparams, cstate, blocks, table, k0, n, out):
    """n closed-loop periods from period k0: sense, ``control_period``, plant. Returns the rows written
    (fewer than n if the plant state became non-finite)."""
    meas = np.empty(N_MEAS)
    report = np.full(N_REPORT, np.nan)
    sensed = np.empty(2)
    h = lp[0] / substeps
    for i in range(n):
        k = k0 + i
        sense(x[X_Y], x[X_PL], k, sp, history, sensed)
        row = out[i]
        force = p[P_KD] * x[X_Y] + p[P_KW] * x[X_W]
        u = control_period(k, sensed[0], force, sensed[1], p[P_SUPPLY], STATUS_ARMED, lp, ls, kind, cparams,
                           cstate, blocks, table, meas, report, row)
        row[_Y] = x[X_Y]
        row[_VEL] = x[X_V]
        row[_FLOW] = load_flow(x[X_VE], x[X_PL], p)
        row[_VALVE] = x[X_VE]
        if not advance_period(x, valve_command(u, p), p, substeps, h):
            return i + 1
    return n


class SimulatedPlant:
    """The rig model with one isolator at one supply pressure, as hardware: sensors in, valve command out."""

    def __init__(self, rig: RigParameters, isolator: Isolator, supply_pa: float, noise_seed: int = 0,
                 control_period_s: float = CONTROL_PERIOD_S, substeps: int = PLANT_SUBSTEPS):
        self.rig = rig
        self.isolator = isolator
        self.control_period_s = control_period_s
        self.substeps = substeps
        self.params = pack_plant(rig, isolator, supply_pa)
        self.sensors = pack_sensors(rig, control_period_s, noise_seed)
        self.history = new_history()
        self.state = np.zeros(N_STATES)
        self.period = 0
        self.diverged = False
        self._sensed = np.empty(2)

    def place(self, position_m: float) -> None:
        """Start with the table at rest at ``position_m`` (where the last test or move left it; the sensors'
        delay lines hold it too). Load pressure and the isolator's hysteretic state start at zero."""
        self.state[X_Y] = position_m
        self.history[0, :] = position_m

    def rebuild(self, rig: RigParameters, isolator: Isolator) -> None:
        """The plant's parameters changed (a timed change in the middle of a test): state and history kept."""
        self.rig, self.isolator = rig, isolator
        held = self.params[P_PLAY_HELD]  # the valve's play keeps where it holds the spool
        self.params = pack_plant(rig, isolator, self.supply_pa)
        self.params[P_PLAY_HELD] = held
        self.sensors = pack_sensors(rig, self.control_period_s, int(self.sensors[5]))

    @property
    def supply_pa(self) -> float:
        return float(self.params[P_SUPPLY])

    @property
    def position_m(self) -> float:
        return float(self.state[X_Y])

    def set_conditions(self, supply_pa: float, vertical_load_n: float, pump_ready: bool = True) -> None:
        """What ARM asks for: the supply pressure and the vertical jack (the guides' friction mu N + F_c follows).
        The model's supply is its set point at once, so ``pump_ready`` (sim.foreign_plant's: whether an accumulator
        starts charged) changes nothing here."""
        self.params[P_SUPPLY] = supply_pa
        self.params[P_FRICTION] = self.rig.with_changes(vertical_load_n=vertical_load_n).friction_force_n

    def hydraulics_off(self) -> None:
        """Disarmed: nothing to do, the model's valve at 0 V stays inside its dead zone and the table rests."""

    def lose_supply(self, since_s: float, set_pa: float) -> None:
        """The pump lost ``since_s`` ago: the supply decays from ``set_pa`` (SUPPLY_DECAY_S)."""
        self.params[P_SUPPLY] = set_pa * np.exp(-since_s / SUPPLY_DECAY_S)

    @property
    def force_n(self) -> float:
        x, p = self.state, self.params
        return float(p[P_KD] * x[X_Y] + p[P_KW] * x[X_W])

    def measure(self) -> Measurement:
        """The sensors at the start of the current period (and the true state, which only a simulation has)."""
        x = self.state
        sense(x[X_Y], x[X_PL], self.period, self.sensors, self.history, self._sensed)
        return Measurement(self.period, self.period * self.control_period_s, float(self._sensed[0]), self.force_n,
                           float(self._sensed[1]), self.supply_pa, STATUS_ARMED, float(x[X_Y]), float(x[X_V]),
                           float(load_flow(x[X_VE], x[X_PL], self.params)), float(x[X_VE]))

    def advance(self, command_v: float, new_command_v: float | None = None, switch_fraction: float = 0.0) -> None:
        """Hold ``command_v`` (eq. 2 gives the valve voltage) over the current period; with ``new_command_v``,
        switch to it at the first plant step from ``switch_fraction`` of the period on (0: at once)."""
        if not self.diverged:
            v_old = valve_command(float(command_v), self.params)
            h = self.control_period_s / self.substeps
            if new_command_v is None:
                ok = advance_period(self.state, v_old, self.params, self.substeps, h)
            else:
                switch = min(self.substeps, max(0, int(np.ceil(switch_fraction * self.substeps - 1e-9))))
                ok = advance_period_split(self.state, v_old, valve_command(float(new_command_v), self.params), switch,
                                          self.params, self.substeps, h)
            self.diverged = not ok
        self.period += 1

    def run_closed(self, loop: ClosedLoop, n_periods: int, out: np.ndarray | None = None) -> Samples:
        """Up to n periods of ``loop`` around this plant in one compiled call (the fast path). ``out``: rows to
        write into (a C-contiguous (m, N_FIELDS) array; at most m periods run), else new ones; the samples
        returned are a view of them."""
        if loop.period != self.period:
            raise ValueError(f"loop at period {loop.period}, plant at period {self.period}: they must run together")
        n = loop.remaining(n_periods)
        if out is not None:
            if out.ndim != 2 or out.shape[1] != N_FIELDS or out.dtype != np.float64 or not out.flags.c_contiguous:
                raise ValueError(f"out must be a C-contiguous float64 array of shape (m, {N_FIELDS}); got "
                                 f"{out.dtype} {out.shape}")
            n = min(n, out.shape[0])
        if n == 0 or self.diverged:
            return Samples.empty()
        out = np.empty((n, N_FIELDS)) if out is None else out[:n]
        written = run_closed(self.state, self.params, self.substeps, self.sensors, self.history, loop.params,
                             loop.state, loop.controller.kind, loop.controller.params, loop.controller_state,
                             loop.blocks, loop.table, self.period, n, out)
        self.period += written
        loop.period += written
        if written < n:
            self.diverged = True
        return Samples(out[:written])
