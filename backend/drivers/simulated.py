"""The simulated rig behind the driver protocol: sim.plant's fifth-order model with a mounted isolator.

The isolator is part of the simulated hardware (it is given when the rig is built, as a specimen is
mounted on a real rig), never passed through the protocol. ``run_compiled(loop, n)`` is the optional fast
path: n periods of the loop around the plant in one compiled call, the same ``control_period`` and the
same sensor readings as the per-period path.
"""

from __future__ import annotations

from sim.isolator import Isolator
from sim.loop import CONTROL_PERIOD_S, ClosedLoop
from sim.measurement import Measurement
from sim.plant import SimulatedPlant
from sim.rig import DEFAULT_RIG, RigParameters
from sim.samples import Samples

from .base import ArmConditions, RigDescription, RigDriver, check_command


class SimulatedRig(RigDriver):
    """The rig model of sim/ in place of hardware; paced by the caller, so it may run faster than real time."""

    def __init__(self, isolator: Isolator, rig: RigParameters = DEFAULT_RIG, noise_seed: int = 0,
                 table_position_m: float = 0.0):
        self.rig = rig
        self.isolator = isolator
        self.noise_seed = noise_seed
        self.table_position_m = table_position_m  # where the table rests when armed (the last test left it)
        self.plant: SimulatedPlant | None = None
        self.armed = False
        self.command_v = 0.0

    def describe(self) -> RigDescription:
        return RigDescription(name=f"simulated rig ({self.isolator.name} mounted)", kind="simulated",
                              control_period_s=CONTROL_PERIOD_S, command_limit_v=self.rig.command_limit_v,
                              realtime=False, details={"model": "fifth-order, eqs. (2)-(4)",
                                                       "isolator": self.isolator.name})

    def arm(self, conditions: ArmConditions) -> None:
        rig = self.rig.with_changes(vertical_load_n=conditions.vertical_load_n)  # the jack: friction follows
        self.plant = SimulatedPlant(rig, self.isolator, conditions.supply_pressure_pa, self.noise_seed)
        if self.table_position_m:
            self.plant.place(self.table_position_m)
        self.command_v = 0.0
        self.armed = True

    def read(self) -> Measurement:
        return self.plant.measure()

    def write(self, command_v: float) -> None:
        self.command_v = check_command(command_v, self.rig.command_limit_v)

    def wait_next_period(self) -> None:
        self.plant.advance(self.command_v if self.armed else 0.0)

    def disarm(self, success: bool = True) -> None:
        self.command_v = 0.0
        self.armed = False

    def fault(self) -> str | None:
        if self.plant is not None and self.plant.diverged:
            return "the simulated rig's state became non-finite"
        return None

    def run_compiled(self, loop: ClosedLoop, n_periods: int) -> Samples:
        """Up to n periods of ``loop`` around the plant in one compiled call."""
        rows = self.plant.run_closed(loop, n_periods)
        self.command_v = loop.last_command_v
        return rows
