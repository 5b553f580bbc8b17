"""Does the table follow its target? The detector of a rig the controller cannot follow, and the verdict.

A controller told the wrong rig (an oil column softer than declared, a valve slower, a dead zone wider)
either oscillates (a limit cycle near the oil column, tens of hertz) or tracks at percent level while the
learning cannot absorb the mismatch. Either way the test's record would be worthless and the rig is driven
by a loop that is not what it was designed as. ``FollowMonitor`` watches the position reading against the
target (the target of ``L`` ago for a reading ``L`` late, as the servo aims) and trips:

- on an **oscillation**: the part of the error above ``corner_hz`` (the target's own harmonics that matter are
  below) has an RMS above ``oscillation_share`` of the amplitude (at least ``floor_m``) over the last
  ``oscillation_window_s``, anywhere in the test after its first ``oscillation_window_s``;
- on **tracking** that the learning does not bring within ``rms_share``: at the end of each steady cycle of a
  sine block after its first ``learning_cycles``, the cycle's RMS error is above ``rms_share`` of the amplitude
  and either it fell by less than ``min_improvement`` since the cycle before, or ``improving_cycles`` more
  steady cycles have passed (the learning removes most of the periodic error every cycle; what it cannot
  absorb stays).

``tracking_verdict`` says after a test how well the table followed: within the labs' target (0.1 % of the
amplitude), followed outside it, or did not follow (above ``rms_share``), over each block's last two steady
cycles (the learning's converged cycles; fewer when a block has fewer). Pure numerics: the worker acts on a
trip (the valve closes at once: the controller is no longer trusted), the summaries carry the verdict.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy import signal

from .loop import CONTROL_PERIOD_S
from .measurement import measured_rows

LAB_TARGET_SHARE = 0.001  # the labs' target: the table follows within 0.1 % of the amplitude
HISTORY_J2_BOUND = 0.01  # a time history follows when its J2 is within this (sim.hybrid_metrics.CRITERIA)
ADVICE = ("the rig is not what the controller was told: commission it (isorig identify rig, or the console's "
          "Commissioning page) and run with the rig file it writes")


def advice_for(controller: str) -> str:
    """What to do when the table does not follow: commission the rig, or (a baseline controller) use the servo."""
    if controller == "servo":
        return ADVICE
    return (f"the {controller} controller does not follow this rig; the default servo controller does "
            "(docs/compare.md), and a rig it does not follow is commissioned with isorig identify rig")


@dataclass(frozen=True)
class FollowLimits:
    """When the table is judged not to follow (shares of the amplitude; SI)."""

    rms_share: float = 0.01
    #: the learning's transient: the servo's error may grow in its second steady cycle (its compression feed-forward
    #: and the harmonics past the oil column start from the first ones) before it falls (docs/controller.md)
    learning_cycles: int = 2
    min_improvement: float = 0.2
    improving_cycles: int = 2
    #: measured on 12 drawn rigs told exactly (scripts/commissioning_targets.py): their error above 10 Hz
    #: reaches 1.05 % of a 2 mm amplitude while the learning converges, so 2 % (and 40 um) is an oscillation
    oscillation_share: float = 0.02
    floor_m: float = 4e-5
    oscillation_window_s: float = 0.5
    corner_hz: float = 10.0
    corner_harmonic: float = 8.0

    def to_dict(self) -> dict:
        return {"rms_share": self.rms_share, "min_improvement": self.min_improvement,
                "learning_cycles": self.learning_cycles, "improving_cycles": self.improving_cycles,
                "oscillation_share": self.oscillation_share,
                "floor_m": self.floor_m, "oscillation_window_s": self.oscillation_window_s,
                "corner_hz": self.corner_hz, "corner_harmonic": self.corner_harmonic}


def limits_for(controller: str) -> FollowLimits:
    """The monitor's limits for a controller: a fixed-gain one (``pid``) learns nothing, so its first steady
    cycle is judged; the learning ones (``servo``, the paper's ``mrac``) get their transient."""
    return FollowLimits(learning_cycles=0) if controller == "pid" else FollowLimits()



@dataclass
class Reference:
    """Each sine block of a test as the monitor judges it: first period, amplitude, period in control periods,
    taper and total cycles. A time history is one span at its peak with no cycles (its J criteria are its
    verdict)."""

    starts: np.ndarray
    amplitudes: np.ndarray
    periods: np.ndarray  # control periods per target cycle (0: a history)
    tapers: np.ndarray
    cycles: np.ndarray

    def span(self, k: np.ndarray) -> np.ndarray:
        return np.clip(np.searchsorted(self.starts, k, side="right") - 1, 0, self.starts.size - 1)

    def cycle(self, k: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(span, cycle within its block, steady?) of each period k."""
        b = self.span(k)
        p = self.periods[b]
        c = np.where(p > 0, (k - self.starts[b]) // np.maximum(p, 1), -1)
        steady = (p > 0) & (c >= self.tapers[b]) & (c < self.cycles[b] - self.tapers[b])
        return b, c, steady


def reference_for(profile, history=None) -> Reference:
    """The ``Reference`` of a sine profile (a list of SineProfile blocks) or of a time history's r (m)."""
    if history is not None or not profile:
        r = np.asarray(history if history is not None else [0.0], dtype=float)
        peak = float(np.max(np.abs(r))) if r.size else 0.0
        return Reference(np.array([0]), np.array([peak]), np.array([0]), np.array([0]), np.array([0]))
    starts, amps, periods = [], [], []
    t = 0.0
    for b in profile:
        starts.append(int(round(t / CONTROL_PERIOD_S)))
        amps.append(b.amplitude_m)
        periods.append(int(round(1.0 / b.frequency_hz / CONTROL_PERIOD_S)))
        t += b.cycles / b.frequency_hz
    return Reference(np.array(starts), np.array(amps), np.array(periods),
                     np.array([b.taper_cycles for b in profile]), np.array([b.cycles for b in profile]))


LOST_WINDOW_PERIODS = 1000  # a trip names the periods lost on the link over the last second ...
LOST_SHARE_BLAMED = 0.01  # ... and blames them, not the rig's description, beyond this share


@dataclass
class FollowTrip:
    """The table did not follow: when, why (``kind``: oscillation or tracking), the figures and the message."""

    index: int
    time_s: float
    kind: str
    message: str
    values: dict = field(default_factory=dict)


class FollowMonitor:
    """Feed it the test's rows in order (``check``); it returns the first ``FollowTrip`` or None."""

    def __init__(self, reference: Reference, latency_s: float = 0.0, limits: FollowLimits | None = None,
                 advice: str = ADVICE):
        self.reference = reference
        self.advice = advice
        self.limits = limits or FollowLimits()
        self.lag = max(0.0, latency_s) / CONTROL_PERIOD_S
        self.n_osc = max(1, int(round(self.limits.oscillation_window_s / CONTROL_PERIOD_S)))
        top_hz = max((1.0 / (p * CONTROL_PERIOD_S) for p in reference.periods if p > 0), default=0.0)
        self.corner_hz = min(max(self.limits.corner_hz, self.limits.corner_harmonic * top_hz), 200.0)
        b, a = signal.butter(2, self.corner_hz, btype="highpass", fs=1.0 / CONTROL_PERIOD_S)
        self.biquad = (*(float(x) for x in b), float(a[1]), float(a[2]))
        self.z = [0.0, 0.0]  # the high-pass's state (transposed direct form II)
        self.r_hist = np.full(int(math.ceil(self.lag)) + 2, np.nan)  # the last targets (for r(t - L))
        self.e_hf = np.full(self.n_osc, np.nan)
        self.cycle_key = (-1, -1)  # (span, cycle) being summed
        self.cycle_sum = 0.0
        self.cycle_n = 0
        self.previous_share: float | None = None  # the last steady cycle's RMS share in this block
        self.steady_judged = 0  # steady cycles judged in this block
        self.tripped: FollowTrip | None = None
        self.last_fresh: tuple[int, float] | None = None  # (period, reading) of the last fresh measurement
        self.lost_recent = np.zeros(LOST_WINDOW_PERIODS, dtype=bool)  # which of the last periods were lost

    def _late_target(self, r: np.ndarray) -> np.ndarray:
        """r(t - L) for each row of this block, from the targets kept."""
        full = np.concatenate([self.r_hist, r])
        self.r_hist = full[-self.r_hist.size:]
        return late(full, self.lag)[-r.size:]

    def _bridge_lost(self, k: np.ndarray, y: np.ndarray, lost: np.ndarray) -> np.ndarray:
        """The readings with each lost period's (an older reading held) replaced by a straight line between
        the fresh readings around it: a host's stall must not look like a step of the table to the
        oscillation detector. The tracking figures skip lost periods altogether (``check``)."""
        fresh = ~lost & np.isfinite(y)
        known_k, known_y = k[fresh], y[fresh]
        if self.last_fresh is not None:
            known_k, known_y = np.concatenate([[self.last_fresh[0]], known_k]), np.concatenate([[self.last_fresh[1]],
                                                                                             known_y])
        if known_k.size:
            self.last_fresh = (int(known_k[-1]), float(known_y[-1]))
        if not lost.any() or known_k.size == 0:
            return y
        out = y.copy()
        out[lost] = np.interp(k[lost], known_k, known_y)
        return out

    def check(self, rows) -> FollowTrip | None:
        """Take the next rows of the test (the worker's blocks of ten periods; ``feed`` cuts a record into
        such blocks) and judge what they complete."""
        if self.tripped is not None or len(rows) == 0:
            return None
        t = np.asarray(rows["time_s"], dtype=float)
        r = np.asarray(rows["target_m"], dtype=float)
        y = np.asarray(rows["measured_displacement_m"], dtype=float)
        k = np.round(t / CONTROL_PERIOD_S).astype(np.int64)
        lost = ~measured_rows(rows["flags"])
        y = self._bridge_lost(k, y, lost)
        self.lost_recent = np.concatenate([self.lost_recent, lost])[-LOST_WINDOW_PERIODS:]
        e = y - self._late_target(r)
        closed = np.isfinite(e)
        e_hf = self._high_pass(np.where(closed, e, 0.0))
        self.e_hf = np.concatenate([self.e_hf, np.where(closed, e_hf, np.nan)])[-self.n_osc:]
        span, cycle, steady = self.reference.cycle(k)
        lim = self.limits
        a = float(self.reference.amplitudes[span[-1]])
        if not np.any(np.isnan(self.e_hf)):
            hf = float(np.sqrt(np.mean(self.e_hf ** 2)))
            bound = max(lim.oscillation_share * a, lim.floor_m)
            if hf > bound:
                return self._trip(len(rows) - 1, float(t[-1]), "oscillation", hf, bound, a)
        cut = np.flatnonzero((span[1:] != span[:-1]) | (cycle[1:] != cycle[:-1])) + 1
        for a, b in zip(np.concatenate([[0], cut]), np.concatenate([cut, [len(rows)]]), strict=True):
            key = (int(span[a]), int(cycle[a]))
            if key != self.cycle_key:
                trip = self._cycle_done(int(a), float(t[a]))
                if trip is not None:
                    return trip
                if key[0] != self.cycle_key[0]:
                    self.previous_share, self.steady_judged = None, 0
                self.cycle_key, self.cycle_sum, self.cycle_n = key, 0.0, 0
                self.cycle_steady = bool(steady[a])
            part = e[a:b][closed[a:b] & ~lost[a:b]]  # a lost period's reading is an older one: not judged
            self.cycle_sum += float(np.dot(part, part))
            self.cycle_n += part.size
        return None

    def _cycle_done(self, i: int, t: float) -> FollowTrip | None:
        """The cycle being summed has ended: judge it if it was a steady one after its block's first
        ``learning_cycles``."""
        b, c = self.cycle_key
        if b < 0 or not getattr(self, "cycle_steady", False) or self.cycle_n < 0.9 * self.reference.periods[b]:
            return None
        a = float(self.reference.amplitudes[b])
        share = math.sqrt(self.cycle_sum / self.cycle_n) / a if a > 0 else 0.0
        previous, self.previous_share = self.previous_share, share
        self.steady_judged += 1
        lim = self.limits
        if self.steady_judged <= lim.learning_cycles:
            return None  # the learning's transient
        stuck = (previous is None or share > (1.0 - lim.min_improvement) * previous
                 or self.steady_judged > lim.learning_cycles + lim.improving_cycles)
        if share > lim.rms_share and stuck:
            return self._trip(i, t, "tracking", share * a, lim.rms_share * a, a)
        return None

    def _high_pass(self, x: np.ndarray) -> np.ndarray:
        """The second-order Butterworth high-pass at ``corner_hz``, sample by sample (ten at a time in the
        worker: a loop here costs less than scipy's call)."""
        b0, b1, b2, a1, a2 = self.biquad
        z1, z2 = self.z
        out = np.empty(x.size)
        for i, xi in enumerate(x.tolist()):
            yi = b0 * xi + z1
            z1 = b1 * xi - a1 * yi + z2
            z2 = b2 * xi - a2 * yi
            out[i] = yi
        self.z = [z1, z2]
        return out

    def feed(self, samples, block: int = 10) -> FollowTrip | None:
        """``check`` a whole record in blocks of ``block`` rows, as the worker would; the first trip or None."""
        for i in range(0, len(samples), block):
            trip = self.check(samples[i:i + block])
            if trip is not None:
                trip.index += i
                return trip
        return None

    def _trip(self, i: int, t: float, kind: str, value: float, bound: float, amplitude: float) -> FollowTrip:
        share = value / amplitude if amplitude > 0 else math.inf
        if kind == "oscillation":
            f = oscillation_frequency_hz(self.e_hf)
            what = (f"a sustained oscillation near {f:.0f} Hz: {value * 1e3:.3g} mm RMS over the last "
                    f"{self.limits.oscillation_window_s:g} s ({100 * share:.2g} % of the amplitude; at most "
                    f"{bound * 1e3:.3g} mm)")
        else:
            f = None
            what = (f"|y - r| {value * 1e3:.3g} mm RMS over the last cycle, {100 * share:.2g} % of the "
                    f"{amplitude * 1e3:.4g} mm amplitude (at most {100 * self.limits.rms_share:g} %), and the "
                    "learning is not bringing it down")
        lost = int(np.count_nonzero(self.lost_recent))
        advice = self.advice
        if lost > LOST_SHARE_BLAMED * LOST_WINDOW_PERIODS:  # the host or the link, not the rig's description
            advice = (f"{lost} of the last {LOST_WINDOW_PERIODS} periods were lost on the link (a host that stalls "
                      "or a link that drops packets: see the link figures), so the controller held its command "
                      "through them; make the host's real-time path steadier before commissioning the rig")
        message = f"the table does not follow its target at t = {t:.3f} s: {what}; {advice}"
        values = {"time_s": t, "kind": kind, "value_m": value, "limit_m": bound, "amplitude_m": amplitude,
                  "share": share, "frequency_hz": f, "lost_periods_last_s": lost}
        self.tripped = FollowTrip(i, t, kind, message, values)
        return self.tripped


def late(r: np.ndarray, periods: float) -> np.ndarray:
    """r ``periods`` earlier (linear between periods; NaN before the start)."""
    if periods <= 0.0:
        return r
    k = np.arange(r.size, dtype=float)
    return np.interp(k - periods, k, r, left=np.nan)


def oscillation_frequency_hz(x: np.ndarray) -> float:
    """The dominant frequency of a zero-mean signal from its zero crossings."""
    x = x[np.isfinite(x)]
    if x.size < 3:
        return float("nan")
    crossings = np.count_nonzero(np.signbit(x[1:]) != np.signbit(x[:-1]))
    return crossings / (2.0 * x.size * CONTROL_PERIOD_S)


def tracking_verdict(samples, profile, history_criteria: dict | None = None,
                     limits: FollowLimits | None = None, advice: str = ADVICE, latency_s: float = 0.0) -> dict:
    """How well the table followed: ``verdict`` (``followed``: within LAB_TARGET_SHARE; ``outside_target``:
    within the monitor's ``rms_share``; ``did_not_follow``; ``not_judged``: no steady cycle ran), the figure
    it rests on (``rms_share``: the worst block's RMS |y - r| over its judged cycles / its amplitude; a time
    history: J2 / 100), and words for a person. Judged as the monitor judges: the position reading against the
    target of ``latency_s`` (the rig's declared position latency) ago, so that a real rig's record (its reading)
    and a simulation's are judged alike."""
    limits = limits or FollowLimits()
    if history_criteria is not None:
        j2 = history_criteria.get("j2_rms_percent")
        if j2 is None or not math.isfinite(j2):
            return {"verdict": "not_judged", "words": "not judged (no record to judge)"}
        share = j2 / 100.0
        out = {"rms_share": share, "limit_share": HISTORY_J2_BOUND, "basis": "J2, the normalised RMS tracking error"}
        if share <= HISTORY_J2_BOUND:
            bound = f"{100 * HISTORY_J2_BOUND:g} %"
            return {**out, "verdict": "followed", "words": f"followed: J2 {j2:.3g} % (within its {bound} bound)"}
        return {**out, "verdict": "did_not_follow", "words": f"did not follow: J2 {j2:.3g} % (more than "
                                                            f"{100 * HISTORY_J2_BOUND:g} %); {advice}"}
    n = len(samples)
    if n == 0 or not profile:
        return {"verdict": "not_judged", "words": "not judged (no steady cycle ran)"}
    ref = reference_for(profile)
    r = np.asarray(samples["target_m"], dtype=float)
    e = np.asarray(samples["measured_displacement_m"], dtype=float) - late(r, latency_s / CONTROL_PERIOD_S)
    worst = None
    for b in range(ref.starts.size):
        a = float(ref.amplitudes[b])
        full = []  # the block's steady cycles that ran whole at the amplitude (a stop's ramp-out is not)
        for c in range(int(ref.tapers[b]), int(ref.cycles[b] - ref.tapers[b])):
            i0, i1 = ref.starts[b] + c * ref.periods[b], ref.starts[b] + (c + 1) * ref.periods[b]
            if i1 <= n and a > 0 and np.all(np.isfinite(e[i0:i1])) and np.ptp(r[i0:i1]) >= 1.98 * a:
                full.append((i0, i1))
        if not full:
            continue
        judged = full[-2:] if len(full) >= 3 else full[1:] or full
        err = np.concatenate([e[i0:i1] for i0, i1 in judged])
        share = float(np.sqrt(np.mean(err ** 2)) / a)
        worst = share if worst is None else max(worst, share)
    if worst is None:
        return {"verdict": "not_judged", "words": "not judged (no steady cycle ran)"}
    return _verdict(worst, limits, "RMS |y - r| over each block's last two steady cycles, over its amplitude",
                    advice)


def _verdict(share: float, limits: FollowLimits, basis: str, advice: str) -> dict:
    out = {"rms_share": share, "lab_target_share": LAB_TARGET_SHARE, "limit_share": limits.rms_share,
           "basis": basis}
    if share <= LAB_TARGET_SHARE:
        out.update(verdict="followed", words=f"followed: {100 * share:.3g} % (within the "
                                              f"{100 * LAB_TARGET_SHARE:g} % target)")
    elif share <= limits.rms_share:
        out.update(verdict="outside_target", words=f"followed at {100 * share:.3g} %, outside the "
                                                    f"{100 * LAB_TARGET_SHARE:g} % target")
    else:
        out.update(verdict="did_not_follow", words=f"did not follow: {100 * share:.3g} % (more than "
                                                    f"{100 * limits.rms_share:g} %); {advice}")
    return out
