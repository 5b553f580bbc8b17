"""A foreign rig (the ``foreign_rigs`` instrument, written from the physics and not from sim's model) as isorig's
simulated hardware: the same interface as ``sim.plant.SimulatedPlant`` (``measure``, ``advance``, ``place``,
``run_closed``), so the engine, the worker's simulated rig and the rig emulator play it unchanged.

The instrument imports nothing from sim; this adapter is the only place where the two meet: it turns the rig's
readings into a ``Measurement`` and runs ``sim.loop.control_period`` around the rig's compiled period in one
compiled call (``run_closed``), reading and stepping it exactly as the per-period path does.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from foreign_rigs import ForeignRig, ForeignRigSpec
from foreign_rigs import physics as fp

from .controllers.base import N_MEAS, N_REPORT
from .loop import CONTROL_PERIOD_S, ClosedLoop, control_period
from .measurement import STATUS_ARMED, Measurement
from .samples import _FLOW, _VALVE, _VEL, _Y, N_FIELDS, Samples


@njit(cache=True, error_model="numpy")
def run_closed_foreign(x, p, aux, readings, steps, h, lp, ls, kind, cparams, cstate, blocks, table, k0, n, out):
    """n closed-loop periods from period k0 around a foreign rig: read, ``control_period``, the rig's period.
    Returns the rows written (fewer than n if the rig's state became non-finite)."""
    meas = np.empty(N_MEAS)
    report = np.full(N_REPORT, np.nan)
    for i in range(n):
        k = k0 + i
        fp.read(x, p, aux, k, readings)
        row = out[i]
        u = control_period(k, readings[fp.R_POSITION], readings[fp.R_FORCE], readings[fp.R_LOAD_PRESSURE],
                           readings[fp.R_SUPPLY], STATUS_ARMED, lp, ls, kind, cparams, cstate, blocks, table, meas,
                           report, row)
        row[_Y] = readings[fp.R_TRUE_Y]
        row[_VEL] = readings[fp.R_TRUE_V]
        row[_FLOW] = readings[fp.R_FLOW]
        row[_VALVE] = readings[fp.R_SPOOL_V]
        if not fp.advance(x, p, aux, u, u, steps, steps, h):
            return i + 1
    return n


class ForeignPlant:
    """A foreign rig behind ``SimulatedPlant``'s interface (module docstring)."""

    def __init__(self, spec: ForeignRigSpec, supply_pa: float, vertical_load_n: float,
                 control_period_s: float = CONTROL_PERIOD_S, pump_ready: bool = True):
        self.spec = spec
        self.rig = ForeignRig(spec, control_period_s)
        self.rig.set_conditions(supply_pa, vertical_load_n, pump_ready)
        self.control_period_s = control_period_s

    @property
    def name(self) -> str:
        return self.rig.name

    @property
    def period(self) -> int:
        return self.rig.period

    @period.setter
    def period(self, value: int) -> None:
        self.rig.period = value

    @property
    def diverged(self) -> bool:
        return self.rig.diverged

    @property
    def position_m(self) -> float:
        return self.rig.position_m

    @property
    def supply_pa(self) -> float:
        """The supply pressure at the valve now (as SimulatedPlant's: the true value, not a reading)."""
        return self.rig.supply_pa

    def set_conditions(self, supply_pa: float, vertical_load_n: float, pump_ready: bool = True) -> None:
        self.rig.set_conditions(supply_pa, vertical_load_n, pump_ready)

    def hydraulics_off(self) -> None:
        """Disarmed: the rig's isolation valve closes and holds the table."""
        self.rig.isolate()

    def lose_supply(self, since_s: float = 0.0, set_pa: float = 0.0) -> None:
        """The pump stops: the accumulator alone feeds the valve, its pressure falls as the valve draws."""
        self.rig.stop_pump()

    def place(self, position_m: float) -> None:
        self.rig.place(position_m)

    def rebuild(self, rig, isolator) -> None:
        raise ValueError("a foreign rig's parameters cannot be changed in the middle of a test")

    def measure(self) -> Measurement:
        r = self.rig.read()
        k = self.rig.period
        return Measurement(k, k * self.control_period_s, float(r[fp.R_POSITION]), float(r[fp.R_FORCE]),
                           float(r[fp.R_LOAD_PRESSURE]), float(r[fp.R_SUPPLY]), STATUS_ARMED, float(r[fp.R_TRUE_Y]),
                           float(r[fp.R_TRUE_V]), float(r[fp.R_FLOW]), float(r[fp.R_SPOOL_V]))

    def advance(self, command_v: float, new_command_v: float | None = None, switch_fraction: float = 0.0) -> None:
        self.rig.advance(command_v, new_command_v, switch_fraction)

    def run_closed(self, loop: ClosedLoop, n_periods: int, out: np.ndarray | None = None) -> Samples:
        """Up to n periods of ``loop`` around the rig in one compiled call (as ``SimulatedPlant.run_closed``)."""
        rig = self.rig
        if loop.period != rig.period:
            raise ValueError(f"loop at period {loop.period}, plant at period {rig.period}: they must run together")
        n = loop.remaining(n_periods)
        if out is not None:
            n = min(n, out.shape[0])
        if n == 0 or rig.diverged:
            return Samples.empty()
        out = np.empty((n, N_FIELDS)) if out is None else out[:n]
        h = self.control_period_s / rig.steps_per_period
        written = run_closed_foreign(rig.state, rig.params, rig.aux, rig.readings, rig.steps_per_period, h,
                                     loop.params, loop.state, loop.controller.kind, loop.controller.params,
                                     loop.controller_state, loop.blocks, loop.table, rig.period, n, out)
        rig.period += written
        loop.period += written
        if written < n:
            rig.diverged = True
        return Samples(out[:written])
