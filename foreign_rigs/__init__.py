"""Foreign rigs: a test instrument of servo-hydraulic isolator rigs written from their physics, kept apart from
isorig's model. It imports nothing from ``sim/``: a rig here is what a lab has (valve lands, spool, chambers,
hoses, pump and accumulator, LuGre friction, specimens beyond Bouc-Wen, a load cell, late and noisy sensors),
not isorig's fifth-order model with other numbers. isorig's commissioning and controller are tried on it.

- ``physics``: the compiled equations of the rig (one state vector, one parameter vector, RK4 per period);
- ``draw``: the family: ``draw_rig(seed)`` from the declared distributions in ``distributions.toml``, what the
  lab knows of a rig (its start rig file) and the truth its commissioning is judged against;
- ``ForeignRig``: one rig as hardware: ``set_conditions`` (the pump's set point and the jack, at ARM), ``place``,
  ``read(period)`` (the sensors) and ``advance(command_v)`` (one control period). The rig emulator plays it behind
  the rig protocol (``isorig rig-emulator --foreign-rig SEED``); isorig's engine plays it through an adapter.
"""

from __future__ import annotations

import math

import numpy as np

from . import physics as ph
from .draw import CONTROL_PERIOD_S, DISTRIBUTIONS_FILE, ForeignRigSpec, draw_rig, load_distributions

__all__ = ["CONTROL_PERIOD_S", "DISTRIBUTIONS_FILE", "ForeignRig", "ForeignRigSpec", "draw_rig", "load_distributions"]

STEPS_PER_PERIOD = 10  # RK4 at 0.1 ms: the spool (<= 150 Hz), the bristles and the load cell (<= 500 Hz) are resolved


class ForeignRig:
    """One foreign rig as hardware, stepped one control period at a time (module docstring)."""

    def __init__(self, spec: ForeignRigSpec, control_period_s: float = CONTROL_PERIOD_S,
                 steps_per_period: int = STEPS_PER_PERIOD):
        self.spec = spec
        self.params = spec.params.copy()
        self.control_period_s = control_period_s
        self.steps_per_period = steps_per_period
        self.state = np.zeros(ph.N_STATES)
        self.aux = ph.new_aux()
        self.readings = np.zeros(ph.N_READINGS)
        self.period = 0
        self.diverged = False
        self.set_conditions(float(self.params[ph.P_PUMP_SET]), float(self.params[ph.P_LOAD]))

    @property
    def name(self) -> str:
        return self.spec.name

    def set_conditions(self, supply_pa: float, vertical_load_n: float, pump_ready: bool = True) -> None:
        """The pump's set point and the vertical jack (what ARM asks for). ``pump_ready``: the accumulator is
        at the set point already (the pump ran before); else it rises from where it is at the pump's flow."""
        p = self.params
        p[ph.P_PUMP_SET] = max(0.0, float(supply_pa))
        p[ph.P_LOAD] = max(0.0, float(vertical_load_n))
        p[ph.P_ISOLATED] = 0.0
        if pump_ready:
            self.state[ph.X_ACC] = p[ph.P_PUMP_SET]
            share = p[ph.P_AREA_B] / (p[ph.P_AREA_A] + p[ph.P_AREA_B])  # the chambers balanced at rest
            self.state[ph.X_PA] = p[ph.P_PUMP_SET] * share
            self.state[ph.X_PB] = p[ph.P_PUMP_SET] * (1.0 - share)

    def isolate(self) -> None:
        """The isolation valve closes (DISARM, the watchdog): the cylinder's ports are blocked, the table held."""
        self.params[ph.P_ISOLATED] = 1.0

    def stop_pump(self) -> None:
        """The pump stops (a supply loss): the accumulator alone feeds the valve from now on."""
        self.params[ph.P_PUMP_FLOW] = 0.0

    def place(self, position_m: float) -> None:
        """The table at rest at ``position_m``; the position sensor's history holds it too."""
        self.state[ph.X_Y] = float(position_m)
        self.state[ph.X_V] = 0.0
        self.aux[ph.AUX_LAST_PERIOD] = -1.0

    @property
    def position_m(self) -> float:
        return float(self.state[ph.X_Y])

    @property
    def supply_pa(self) -> float:
        """The supply pressure at the valve now (true, without the sensor's noise; nothing is read or recorded)."""
        return float(ph.supply_at_valve(self.state, self.params))

    def read(self) -> np.ndarray:
        """The readings at the start of the current period (``physics.READING_NAMES``); a view, copied on use."""
        ph.read(self.state, self.params, self.aux, self.period, self.readings)
        return self.readings

    def advance(self, command_v: float, new_command_v: float | None = None, switch_fraction: float = 0.0) -> None:
        """Hold ``command_v`` over the current period; with ``new_command_v``, switch to it from
        ``switch_fraction`` of the period on."""
        if not self.diverged:
            steps = self.steps_per_period
            if new_command_v is None:
                new_command_v, switch = command_v, steps
            else:
                switch = min(steps, max(0, int(math.ceil(switch_fraction * steps - 1e-9))))
            self.diverged = not ph.advance(self.state, self.params, self.aux, float(command_v), float(new_command_v),
                                           switch, steps, self.control_period_s / steps)
        self.period += 1
