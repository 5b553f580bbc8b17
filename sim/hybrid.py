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

import math

import numpy as np

from .hybrid_metrics import EnergyMonitor, reference_criteria, tracking_criteria
from .isolator import Isolator
from .loop import CONTROL_PERIOD_S, ClosedLoop
from .measurement import Measurement, measured_rows
from .structure import CRIntegrator, ShearBuilding, channel_names, reference_response

MIN_CRITERIA_SAMPLES = 4  # the criteria of fewer samples are NaN (a run that ended in its first periods)
STOP_BRAKE_S = 0.1  # an operator's stop: the table brakes from its speed with this time constant, then fades
# After the ground motion the structure is frozen (its record ends there) and the table comes to rest where it
# is (the isolator's residual displacement stays): it brakes within REST_FADE_S, then holds for REST_HOLD_S, its
# valve closed in the dead zone. (Following the building's ringing after the shaking, tens of micrometres, took
# the valve across its whole dead zone at every reversal: a +-1 V chatter, command std 0.85 V in the last second.)
REST_FADE_S = 1.0
REST_HOLD_S = 1.5


def rest_periods(dt_s: float = CONTROL_PERIOD_S) -> int:
    """The periods a hybrid test runs after its ground motion: the table brought to rest where it is, then held."""
    return int(round((REST_FADE_S + REST_HOLD_S) / dt_s))


def brake_and_fade(r0_m: float, v0_m_per_s: float, fade_periods: int, rows: int, dt_s: float = CONTROL_PERIOD_S,
                   brake_s: float = STOP_BRAKE_S) -> np.ndarray:
    """The target (r, r', r'') for the ``rows`` periods after one whose command was (r0, v0): the table brakes
    exponentially, x(t) = r0 + v0 tau (1 - exp(-t / tau)) with tau = ``brake_s``, times a raised-cosine fade
    w that is exactly 0 from row ``fade_periods`` - 1 on (as sim.loop.fade_table): r = w x, r' = w' x + w x',
    r'' = w'' x + 2 w' x' + w x''. Rows past the fade are zero."""
    out = np.zeros((max(0, int(rows)), 3))
    n = int(fade_periods)
    i = np.arange(1, min(int(rows), n - 2) + 1)  # the fading rows; row n - 1 and after: 0
    if n < 3 or i.size == 0:
        return out
    t = i * dt_s
    decay = np.exp(-t / brake_s)
    x = r0_m + v0_m_per_s * brake_s * (1.0 - decay)
    xd = v0_m_per_s * decay
    xdd = -v0_m_per_s / brake_s * decay
    rate = 1.0 / (n * dt_s)
    phase = np.pi * (i + 1) / n
    w = 0.5 * (1.0 + np.cos(phase))
    wd = -0.5 * np.pi * np.sin(phase) * rate
    wdd = -0.5 * np.pi ** 2 * np.cos(phase) * rate ** 2
    out[: i.size, 0] = w * x
    out[: i.size, 1] = wd * x + w * xd
    out[: i.size, 2] = wdd * x + 2.0 * wd * xd + w * xdd
    return out


def rest_tail(r0_m: float, v0_m_per_s: float, dt_s: float = CONTROL_PERIOD_S,
              brake_s: float = STOP_BRAKE_S) -> np.ndarray:
    """The target after the ground motion's last period (command r0, v0): the table brakes to rest where the
    braking takes it, r_rest = r0 + v0 tau, exactly there after REST_FADE_S (``brake_and_fade`` of the offset
    from r_rest), then held (``rest_periods`` rows in all)."""
    r_rest = r0_m + v0_m_per_s * brake_s
    tail = brake_and_fade(r0_m - r_rest, v0_m_per_s, int(round(REST_FADE_S / dt_s)) + 1, rest_periods(dt_s), dt_s,
                          brake_s)
    tail[:, 0] += r_rest
    return tail


def predicted_with_rest(base_displacement_m: np.ndarray, base_velocity_m_per_s: np.ndarray,
                        dt_s: float = CONTROL_PERIOD_S) -> np.ndarray:
    """The table's displacement a hybrid test is expected to ask for: the reference's base displacement, then
    the table's rest after the ground motion (``rest_tail``; the envelope is checked on this)."""
    x = np.asarray(base_displacement_m, dtype=float)
    tail = rest_tail(float(x[-1]), float(np.asarray(base_velocity_m_per_s)[-1]), dt_s)
    return np.concatenate([x, tail[:, 0]])


