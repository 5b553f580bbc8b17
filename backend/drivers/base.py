"""The rig driver interface: what the worker needs from a rig, simulated or real.

A driver is armed for one test (hydraulics enabled, valve amplifier on), then advanced period by period
at the control rate: read the sensors, write the valve command, step. ``run_closed_loop`` closes the
test's controller (sim.controllers) around the driver one period at a time; a driver may override it
with something faster that does the same (the simulated rig runs the compiled engine for a whole chunk).
Every method returns or takes SI units. A hardware driver implements the abstract methods and nothing
else in the backend changes.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass

import numpy as np

from sim.controllers.base import (
    M_LOAD_PRESSURE,
    M_POSITION,
    M_SUPPLY_PRESSURE,
    M_TARGET,
    M_TARGET_RATE,
    M_TIME,
    N_MEAS,
)
from sim.engine import (
    C_AR,
    C_AS,
    C_AY,
    C_FORCE,
    C_MODEL,
    C_PL,
    C_TARGET,
    C_TIME,
    C_U,
    C_URAW,
    C_Y,
    COLUMNS,
    CONTROL_PERIOD_S,
    Scenario,
)
from sim.profiles import target


@dataclass
class Measurement:
    """What a rig measures at the start of a control period."""

    time_s: float
    position_m: float
    force_n: float
    load_pressure_pa: float
    supply_pressure_pa: float


class RigDriver(ABC):
    """A rig behind one interface: arm/disarm, read sensors, write the valve command, step."""

    name = "abstract"
    control_period_s = CONTROL_PERIOD_S
    #: whether the rig can run faster than real time (only a simulation can)
    can_accelerate = False

    def __init__(self) -> None:
        self.scenario: Scenario | None = None
        self.blocks: np.ndarray | None = None
        self.controller = None
        self.controller_state: np.ndarray | None = None
        self.period = 0
        self.total_periods = 0
        self.last_command_v = 0.0

    # --- what every driver implements ---------------------------------------------------------------
    @abstractmethod
    def arm(self, scenario: Scenario) -> None:
        """Prepare the rig for this test (supply pressure, valve amplifier on); time starts at 0."""

    @abstractmethod
    def disarm(self) -> None:
        """Valve command to zero and the rig made safe. Safe to call more than once."""

    @abstractmethod
    def read(self) -> Measurement:
        """The sensors now (start of the current control period)."""

    @abstractmethod
    def write_valve_command(self, u_v: float) -> None:
        """The valve command in volts for the current period (the driver applies its own saturation)."""

    @abstractmethod
    def step(self, n_periods: int = 1) -> np.ndarray:
        """Hold the last command for n periods; rows in the engine's COLUMNS layout (one per period)."""

    def fault(self) -> str | None:
        """A fault the rig itself reports (e.g. a non-finite state), or None."""
        return None

    # --- closed loop ---------------------------------------------------------------------------------
    @property
    def done(self) -> bool:
        return self.period >= self.total_periods

    @property
    def time_s(self) -> float:
        return self.period * self.control_period_s

    def set_profile(self, blocks: np.ndarray, total_periods: int) -> None:
        """Replace the target profile from now on (used by the ramp-out of an operator stop)."""
        self.blocks = blocks
        self.total_periods = total_periods

    def run_closed_loop(self, n_periods: int) -> np.ndarray:
        """The test's controller around the rig for up to n periods, one period at a time."""
        n = max(0, min(n_periods, self.total_periods - self.period))
        out = np.full((n, len(COLUMNS)), np.nan)
        meas = np.empty(N_MEAS)
        dt = self.control_period_s
        limit = self.scenario.rig.command_limit_v
        for i in range(n):
            m = self.read()
            t = self.period * dt
            r, rdot = target(t, self.blocks)
            meas[M_TIME], meas[M_TARGET], meas[M_TARGET_RATE] = t, r, rdot
            meas[M_POSITION], meas[M_LOAD_PRESSURE], meas[M_SUPPLY_PRESSURE] = (
                m.position_m, m.load_pressure_pa, m.supply_pressure_pa)
            u_raw, report = self.controller.step(self.controller_state, meas, dt)
            u = min(max(u_raw, -limit), limit) if np.isfinite(u_raw) else 0.0
            self.write_valve_command(u)
            row = self.step(1)[0]
            row[C_TARGET], row[C_URAW] = r, u_raw
            row[C_MODEL], row[C_AR], row[C_AY], row[C_AS] = report
            out[i] = row
        return out


def measured_row(m: Measurement, u_v: float) -> np.ndarray:
    """A sample row from a measurement (columns a real rig does not measure stay NaN)."""
    row = np.full(len(COLUMNS), np.nan)
    row[C_TIME], row[C_Y], row[C_FORCE], row[C_PL], row[C_U] = (
        m.time_s, m.position_m, m.force_n, m.load_pressure_pa, u_v)
    return row
