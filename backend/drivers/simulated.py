"""The simulated rig: sim.engine's fifth-order rig model (eqs. 1-4) behind the driver interface.

Closed-loop chunks run in the compiled engine (``Simulation.advance``); open-loop periods (the command
ramp of a controlled stop) step the same plant with ``sim.rig.rk4_step`` at the engine's 0.2 ms substep.
"""

from __future__ import annotations

import numpy as np

from sim.engine import (
    C_FLOW,
    C_FORCE,
    C_PL,
    C_TIME,
    C_U,
    C_URAW,
    C_VALVE,
    C_VEL,
    C_Y,
    COLUMNS,
    CONTROL_PERIOD_S,
    PLANT_SUBSTEPS,
    Scenario,
    Simulation,
)
from sim.rig import (
    N_STATES,
    P_KD,
    P_KW,
    P_SUPPLY,
    P_ULIM,
    X_PL,
    X_V,
    X_VE,
    X_W,
    X_Y,
    load_flow,
    rk4_step,
    valve_command,
)

from .base import Measurement, RigDriver


class SimulatedRig(RigDriver):
    """The rig model of sim/ stepped in place of hardware; may run faster than real time."""

    name = "simulated"
    can_accelerate = True

    def __init__(self) -> None:
        super().__init__()
        self.sim: Simulation | None = None
        self._work = [np.empty(N_STATES) for _ in range(5)]

    def arm(self, scenario: Scenario) -> None:
        # load the compiled kernels (from numba's cache) before the clock starts
        Simulation(scenario, validate=False).advance(2)
        self.scenario = scenario
        self.sim = Simulation(scenario)
        self.blocks = self.sim.blocks
        self.controller = self.sim.controller
        self.controller_state = self.sim.controller_state
        self.period = 0
        self.total_periods = self.sim.total_periods
        self.last_command_v = 0.0

    def disarm(self) -> None:
        self.last_command_v = 0.0

    def fault(self) -> str | None:
        if self.sim is not None and (self.sim.diverged or not np.all(np.isfinite(self.sim.state))):
            return "the simulated rig's state became non-finite"
        return None

    def read(self) -> Measurement:
        x, p = self.sim.state, self.sim.plant
        return Measurement(self.time_s, float(x[X_Y]), float(p[P_KD] * x[X_Y] + p[P_KW] * x[X_W]),
                           float(x[X_PL]), float(p[P_SUPPLY]))

    def write_valve_command(self, u_v: float) -> None:
        limit = self.sim.plant[P_ULIM]
        self.last_command_v = float(min(max(u_v, -limit), limit)) if np.isfinite(u_v) else 0.0

    def step(self, n_periods: int = 1) -> np.ndarray:
        x, p = self.sim.state, self.sim.plant
        h = CONTROL_PERIOD_S / PLANT_SUBSTEPS
        k1, k2, k3, k4, tmp = self._work
        out = np.full((n_periods, len(COLUMNS)), np.nan)
        u = self.last_command_v
        v_c = valve_command(u, p)
        for i in range(n_periods):
            row = out[i]
            row[C_TIME] = self.time_s
            row[C_Y] = x[X_Y]
            row[C_U] = u
            row[C_URAW] = u
            row[C_FORCE] = p[P_KD] * x[X_Y] + p[P_KW] * x[X_W]
            row[C_PL] = x[X_PL]
            row[C_VEL] = x[X_V]
            row[C_FLOW] = load_flow(x[X_VE], x[X_PL], p)
            row[C_VALVE] = x[X_VE]
            for _ in range(PLANT_SUBSTEPS):
                rk4_step(x, v_c, p, h, k1, k2, k3, k4, tmp)
            self.period += 1
            self.sim.period = self.period
        return out

    def run_closed_loop(self, n_periods: int) -> np.ndarray:
        sim = self.sim
        sim.blocks = self.blocks
        sim.total_periods = self.total_periods
        rows = sim.advance(n_periods)
        self.period = sim.period
        if rows.shape[0]:
            self.last_command_v = float(rows[-1, C_U])
        return rows