def predicted_history(ref: dict, dt_s: float = CONTROL_PERIOD_S, source: str = "the reference's base displacement"):
    """The table's planned motion of a hybrid test as a time history (sim.history.HistoryTarget): the reference's
    (``reference``) base displacement, then its rest (``predicted_with_rest``), neither tapered nor scaled. The
    rig's envelope and the follow detector judge a hybrid test against it (sim.earthquake, isorig hybrid)."""
    from .history import prepare_history

    rested = predicted_with_rest(ref["base_displacement_m"], ref["base_velocity_m_per_s"], dt_s)
    return prepare_history(np.arange(rested.size) * dt_s, rested, dt_s, 1.0, 0.0, 0.0, require_rest=False,
                           source=source)


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
        self.isolator = isolator
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
        self._last_period = -1  # the last period the structure was stepped to
        self._last_force = 0.0  # the force that closed it (held over lost measurements)
        self.stopped_period = None  # the period the structure stopped at (a stop, a trip): its record ends there

    @property
    def n_periods(self) -> int:
        return self.ag.size

    @property
    def total_periods(self) -> int:
        """The periods the loop runs: the ground motion's, then the table's rest (``rest_periods``)."""
        return self.n_periods + rest_periods(self.dt_s)

    def target_table(self) -> np.ndarray:
        """The loop's table to start with: at rest; each period writes the next one, the last the rest."""
        return np.zeros((self.total_periods, 3))

    def warm_up(self) -> None:
        """Run a throwaway copy of this substructure for a few periods, so that the compiled kernels (CR, loaded
        from numba's cache on their first call: 8-55 ms measured) are loaded before a rig is armed: a first
        call inside the loop stalls it past a real rig's watchdog. This substructure is not touched."""
        n = 4
        spare = HybridSubstructure(self.building, self.isolator, np.zeros(n), EnergyMonitor(),
                                   self.dt_s, self.force_correction)
        loop = RecordedLoop(n)
        for k in range(n):
            spare.on_measurement(Measurement(k, k * self.dt_s, 0.0, 0.0, math.nan, math.nan), loop)
        spare.monitor.to_dict()

    def on_measurement(self, m: Measurement, loop: ClosedLoop) -> None:
        """Period k's measurement: close step k with its force, record, predict period k + 1's target.

        Periods whose measurement never arrived (k jumps ahead: a lost packet) are stepped first with the last
        force measured (held, as the loop holds the measurement), so every period the loop runs has the
        structure's target. Once the loop ramps its command to zero (a limit trip, the stability monitor) the
        structure no longer drives anything: it stops. An operator's stop (``loop.stopping``) freezes the
        structure too and brakes the table to rest from where it is (``stop_target``)."""
        k = m.period
        if k >= self.n_periods:
            return
        if self.stopped_period is not None:  # frozen: during a stop's braking the tracking is still watched
            if loop.stopping and not loop.ramping:
                self._watch(m, loop.table[k, 0])
            return
        if loop.ramping:  # open loop (a limit trip, this monitor): the structure is no longer in the loop
            self.stopped_period = loop.period
            return
        if loop.stopping:
            self.stopped_period = loop.period
            self.stop_target(loop, loop.period)
            self._watch(m, loop.table[k, 0])
            return
        for j in range(self._last_period + 1, k):  # lost measurements: the held force closes their steps
            self._step(j, self._last_force, loop)
        commanded = loop.table[k, 0]  # the command that was for t_k
        self._step(k, self.corrected_force(m, commanded), loop)
        self._watch(m, commanded)

    def _watch(self, m: Measurement, commanded_m: float) -> None:
        if self.monitor.update(m.force_n, commanded_m, m.position_m, self.cr.input_energy_j, m.time_s):
            self.tripped = True

    def _step(self, k: int, force_n: float, loop) -> None:
        """Close step k with ``force_n`` (k = 0: the start, at rest), record its channels, write the target of
        period k + 1."""
        if k > 0:
            self.cr.advance(force_n, float(self.ag[k]))
        self.cr.write_channels(self.channels[k])
        self._last_period = k
        self._last_force = force_n
        if k + 1 < self.n_periods:
            x_next = self.cr.next_base_displacement()
            loop.set_target(k + 1, x_next, float(self.cr.vp[0]), float(self.cr.a[0]))
        elif k + 1 == self.n_periods:  # the ground motion's last period: the structure stops, the table rests
            self.rest_target(loop, k)

    def rest_target(self, loop, k: int) -> None:
        """After the structure's last period k: the table brakes to rest from that period's command and holds
        there (``rest_tail``), in the periods of the loop's table that follow."""
        end = min(loop.total_periods, loop.table.shape[0])
        if k + 1 >= end:
            return
        loop.table[k + 1:end] = rest_tail(float(loop.table[k, 0]), float(loop.table[k, 1]), self.dt_s)[: end - k - 1]

    def stop_target(self, loop, k: int, brake_s: float = STOP_BRAKE_S) -> None:
        """An operator's stop from period k (the first the loop has not run): from the command of period k
        (r0, v0, written before the stop) the table brakes
        exponentially, x(t) = r0 + v0 tau (1 - exp(-t / tau)) with tau = ``brake_s``, and the loop's fade
        (sim.loop.ClosedLoop.ramp_out: a raised cosine to zero over the periods the loop has left) takes it to
        zero: r = w x, r' = w' x + w x', r'' = w'' x + 2 w' x' + w x''. The structure is frozen; its record ends
        at k. (The loop's own fade multiplies the table, but a hybrid table holds only the next period.)"""
        end = min(loop.total_periods, loop.table.shape[0])
        if k + 1 >= end:
            return
        # as sim.loop.fade_table from period k: exactly 0 at the loop's last period
        loop.table[k + 1:end] = brake_and_fade(float(loop.table[k, 0]), float(loop.table[k, 1]), end - k, end - k - 1,
                                               self.dt_s, brake_s)

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

    @property
    def periods_run(self) -> int:
        """How many periods the structure ran in the loop (its record: ``channels[:periods_run]``)."""
        end = self._last_period + 1
        return min(end, self.stopped_period) if self.stopped_period is not None else end

    def results(self, samples) -> dict:
        """The structure's channels (as recorded), the tracking criteria J1-J3 of the rig over the periods
        measured, and ``lost_periods`` (those whose measurement was lost)."""
        n = min(len(samples), self.n_periods)
        out = {name: self.channels[:n, j] for j, name in enumerate(self.names)}
        measured = measured_rows(samples["flags"][:n])
        out["lost_periods"] = int(np.count_nonzero(~measured))  # held readings, left out of J2 and J3
        if n >= MIN_CRITERIA_SAMPLES:
            out["criteria"] = tracking_criteria(samples["target_m"][:n], samples["displacement_m"][:n], self.dt_s,
                                                 measured=measured)
        else:  # a run that ended at once (a fault in its first periods): no criteria, but a summary
            out["criteria"] = {"j1_delay_ms": math.nan, "j2_rms_percent": math.nan, "j3_peak_percent": math.nan}
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
    if np.count_nonzero(ok) < MIN_CRITERIA_SAMPLES:
        return {"j4_rms_percent": math.nan, "j5_peak_percent": math.nan}
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


