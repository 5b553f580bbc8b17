"""Real-time hybrid simulation (RTHS): the building above the isolator in the computer, the isolator on the rig.

Each control period k the rig's measurement arrives; ``HybridSubstructure.on_measurement`` closes the
numerical step with the isolator force just measured (sim.structure.CRIntegrator.advance: the explicit CR
algorithm, stable for this use), predicts the base displacement for t_{k+1} and writes it as the loop's target
of period k + 1 (sim.loop.ClosedLoop.set_target). The tracking controller's feed-forward makes the table
reach a period's target at that period's start (its delay J1 is a few hundredths of a millisecond), so the
force measured at period k + 1 is the force at the commanded displacement, as the CR step assumes. (Writing
the prediction as period k's target instead, one period early, raised J4 on IUT_a from 2.8-3.5 % to
3.4-4.6 %: measured with scripts/earthquake_targets.py.) The small force error that the tracking error still
leaves on a stiff specimen is corrected to the commanded displacement (``force_correction``).

The energy the tracking error adds to the loop is watched by sim.hybrid_metrics.EnergyMonitor; above its
threshold the caller stops the test in a controlled way. ``run_virtual`` runs the whole thing against the
simulated rig (virtual RTHS) and ``reference`` integrates the same structure with the isolator's Bouc-Wen
model offline, to measure J4 and J5.
"""

from __future__ import annotations

import numpy as np

from .hybrid_metrics import EnergyMonitor, reference_criteria, tracking_criteria
from .isolator import Isolator
from .loop import CONTROL_PERIOD_S, ClosedLoop
from .measurement import Measurement
from .structure import CRIntegrator, ShearBuilding, channel_names, reference_response


def ground_at_periods(time_s: np.ndarray, acc_m_per_s2: np.ndarray, dt_s: float = CONTROL_PERIOD_S) -> np.ndarray:
    """The ground acceleration at every control period (linear between the record's samples, 0 after it)."""
    t = np.asarray(time_s, dtype=float)
    n = int(np.floor((t[-1] - t[0]) / dt_s)) + 1
    return np.interp(t[0] + np.arange(n) * dt_s, t, np.asarray(acc_m_per_s2, dtype=float), right=0.0)


class HybridSubstructure:
    """The numerical substructure of one RTHS test and what it records.

    ``building`` above the isolation level, ``isolator`` for the integrator's stability (its largest tangent
    stiffness; the force itself is measured), the ground acceleration at every control period. ``channels``
    (one row per period, ``channel_names``) records the structure's response: base displacement, storey
    drifts, absolute accelerations, isolator force.
    """

    def __init__(self, building: ShearBuilding, isolator: Isolator, ground_acc_m_per_s2: np.ndarray,
                 monitor: EnergyMonitor | None = None, dt_s: float = CONTROL_PERIOD_S,
                 force_correction: bool = True):
        self.building = building
        self.ag = np.ascontiguousarray(ground_acc_m_per_s2, dtype=float)
        self.dt_s = dt_s
        self.cr = CRIntegrator(building, dt_s, isolator, float(self.ag[0]))
        self.names = channel_names(building)
        self.channels = np.full((self.ag.size, len(self.names)), np.nan)
        self.monitor = monitor or EnergyMonitor()
        self.tripped = False
        self.force_correction = force_correction
        self.stiffness_n_per_m = isolator.kd_n_per_m  # the specimen's tangent stiffness, estimated as it runs
        self._previous = None  # (displacement, force) of the previous period

    @property
    def n_periods(self) -> int:
        return self.ag.size

    def target_table(self) -> np.ndarray:
        """The loop's table to start with: at rest; each period writes the next one."""
        return np.zeros((self.n_periods, 3))

    def on_measurement(self, m: Measurement, loop: ClosedLoop) -> None:
        """Period k's measurement: close step k with its force, record, predict period k + 1's target."""
        k = m.period
        if k >= self.n_periods:
            return
        commanded = loop.table[k, 0]  # the command that was for t_k
        if k > 0:
            self.cr.advance(self.corrected_force(m, commanded), float(self.ag[k]))
        self.cr.write_channels(self.channels[k])
        if self.monitor.update(m.force_n, commanded, m.position_m, self.cr.input_energy_j, m.time_s):
            self.tripped = True
        if k + 1 < self.n_periods:
            x_next = self.cr.next_base_displacement()
            loop.set_target(k + 1, x_next, float(self.cr.vp[0]), float(self.cr.a[0]))

    def corrected_force(self, m: Measurement, commanded_m: float) -> float:
        """The force measured, corrected to the commanded displacement: F + k_t (x_command - y_measured), k_t the
        specimen's tangent stiffness estimated from its last force and displacement increments (smoothed,
        taken only when the table moved at least 2 um). The tracking error is a few hundredths of a millimetre
        and k_t of a stiff bearing over a MN/m: uncorrected, that force error was most of J4."""
        y, f = m.position_m, m.force_n
        if self._previous is not None:
            dy, df = y - self._previous[0], f - self._previous[1]
            if abs(dy) > 2e-6:
                k_raw = df / dy
                if 0.0 < k_raw < 20.0 * self.cr.isolator_stiffness_n_per_m:
                    self.stiffness_n_per_m += 0.1 * (k_raw - self.stiffness_n_per_m)
        self._previous = (y, f)
        if not self.force_correction:
            return f
        return f + self.stiffness_n_per_m * (commanded_m - y)

    def results(self, samples) -> dict:
        """The structure's channels (as recorded) and the tracking criteria J1-J3 of the rig."""
        n = min(len(samples), self.n_periods)
        out = {name: self.channels[:n, j] for j, name in enumerate(self.names)}
        out["criteria"] = tracking_criteria(samples["target_m"][:n], samples["displacement_m"][:n], self.dt_s)
        out["stability"] = self.monitor.to_dict()
        return out


def reference(building: ShearBuilding, isolator: Isolator, ground_acc_m_per_s2: np.ndarray,
              dt_s: float = CONTROL_PERIOD_S) -> dict:
    """The full-numerical reference: the same structure with the isolator's Bouc-Wen model, offline."""
    t = np.arange(len(ground_acc_m_per_s2)) * dt_s
    return reference_response(building, isolator, t, np.asarray(ground_acc_m_per_s2, dtype=float))


def compare_with_reference(channels: dict, ref: dict) -> dict:
    """J4 and J5 of the base displacement against the reference (sim.hybrid_metrics)."""
    x = channels["base_displacement_m"]
    n = min(len(x), len(ref["base_displacement_m"]))
    ok = np.isfinite(x[:n])
    return reference_criteria(x[:n][ok], ref["base_displacement_m"][:n][ok])


def run_virtual(sub: HybridSubstructure, loop: ClosedLoop, plant) -> tuple:
    """Virtual RTHS: the hybrid loop against a sim.plant.SimulatedPlant, one period at a time. Stops in a
    controlled way (command ramp) when the stability monitor trips. Returns (samples, stopped_reason)."""
    from .samples import Samples

    parts = []
    reason = None
    while not loop.done:
        m = plant.measure()
        sub.on_measurement(m, loop)
        if sub.tripped and not loop.ramping:
            reason = sub.monitor.reason
            loop.begin_command_ramp()
        u, rows = loop.step(m)
        parts.append(rows)
        plant.advance(u)
    return Samples.concatenate(parts), reason
