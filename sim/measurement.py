"""What a rig measures at the start of one control period, and the status bits that come with it.

A rig driver (backend.drivers) returns one ``Measurement`` per period; the closed loop (sim.loop) turns it
into a command and a recorded row. The first block of fields is what every rig measures; the second is
what only a simulation knows (the true table state), NaN from real hardware.

Status bits: the low byte is what the rig reports about itself (the same bits travel in the UDP packet,
docs/rig-protocol.md); the loop adds its own FLAG_* bits in the recorded ``flags`` field.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

# Reported by the rig (bits 0-7).
STATUS_ARMED = 1 << 0  # hydraulics on, valve amplifier enabled, commands are applied
STATUS_SENSOR_FAULT = 1 << 1  # the rig's own sensor diagnostics found a fault (open wire, out of range)
STATUS_SUPPLY_LOW = 1 << 2  # supply pressure below what was asked at arm
STATUS_WATCHDOG = 1 << 3  # no valid command for the watchdog time: the rig closed the valve by itself
STATUS_COMMAND_MISSED = 1 << 4  # no new command arrived in time for this period: the previous one was held
STATUS_INTERLOCK = 1 << 5  # an interlock or emergency stop of the rig is open
RIG_STATUS_NAMES = {STATUS_ARMED: "armed", STATUS_SENSOR_FAULT: "sensor fault", STATUS_SUPPLY_LOW: "supply low",
                    STATUS_WATCHDOG: "watchdog tripped", STATUS_COMMAND_MISSED: "command missed",
                    STATUS_INTERLOCK: "interlock open"}
#: bits that end a test at once when the rig reports them
RIG_FAULT_BITS = STATUS_SENSOR_FAULT | STATUS_WATCHDOG | STATUS_INTERLOCK

# Added by the host's loop (bits 8-15).
FLAG_LOST = 1 << 8  # no fresh measurement for this period (a packet was lost): the previous one is held
FLAG_OPEN_LOOP = 1 << 9  # the controller was not stepped (command ramp of a controlled stop)
FLAG_PREDICTED = 1 << 10  # a lost period: the controller ran on a predicted reading (target less the last error)
FLAG_BRAKE = 1 << 11  # a controlled stop: the target brakes to rest (sim.loop.brake_target), the controller in the loop
FLAG_GUARD = 1 << 12  # the displacement guard began the stop here: the target would have carried the table past it
#: a lost period or within its settling (sim.loop.hold_learning): the controller acted but its learning law learned
#: nothing from this period (the error is the stall's, not the cycle's)
FLAG_LEARNING_HELD = 1 << 13


def measured_rows(flags) -> np.ndarray:
    """True where a period's measurement arrived; False where it was lost (FLAG_LOST: the row holds the previous
    reading, not a measurement). Tracking figures are taken over the measured rows only."""
    return (np.nan_to_num(np.asarray(flags, dtype=float)).astype(np.int64) & FLAG_LOST) == 0


def describe_status(bits: int) -> str:
    """The set status bits in words, e.g. 'armed, command missed'."""
    names = [name for bit, name in RIG_STATUS_NAMES.items() if bits & bit]
    if bits & FLAG_LOST:
        names.append("measurement lost")
    if bits & FLAG_GUARD:
        names.append("displacement guard")
    if bits & FLAG_BRAKE:
        names.append("braking stop")
    if bits & FLAG_PREDICTED:
        names.append("reading predicted")
    if bits & FLAG_OPEN_LOOP:
        names.append("open loop")
    if bits & FLAG_LEARNING_HELD:
        names.append("learning held")
    return ", ".join(names) or "none"


NAN = math.nan


@dataclass(frozen=True)
class Measurement:
    """One period's sensor readings, SI units.

    ``period`` counts control periods since the rig was armed (the rig's sequence number); ``time_s`` is
    ``period`` times the control period.
    """

    period: int
    time_s: float
    position_m: float
    force_n: float
    load_pressure_pa: float
    supply_pressure_pa: float
    status: int = STATUS_ARMED
    # only a simulation knows these; NaN from real hardware
    true_position_m: float = NAN
    velocity_m_per_s: float = NAN
    flow_m3_per_s: float = NAN
    valve_v: float = NAN

    def is_finite(self) -> bool:
        return all(math.isfinite(v) for v in (self.position_m, self.force_n, self.load_pressure_pa,
                                              self.supply_pressure_pa))