class RecordedLoop:
    """What ``HybridSubstructure.on_measurement`` needs of a loop, to replay a record: the table, with each
    period's command set from the record before its measurement is replayed, and what the structure predicted
    (``predicted``: its target for each period)."""

    def __init__(self, n_periods: int):
        self.table = np.zeros((n_periods, 3))
        self.predicted = np.full(n_periods, np.nan)
        self.total_periods = n_periods
        self.period = 0
        self.stopping = False
        self.ramping = False

    def set_target(self, period: int, r_m: float, r_dot_m_per_s: float, r_ddot_m_per_s2: float = 0.0) -> None:
        self.predicted[period] = r_m
        self.table[period] = (r_m, r_dot_m_per_s, r_ddot_m_per_s2)


def replay(building: ShearBuilding, isolator: Isolator, ground_acc_m_per_s2: np.ndarray, samples,
           end_period: int | None = None, monitor: EnergyMonitor | None = None, dt_s: float = CONTROL_PERIOD_S
           ) -> dict:
    """The structure's response of a hybrid test rebuilt from its record: the recorded measurements (position
    and force, ``measured_displacement_m``, ``force_n``) are fed period by period through a new
    ``HybridSubstructure``, each period's command being the recorded target. The integrator is deterministic,
    so this is the response the test computed, to the precision the record keeps (7 significant digits);
    ``command_difference_m`` (the largest |predicted - recorded target|) says how close. Rows whose measurement
    was lost are skipped (the test held the force over them, as the replay does). The replay ends at
    ``end_period`` (e.g. an operator's stop: the structure froze there), at the first row without a target (a
    command ramp: open loop) or at the end of the record.

    Returns ``channels`` (name -> array over the replayed periods), ``periods``, ``time_s``, the monitor's
    ``added_energy_j`` and ``limit_j`` per period, ``monitor`` (its final state, to_dict) and
    ``command_difference_m``."""
    from .measurement import FLAG_LOST, FLAG_OPEN_LOOP

    sub = HybridSubstructure(building, isolator, ground_acc_m_per_s2, monitor=monitor, dt_s=dt_s)
    n = min(len(samples), sub.n_periods, sub.n_periods if end_period is None else max(0, int(end_period)))
    loop = RecordedLoop(sub.n_periods)
    t, y, f = samples["time_s"], samples["measured_displacement_m"], samples["force_n"]
    target = samples["target_m"]
    flags = np.nan_to_num(samples["flags"]).astype(np.int64)
    energy = np.full(n, np.nan)
    limit = np.full(n, np.nan)
    done = 0
    for k in range(n):
        if not np.isfinite(target[k]) or flags[k] & FLAG_OPEN_LOOP:
            break
        done = k + 1
        if flags[k] & FLAG_LOST:
            continue
        loop.table[k, 0] = target[k]
        loop.period = k
        sub.on_measurement(Measurement(k, float(t[k]), float(y[k]), float(f[k]), math.nan, math.nan), loop)
        energy[k] = sub.monitor.added_energy_j
        limit[k] = sub.monitor.limit_j
    done = min(done, sub.periods_run)
    compared = np.abs(loop.predicted[1:done] - target[1:done])
    compared = compared[np.isfinite(compared)]
    return {"substructure": sub, "periods": done, "time_s": np.arange(done) * dt_s,
            "channels": {name: sub.channels[:done, j].copy() for j, name in enumerate(sub.names)},
            "added_energy_j": energy[:done], "limit_j": limit[:done], "monitor": sub.monitor.to_dict(),
            "command_difference_m": float(np.max(compared)) if compared.size else None}

