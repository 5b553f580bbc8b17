"""The simulated rig: sim.engine's fifth-order rig model (eqs. 1-4) behind the driver interface.

Closed-loop chunks run in the compiled engine (``Simulation.advance``); open-loop periods (the command
ramp of a controlled stop, or the generic per-period loop of the driver interface) hold the command in
the same engine (``Simulation.advance_open_loop``).
"""

from __future__ import annotations

import numpy as np

from sim.engine import (
    C_U,
    Scenario,
    Simulation,
)
from sim.rig import (
    P_KD,
    P_KW,
    P_SUPPLY,
    P_ULIM,
    X_PL,
    X_W,
    X_Y,
)

from .base import Measurement, RigDriver


class SimulatedRig(RigDriver):
    """The rig model of sim/ stepped in place of hardware; may run faster than real time."""

    name = "simulated"
    can_accelerate = True

    def __init__(self) -> None:
        super().__init__()
        self.sim: Simulation | None = None

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
        rows = self.sim.advance_open_loop(n_periods, self.last_command_v)
        self.period = self.sim.period
        return rows

    def run_closed_loop(self, n_periods: int) -> np.ndarray:
        sim = self.sim
        sim.blocks = self.blocks
        sim.total_periods = self.total_periods
        rows = sim.advance(n_periods)
        self.period = sim.period
        if rows.shape[0]:
            self.last_command_v = float(rows[-1, C_U])
        return rows
