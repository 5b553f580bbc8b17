"""Was the actuator at its force limit? A table that cannot follow because the rig has no more to give.

The actuator's force is A_A P_L (docs/rig-protocol.md 4.2: P_L = P_A - (A_B / A_A) P_B). Pushing towards +y it
can reach at most A_A P_s (the cap side at the supply, the rod side at the tank), pulling towards -y at most
A_B P_s, that is P_L down to -(A_B / A_A) P_s. A specimen that needs more than that (a lead-rubber bearing at a
large amplitude, a low supply pressure), or a valve that needs more flow than its command limit opens, stalls
the table whatever the controller does: the follow monitor (sim.follow) then sees a large error, or error
that it would take for an oscillation, and without this it would blame the controller or the rig file.

Measured on 300 foreign rigs (docs/commissioning.md, "Stopped at the actuator's force limit"): of the 10
oscillation stops at 20 mm and 0.5 Hz, 8 had the load pressure at 90 % of its limit for 8-40 % of the run
(single-rod actuators pulling a lead-rubber bearing with their rod side), and our own rig at 20 bar with IUT_a
at 20 mm stalls the same way.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .loop import CONTROL_PERIOD_S

#: a row is at the force limit with the load pressure beyond this share of what the supply gives that way ...
PRESSURE_SHARE = 0.9
#: ... or the valve command beyond this share of its limit
COMMAND_SHARE = 0.99
#: a trip is put down to the force limit when the actuator was at it in this share of the rows judged
TRIP_SHARE = 0.05


@dataclass(frozen=True)
class ActuatorLimits:
    """What the actuator can give: the command's limit, the rod side's area over the cap side's (1: double-rod)
    and the highest supply pressure the rig takes (what the advice may offer)."""

    command_limit_v: float
    area_ratio_b: float = 1.0
    max_supply_pa: float | None = None

    @classmethod
    def of_rig(cls, rig) -> ActuatorLimits:
        """The limits of a sim.rig.RigParameters (``area_ratio_b``: 1 on a double-rod rig)."""
        return cls(float(rig.command_limit_v), float(rig.area_ratio_b), float(rig.max_supply_pa))


def at_force_limit(rows, limits: ActuatorLimits) -> np.ndarray:
    """Per row: +1 where the actuator pushed (towards +y) at its limit, -1 where it pulled at its limit, 0 where it
    did not (the load pressure within PRESSURE_SHARE of what the supply gives that way, and the command within
    COMMAND_SHARE of its limit; readings that are not numbers count as not at the limit)."""
    p_load = np.asarray(rows["load_pressure_pa"], dtype=float)
    supply = np.asarray(rows["supply_pressure_pa"], dtype=float)
    u = np.asarray(rows["voltage_v"], dtype=float)
    with np.errstate(invalid="ignore"):
        command = COMMAND_SHARE * limits.command_limit_v
        push = (p_load >= PRESSURE_SHARE * supply) | (u >= command)
        pull = (p_load <= -PRESSURE_SHARE * limits.area_ratio_b * supply) | (u <= -command)
    return push.astype(np.int8) - pull.astype(np.int8)


def diagnosis(window: np.ndarray, supply_pa: float, limits: ActuatorLimits) -> tuple[float, str] | None:
    """(share of the window at the force limit, what happened and what to try) when that share reaches
    TRIP_SHARE; None when the actuator was not held at its limit. ``window``: ``at_force_limit`` of the rows
    judged (oldest first)."""
    if window.size == 0:
        return None
    pushed, pulled = int(np.count_nonzero(window > 0)), int(np.count_nonzero(window < 0))
    share = (pushed + pulled) / window.size
    if share < TRIP_SHARE:
        return None
    way = ("pushing towards +y" if pushed >= pulled else
           "pulling towards -y" + (" with its rod side" if limits.area_ratio_b < 1.0 else ""))
    bar = supply_pa / 1e5 if math.isfinite(supply_pa) and supply_pa > 0.0 else None
    at = f" at {bar:.0f} bar" if bar else ""
    higher = ""
    if limits.max_supply_pa and bar and limits.max_supply_pa > 1.05 * supply_pa:
        higher = f", or a higher supply pressure (this rig takes up to {limits.max_supply_pa / 1e5:.0f} bar)"
    text = (f"the actuator was at its force limit ({way}: the load pressure at {100 * PRESSURE_SHARE:.0f} % or more "
            f"of what the supply gives that way, or the valve command at +-{limits.command_limit_v:g} V) in "
            f"{100 * share:.0f} % of the {window.size * CONTROL_PERIOD_S:.1f} s judged: the specimen needs more "
            f"force, or the motion more flow, than the rig gives{at}, so the table cannot follow whatever the "
            f"controller does. What to try: a smaller amplitude or a lower frequency{higher}")
    return share, text
