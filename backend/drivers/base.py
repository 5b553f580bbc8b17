"""The rig driver protocol: what isorig needs from a rig, simulated or real. I/O only.

A driver reads sensors and writes the valve command, once per control period; it knows nothing of the
isolator under test, the controller, the target or how samples are recorded (sim.loop does all that,
above every driver). A lab connects its rig by implementing seven methods (docs/drivers.md):

======================  =======================================================================================
``describe()``          name, channels with units, command limit, control period, whether it paces itself
``arm(conditions)``     hydraulics on at the test's supply pressure, valve amplifier enabled; period 0 begins
``read()``              the current period's ``sim.measurement.Measurement`` (never blocks)
``write(command_v)``    the valve command for the current period; refuses NaN, inf and |u| > the limit
``wait_next_period()``  returns when the next period has begun (a real rig blocks until its next sample)
``disarm(success)``     valve command zero and hydraulics made safe; idempotent. ``success=False``: at once
``fault()``             a fault the rig reports (a string), or None
======================  =======================================================================================

Stop, abort and faults, side by side (after bluesky's ``stop(success)``): an operator stop and a limit
trip are handled above the driver (sim.loop ramps the target or the command out through ``write``), then
``disarm(success=True)``; an abort calls ``disarm(success=False)``, which sets the valve command to 0 V at
once (the UDP driver sends DISARM three times; the rig applies 0 V on it); a lost link or a rig fault raises
``RigFault`` from ``read``/``wait_next_period`` (never a hang) and the worker calls ``disarm(success=False)``.
After a sensor fault the loop writes 0 V from the next period (``ClosedLoop.begin_command_ramp(at_once=True)``).
A real rig must also close its valve by itself when commands stop coming (its
watchdog): the host cannot be trusted to be there.

Optional capability: ``run_compiled(loop, n)`` runs n periods of a ``sim.loop.ClosedLoop`` in one call
(only the simulated rig has it: it is how a simulated test runs faster than real time).
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from dataclasses import asdict, dataclass, field

from sim.measurement import Measurement


class RigFault(Exception):
    """The rig or its link failed: the test cannot go on (it ends ``failed`` with this message)."""


class CommandRefused(ValueError):
    """A command the driver will not apply: not finite, or beyond the declared limit."""


@dataclass(frozen=True)
class Channel:
    """One measured quantity: its name in ``Measurement``, its SI unit, what it is."""

    name: str
    unit: str
    description: str


#: what every driver measures (the first fields of sim.measurement.Measurement)
STANDARD_CHANNELS = (
    Channel("position_m", "m", "table displacement from the position sensor"),
    Channel("force_n", "N", "isolator force (load cell, or A_p P_L less friction)"),
    Channel("load_pressure_pa", "Pa", "load pressure P_L across the piston"),
    Channel("supply_pressure_pa", "Pa", "supply pressure P_s"),
    Channel("status", "-", "status and fault bits (sim.measurement STATUS_*)"),
)


@dataclass(frozen=True)
class RigDescription:
    """What a driver declares about its rig."""

    name: str
    kind: str
    control_period_s: float
    command_limit_v: float
    channels: tuple[Channel, ...] = STANDARD_CHANNELS
    #: True if ``wait_next_period`` blocks until the next period in real time (hardware); False if the
    #: caller paces it (a simulation, which may also run faster than real time)
    realtime: bool = True
    details: dict = field(default_factory=dict)

    def to_dict(self) -> dict:
        return asdict(self)


@dataclass(frozen=True)
class ArmConditions:
    """Operating conditions the rig is armed for."""

    supply_pressure_pa: float
    vertical_load_n: float = 1.25e5  # the jack's setting for the test
    test_id: int | None = None


def check_command(command_v: float, limit_v: float) -> float:
    """The command as a float, or ``CommandRefused`` naming what is wrong (for ``write`` implementations)."""
    try:
        u = float(command_v)
    except (TypeError, ValueError):
        raise CommandRefused(f"valve command {command_v!r} is not a number") from None
    if not math.isfinite(u):
        raise CommandRefused(f"valve command {u!r} V is not finite; refused (the valve keeps its last command)")
    if abs(u) > limit_v:
        raise CommandRefused(f"valve command {u:g} V is beyond the rig's limit of +-{limit_v:g} V; refused")
    return u


class RigDriver(ABC):
    """A rig behind the driver protocol (see the module docstring)."""

    @abstractmethod
    def describe(self) -> RigDescription:
        """Name, channels, command limit, control period, real-time or not."""

    @abstractmethod
    def arm(self, conditions: ArmConditions) -> None:
        """Make the rig ready at these conditions; period 0 begins. Raises ``RigFault`` if it cannot."""

    @abstractmethod
    def read(self) -> Measurement:
        """The measurement of the current period (does not block)."""

    @abstractmethod
    def write(self, command_v: float) -> None:
        """The valve command for the current period, in volts. Raises ``CommandRefused`` for NaN, inf or
        a command beyond ``describe().command_limit_v``; a refused command is never applied."""

    @abstractmethod
    def wait_next_period(self) -> None:
        """Return once the next period has begun. Raises ``RigFault`` if the rig does not answer in time."""

    @abstractmethod
    def disarm(self, success: bool = True) -> None:
        """Valve command zero, rig safe. Safe to call any number of times, armed or not, after a fault too."""

    def fault(self) -> str | None:
        """A fault the rig reports now, or None."""
        return None

    def link_stats(self) -> dict:
        """Health of the link to the rig (latency, lost packets, last sequence); empty if there is no link."""
        return {}
