"""Does the table follow its target? The detector of a rig the controller cannot follow, and the verdict.

A controller told the wrong rig (an oil column softer than declared, a valve slower, a dead zone wider)
either oscillates (a limit cycle near the oil column, tens of hertz) or tracks at percent level while the
learning cannot absorb the mismatch. Either way the test's record would be worthless and the rig is driven
by a loop that is not what it was designed as. ``FollowMonitor`` watches the position reading against the
target (the target of ``L`` ago for a reading ``L`` late, as the servo aims) and trips:

- on an **oscillation**: the part of the error above ``corner_hz`` (a fourth-order high-pass; the target's own
  harmonics that matter are below) that does not repeat from one test period to the next (a component at a whole
  multiple of the test frequency is tracking error, never an oscillation: the smaller of the RMS of the
  high-passed error and of it less its value one test period earlier) has an RMS above ``oscillation_share`` of
  the amplitude (at least ``floor_m``) over the last ``oscillation_window_s``, anywhere in the test after its
  first ``oscillation_window_s``; in the steady cycles (``Reference.settled``, no period lost in the last second)
  above ``steady_oscillation_share``, so an oscillation that starts mid-test is stopped within 2 s;
- on a **tone** (an oscillation told by its signature, not by its size alone): in those steady cycles, the part of
  the error that does not repeat with the test repeats every period of its own (``tone_correlation``: the mean of
  c(t) c(t + T) over the mean of c^2, T from its zero crossings), as strong in either half of the window
  (``tone_sustain``: not a ring that dies), and its RMS is above ``tone_share`` of the amplitude (the labs' target)
  and ``tone_floor_m``: an oscillation that hovers about the size rule's floor is stopped as quickly as a large one;
- on **tracking** that the learning does not bring within ``rms_share``: at the end of each steady cycle of a
  sine block after its first ``learning_cycles``, the cycle's RMS error is above ``rms_share`` of the amplitude
  and the learning no longer gains ``min_improvement`` a cycle (the cycle's error is not that much below the
  cycle before's, nor the smallest error of the block's steady cycles so far (1 - min_improvement)^2 of the
  smallest of two cycles earlier), or ``improving_cycles`` more steady cycles have passed (the learning removes
  most of the periodic error every cycle, in steps where it overshoots; what it cannot absorb stays).

``tracking_verdict`` says after a test how well the table followed: within the labs' target (0.1 % of the
amplitude), followed outside it, or did not follow (above ``rms_share``), over each block's last two steady
cycles (the learning's converged cycles; fewer when a block has fewer), with a commissioned latency anywhere
within its uncertainty (the worst figure counts). On a commissioned rig (``commissioning_facts``) an oscillation is
named as the controller's own, with what to try; a stop while the actuator was held at its force limit
(sim.force_limit, over the last test period) is named as that (``values["cause"]``), whichever rule made it.
Pure numerics: the worker acts on a trip (the valve closes at once: the controller is no longer trusted), the
summaries carry the verdict.

The monitor judges in one compiled call (``_judge_blocks``: a whole record cut into the worker's blocks, or one
block), bit for bit the per-block numpy path it replaced (``FollowMonitor._check_reference``, kept as the
reference tests/test_follow.py compares with): the same sums in the same order (numpy's pairwise mean,
``numpy.interp``'s arithmetic, OpenBLAS's dot of a block, probed once per process: ``dot_is_fused``).
"""

from __future__ import annotations

import copy
import dataclasses
import functools
import math
from dataclasses import dataclass, field

import numpy as np
from llvmlite import ir
from numba import njit, types
from numba.extending import intrinsic

from .force_limit import ActuatorLimits, at_force_limit, diagnosis
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


def commissioning_facts(section: dict | None) -> dict | None:
    """What the monitor and the verdict need of a rig file's ``commissioning`` section (sim.rigfile
    RigDescription.commissioning, written by ``isorig identify rig``): when, whether the fit was trusted, the
    excitation's velocity bound, and the position latency's estimate with its one-sigma uncertainty. None for a
    rig nobody commissioned (a rig file written by hand, or the defaults). Takes its own output as well, so a job
    can carry the few facts instead of the section."""
    if not isinstance(section, dict) or not section:
        return None
    if section.get("trusted") is False:
        return None  # a fit isorig did not trust is no commissioning of the rig
    estimates = section.get("estimates") if isinstance(section.get("estimates"), dict) else {}
    latency = estimates.get("position_latency_s") if isinstance(estimates.get("position_latency_s"), dict) else {}

    def number(x):
        return float(x) if isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x) else None

    return {"date": section.get("date") if isinstance(section.get("date"), str) else None,
            "max_velocity_m_per_s": number(section.get("max_velocity_m_per_s")),
            "position_latency_s": number(latency.get("value", section.get("position_latency_s"))),
            "position_latency_std_s": number(latency.get("std", section.get("position_latency_std_s")))}


#: the gain a lab lowers first when a controller's loop oscillates, per controller (its option's name)
LOOP_GAIN_OPTIONS = {"servo": "kp_per_s", "pid": "kp_v_per_m"}


def _option_value(controller: str, name: str, options: dict | None) -> float | None:
    """The value the run used for a controller option: the run's own, else the controller's default."""
    if options and isinstance(options.get(name), (int, float)) and not isinstance(options.get(name), bool):
        return float(options[name])
    from .controllers import pid, servo

    specs = {"servo": servo.OPTIONS, "pid": pid.OPTIONS}.get(controller, {})
    default = specs[name].default if name in specs else None
    return float(default) if isinstance(default, (int, float)) and not isinstance(default, bool) else None


def controller_advice(controller: str, commissioning: dict | None, frequency_hz: float | None = None,
                      options: dict | None = None) -> str:
    """What to do about a sustained oscillation on a commissioned rig: the rig is what the controller was told
    (``isorig identify rig`` measured it), so the loop itself oscillates; say what a lab can change, with the
    option's exact name and a value (``options``: the run's controller options). Measured on our rig with the
    oil column's stiffness lost mid-test (bulk modulus 1e9 -> 2e8 Pa, 20 mm at 0.5 Hz): kp_per_s 30 -> 15 ran it
    to the end, learning_gain 0.8 -> 0.4 halved the oscillation, pressure_feedback_max_damping changed nothing."""
    facts = commissioning_facts(commissioning) or {}
    when = f" on {facts['date'][:10]}" if facts.get("date") else ""
    near = f" at {frequency_hz:.0f} Hz" if frequency_hz is not None and math.isfinite(frequency_hz) else ""
    velocity = facts.get("max_velocity_m_per_s")
    larger = f"{min(0.1, 2.0 * velocity):.2g}" if velocity else "0.04"
    again = ("if the rig changed since the commissioning (air in the oil, a hose that gives, the valve's dead zone "
             f"or null), commission the rig again (isorig identify rig --max-velocity-m-per-s {larger})")
    gain = LOOP_GAIN_OPTIONS.get(controller)
    value = _option_value(controller, gain, options) if gain else None
    lower = (f"--controller-option {gain}={value / 2:.4g}, half the {value:.4g} it ran with, or the console's "
             "controller options") if value else None
    if controller != "servo":
        try_ = f"What to try: a lower loop gain ({lower}), or " if lower else "What to try: "
        return (f"the rig was commissioned{when}, so this is the {controller} controller's own loop oscillating"
                f"{near}, not a rig it was not told of. {try_}the default servo controller, which follows a "
                f"commissioned rig (docs/compare.md); {again}")
    learning = _option_value(controller, "learning_gain", options)
    return (f"the rig was commissioned{when}, so this is the servo controller's loop oscillating{near} on the rig "
            f"it was told of, not a rig it does not know. What to try: a lower position loop gain ({lower}), then "
            f"a lower learning gain (--controller-option learning_gain={(learning or 0.8) / 2:.2g}); {again}")


@dataclass(frozen=True)
class FollowLimits:
    """When the table is judged not to follow (shares of the amplitude; SI)."""

    rms_share: float = 0.01
    #: the learning's transient: the servo's error may grow in its second steady cycle (its compression feed-forward
    #: and the harmonics past the oil column start from the first ones) before it falls (docs/controller.md)
    learning_cycles: int = 2
    #: ... then a cycle whose error is above ``rms_share`` is let go while the learning still gains
    #: ``min_improvement`` a cycle: its error is that much below the cycle before's, or the smallest error of the
    #: block's steady cycles so far is (1 - min_improvement)^2 of the smallest of two cycles earlier (a learning
    #: that overshoots converges in steps, 9.5, 2.7, 7.7, 2.0, 0.9 % on a foreign rig at 0.5 mm), for at most
    #: ``improving_cycles`` more cycles. A table that starts each cycle stuck on its guides needs 6-8 cycles to
    #: learn its reversals (docs/commissioning.md, twelfth session)
    min_improvement: float = 0.2
    improving_cycles: int = 8
    #: measured on 12 drawn rigs told exactly (scripts/commissioning_targets.py): their error above 10 Hz
    #: reaches 1.05 % of a 2 mm amplitude while the learning converges, so 2 % (and 40 um) is an oscillation
    oscillation_share: float = 0.02
    floor_m: float = 4e-5
    oscillation_window_s: float = 0.5
    #: ... and in the steady cycles (a window whose every reading and the one a test period before it lie in
    #: steady cycles of one block, past its first; no period lost on the link in the last second, whose held
    #: readings are steps the table did not make): there the learning's transient is over and what repeats is
    #: taken off, so good runs reach 0.38 % (the paper's MRAC; servo and pid ~0), while an oil column that lost
    #: its stiffness mid-test oscillates at 0.7-1.6 % within 2 s (scripts/bench_detectors.py --oscillations)
    steady_oscillation_share: float = 0.005
    corner_hz: float = 10.0
    corner_harmonic: float = 8.0
    #: ... and, in those steady windows, a **tone**: an oscillation told by its signature, not its size alone. Its
    #: part that does not repeat with the test (the high-passed error less that of one test period earlier) is
    #: periodic of itself: it correlates at ``tone_correlation`` or more with itself one of its own periods later
    #: (the period from its zero crossings over the window), the two halves of the window have RMS within
    #: ``tone_sustain`` of each other (sustained, not a ring that dies), and the window's RMS (as above) is above
    #: ``tone_share`` of the amplitude (the labs' target: a tone that alone exceeds it spoils the test), at least
    #: ``tone_floor_m``. Why: our rig's oil column at 2.5e8 Pa from 4.3 s of a 5 mm 0.5 Hz test oscillates near 26
    #: Hz at 20-45 um RMS, in bursts with the test's half cycles, about the 40 um floor (and, where it nearly
    #: repeats every 2 s test period, less its value a period earlier is smaller still): the size rule stopped it
    #: 5.7 s after the change, the tone rule 0.78 s. scripts/bench_detectors.py --oscillations: all 25 injected
    #: cases stopped within 1.70 s (4 that the size rule never stopped: 27-28 Hz, 0.2-0.4 % of the amplitude),
    #: no first trip changed over 240 runs without a change (128 good); the rule's margin there: at a correlation
    #: of 0.85 or a 5 um floor no good run would be stopped, at 0.8 one (a told rig's learning transient, 12 Hz)
    tone_share: float = LAB_TARGET_SHARE
    tone_floor_m: float = 1e-5
    tone_correlation: float = 0.9
    tone_sustain: float = 0.5

    def to_dict(self) -> dict:
        return {"rms_share": self.rms_share, "min_improvement": self.min_improvement,
                "learning_cycles": self.learning_cycles, "improving_cycles": self.improving_cycles,
                "oscillation_share": self.oscillation_share,
                "floor_m": self.floor_m, "oscillation_window_s": self.oscillation_window_s,
                "steady_oscillation_share": self.steady_oscillation_share,
                "corner_hz": self.corner_hz, "corner_harmonic": self.corner_harmonic,
                "tone_share": self.tone_share, "tone_floor_m": self.tone_floor_m,
                "tone_correlation": self.tone_correlation, "tone_sustain": self.tone_sustain}


def follow_thresholds() -> dict:
    """The detector's thresholds as the limits list shows them (``FollowLimits``; shares of the amplitude, SI)."""
    return FollowLimits().to_dict()


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

    def settled(self, k: np.ndarray, n: int) -> np.ndarray:
        """Is the window of the ``n`` periods ending at each k in the steady cycles, each compared with a steady
        one (one block, from its second steady cycle, before its taper-out)?"""
        k0 = k - (n - 1)
        b, c, _ = self.cycle(k)
        b0, c0, _ = self.cycle(k0)
        return ((k0 >= self.starts[0]) & (b0 == b) & (self.periods[b] > 0) & (c0 >= self.tapers[b] + 1)
                & (c < self.cycles[b] - self.tapers[b]))

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


HIGH_PASS_ORDER = 4  # two second-order sections: a slow error 0.6 of the corner below passes at 1/8, not 1/3


@functools.lru_cache(maxsize=64)
def high_pass_sections(corner_hz: float) -> tuple[float, ...]:
    """(b0, b1, b2, a1, a2) of each of the two second-order sections of the fourth-order Butterworth high-pass at
    ``corner_hz``, one after the other (kept: scipy's design costs more than judging a whole run). The second
    order it replaced passed a slow tracking error's harmonics just below the corner at a third of their size:
    the paper's MRAC, 100 % of the amplitude off in its first cycles, was stopped as 'a sustained oscillation
    near 4 Hz' on a 1 Hz test."""
    from scipy import signal  # here: scipy.signal costs every process importing sim.follow a second of CPU

    sos = signal.butter(HIGH_PASS_ORDER, corner_hz, btype="highpass", fs=1.0 / CONTROL_PERIOD_S, output="sos")
    return tuple(float(x) for section in sos for x in (section[0], section[1], section[2], section[4], section[5]))


class FollowMonitor:
    """Feed it the test's rows in order (``check``); it returns the first ``FollowTrip`` or None."""

    def __init__(self, reference: Reference, latency_s: float = 0.0, limits: FollowLimits | None = None,
                 advice: str = ADVICE, commissioning: dict | None = None, controller: str = "servo",
                 controller_options: dict | None = None, actuator: ActuatorLimits | None = None):
        self.reference = reference
        self.advice = advice
        #: the rig's commissioning (``commissioning_facts``): an oscillation on a commissioned rig is the loop's own
        self.commissioning = commissioning_facts(commissioning)
        self.controller = controller
        self.controller_options = dict(controller_options or {})  # the run's (named in the advice)
        self.limits = limits or FollowLimits()
        self.lag = max(0.0, latency_s) / CONTROL_PERIOD_S
        self.n_osc = max(1, int(round(self.limits.oscillation_window_s / CONTROL_PERIOD_S)))
        top_hz = max((1.0 / (p * CONTROL_PERIOD_S) for p in reference.periods if p > 0), default=0.0)
        self.corner_hz = min(max(self.limits.corner_hz, self.limits.corner_harmonic * top_hz), 200.0)
        self.biquad = high_pass_sections(self.corner_hz)
        self.z = [0.0, 0.0, 0.0, 0.0]  # the high-pass's state (two sections, transposed direct form II)
        #: the high-passed error of the last test period (by period k, at k mod its size; 0 before the start): the
        #: error's part that repeats every cycle of the test (its harmonics) is tracking error, not an oscillation
        self.hf_ring = np.zeros(max(1, int(np.max(reference.periods))))
        self.e_comb = np.full(self.n_osc, np.nan)  # the high-passed error less that of one test period earlier
        self.r_hist = np.full(int(math.ceil(self.lag)) + 2, np.nan)  # the last targets (for r(t - L))
        self.e_hf = np.full(self.n_osc, np.nan)
        self.cycle_key = (-1, -1)  # (span, cycle) being summed
        self.cycle_sum = 0.0
        self.cycle_n = 0
        self.previous_share: float | None = None  # the last steady cycle's RMS share in this block
        #: the smallest RMS share of the steady cycles judged in this block up to the last one, and up to the one
        #: before it (None: not that many judged yet)
        self.best_shares: tuple[float | None, float | None] = (None, None)
        self.steady_judged = 0  # steady cycles judged in this block
        self.tripped: FollowTrip | None = None
        self.last_fresh: tuple[int, float] | None = None  # (period, reading) of the last fresh measurement
        self.lost_recent = np.zeros(LOST_WINDOW_PERIODS, dtype=bool)  # which of the last periods were lost
        self.cycle_steady = False  # the cycle being summed is a steady one
        #: what the actuator can give (sim.force_limit): a trip while it was held at its limit is put down to it
        self.actuator = actuator
        self.force_ring = np.zeros(0, dtype=np.int8)  # at_force_limit of the last rows (up to a test period)
        self.force_keep = max(self.n_osc, int(np.max(reference.periods)) if len(reference.periods) else 0)
        self.supply_pa = math.nan  # the last supply pressure read
        warm_up()  # before the first check: a real-time worker builds its monitor before the rig is armed

    def resume(self) -> None:
        """Go on after a trip the operator set to indicate (sim.safety.follow_trip), judging the other kind only
        (a kind is indicated once; the tracking verdict gives the tracking at the end)."""
        if self.tripped is None:
            return
        off = {"rms_share": math.inf} if self.tripped.kind == "tracking" else {
            "oscillation_share": math.inf, "steady_oscillation_share": math.inf, "floor_m": math.inf,
            "tone_share": math.inf, "tone_floor_m": math.inf}
        self.limits = dataclasses.replace(self.limits, **off)
        self.tripped = None

    def _keep_force_limit(self, rows) -> None:
        """Keep whether the actuator was at its force limit in ``rows`` (the last ``force_keep`` rows)."""
        if self.actuator is None or len(rows) == 0:
            return
        rows = rows[-self.force_keep:]  # a whole record's (``feed``): only its end is kept
        self.force_ring = np.concatenate([self.force_ring, at_force_limit(rows, self.actuator)])[-self.force_keep:]
        supply = np.asarray(rows["supply_pressure_pa"], dtype=float)
        supply = supply[np.isfinite(supply)]
        if supply.size:
            self.supply_pa = float(supply[-1])

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

    def check(self, rows, reference: bool = False) -> FollowTrip | None:
        """Take the next rows of the test (the worker's blocks of ten periods; ``feed`` cuts a record into
        such blocks) and judge what they complete. Compiled (``_judge_blocks``); ``reference``: the per-block
        numpy path it reproduces bit for bit (tests/test_follow.py compares them)."""
        if self.tripped is not None or len(rows) == 0:
            return None
        if reference or not fast_path(len(rows)):
            return self._check_reference(rows)
        return self._judged(rows, len(rows))

    def feed(self, samples, block: int = 10, reference: bool = False) -> FollowTrip | None:
        """``check`` a whole record in blocks of ``block`` rows, as the worker would, in one compiled call; the
        first trip or None (``reference``: block by block on the numpy path)."""
        if reference or not fast_path(block):
            for i in range(0, len(samples), block):
                trip = self.check(samples[i:i + block], reference=True)
                if trip is not None:
                    trip.index += i
                    return trip
            return None
        if self.tripped is not None or len(samples) == 0:
            return None
        return self._judged(samples, block)

    def feed_to_trip(self, samples, block: int = 10) -> int | None:
        """``feed`` a record up to the block in which the monitor first trips, without that block: the trip's
        row, or None (all rows taken). The monitor is then where the worker's is before that block (whose
        ``check`` trips), so a run's rows are fed once (sim.detectors.RunDetectors.first_trip_period)."""
        if self.tripped is not None:
            raise ValueError("feed_to_trip: this monitor has tripped already")
        if not fast_path(block):  # the numpy path: find the trip on a copy, then feed up to its block
            probe = copy.deepcopy(self)
            trip = probe.feed(samples, block, reference=True)
            if trip is None:
                self.__dict__.update(probe.__dict__)
                return None
            self.feed(samples[:trip.index // block * block], block, reference=True)
            return trip.index
        if len(samples) == 0:
            return None
        kind, at, *_ = self._judge(samples, block, rollback=True)
        return None if kind == NO_TRIP else at

    def _judged(self, rows, block: int) -> FollowTrip | None:
        """The compiled judge over ``rows`` in blocks of ``block``: its trip (``_trip``) or None."""
        kind, at, value, bound, amplitude, taken = self._judge(rows, block, rollback=False)
        if kind == NO_TRIP:
            return None
        if at + 1 > taken:  # the rows up to the trip that the judge had not taken
            self._keep_force_limit(rows[taken:at + 1])
        t = float(rows["time_s"][at])
        return self._trip(at, t, "tracking" if kind == TRACKING else "oscillation", value, bound, amplitude,
                          tone=kind == TONE)

    def _judge(self, rows, block: int, rollback: bool) -> tuple[int, int, float, float, float, int]:
        """Run ``_judge_blocks`` on ``rows`` from this monitor's state, and keep the state it ends in:
        (kind, row, value, bound, amplitude) of the first trip (kind NO_TRIP: none), and the rows it took."""
        t = np.asarray(rows["time_s"], dtype=float)
        k = np.round(t / CONTROL_PERIOD_S).astype(np.int64)
        lost = ~measured_rows(rows["flags"])
        span, cycle, steady = self.reference.cycle(k)
        settled = self.reference.settled(k, self.n_osc)
        y = np.ascontiguousarray(rows["measured_displacement_m"], dtype=float)
        h = self.r_hist.size
        r_ext = np.concatenate([self.r_hist, np.asarray(rows["target_m"], dtype=float)])
        fresh_k, fresh_y = self.last_fresh if self.last_fresh is not None else (0, 0.0)
        best_last, best_before = self.best_shares
        fs = np.array([self.z[0], self.z[1], fresh_k, fresh_y, self.cycle_sum,
                       0.0 if self.previous_share is None else self.previous_share, self.z[2], self.z[3],
                       0.0 if best_last is None else best_last, 0.0 if best_before is None else best_before],
                      dtype=float)
        ist = np.array([self.last_fresh is not None, self.cycle_key[0], self.cycle_key[1], self.cycle_n,
                        self.cycle_steady, (best_last is not None) + (best_before is not None), self.steady_judged, 0,
                        np.count_nonzero(np.isnan(self.e_hf)), 0, np.count_nonzero(self.lost_recent)], dtype=np.int64)
        osc = np.concatenate([self.e_hf, self.e_hf])
        osc_c = np.concatenate([self.e_comb, self.e_comb])
        lost_ring = self.lost_recent.copy()
        lim = self.limits
        kind, at, value, bound, amplitude, taken = _judge_blocks(
            k, y, r_ext, lost, span, cycle, steady, settled, block, rollback, dot_is_fused(), self.lag, h,
            np.asarray(self.biquad, dtype=float), np.asarray(self.reference.amplitudes, dtype=float),
            np.asarray(self.reference.periods, dtype=np.int64),
            np.array([lim.oscillation_share, lim.floor_m, lim.rms_share, lim.min_improvement,
                      min(lim.oscillation_share, lim.steady_oscillation_share), lim.tone_share, lim.tone_floor_m,
                      lim.tone_correlation, lim.tone_sustain ** 2]),
            np.array([lim.learning_cycles, lim.improving_cycles], dtype=np.int64), fs, ist, osc, osc * osc, lost_ring,
            self.hf_ring, osc_c, osc_c * osc_c)
        self.z = [float(fs[_F_Z1]), float(fs[_F_Z2]), float(fs[_F_Z3]), float(fs[_F_Z4])]
        self.last_fresh = (int(fs[_F_FRESH_K]), float(fs[_F_FRESH_Y])) if ist[_I_HAS_FRESH] else None
        self.cycle_key = (int(ist[_I_SPAN]), int(ist[_I_CYCLE]))
        self.cycle_sum, self.cycle_n = float(fs[_F_CYCLE_SUM]), int(ist[_I_CYCLE_N])
        self.cycle_steady = bool(ist[_I_STEADY])
        held = int(ist[_I_BESTS])
        self.previous_share = float(fs[_F_PREVIOUS]) if held >= 1 else None
        self.best_shares = (float(fs[_F_BEST_LAST]) if held >= 1 else None,
                            float(fs[_F_BEST_BEFORE]) if held >= 2 else None)
        self.steady_judged = int(ist[_I_JUDGED])
        head = int(ist[_I_OSC_HEAD])
        self.e_hf = osc[head:head + self.n_osc].copy()
        self.e_comb = osc_c[head:head + self.n_osc].copy()
        head = int(ist[_I_LOST_HEAD])
        self.lost_recent = np.concatenate([lost_ring[head:], lost_ring[:head]])
        self.r_hist = r_ext[taken:taken + h].copy()
        self._keep_force_limit(rows[:taken])
        return kind, at, value, bound, amplitude, int(taken)

    def _check_reference(self, rows) -> FollowTrip | None:
        """``check`` on the numpy path, block by block: the reference the compiled judge reproduces."""
        self._keep_force_limit(rows)
        t = np.asarray(rows["time_s"], dtype=float)
        r = np.asarray(rows["target_m"], dtype=float)
        y = np.asarray(rows["measured_displacement_m"], dtype=float)
        k = np.round(t / CONTROL_PERIOD_S).astype(np.int64)
        lost = ~measured_rows(rows["flags"])
        y = self._bridge_lost(k, y, lost)
        self.lost_recent = np.concatenate([self.lost_recent, lost])[-LOST_WINDOW_PERIODS:]
        e = y - self._late_target(r)
        closed = np.isfinite(e)
        e_hf = np.where(closed, self._high_pass(np.where(closed, e, 0.0)), np.nan)
        span, cycle, steady = self.reference.cycle(k)
        e_comb = self._less_last_period(e_hf, k, self.reference.periods[span])
        self.e_hf = np.concatenate([self.e_hf, e_hf])[-self.n_osc:]
        self.e_comb = np.concatenate([self.e_comb, e_comb])[-self.n_osc:]
        lim = self.limits
        a = float(self.reference.amplitudes[span[-1]])
        if not np.any(np.isnan(self.e_hf)):
            hf = min(float(np.sqrt(np.mean(self.e_hf ** 2))), float(np.sqrt(np.mean(self.e_comb ** 2))))
            settled = bool(self.reference.settled(k[-1:], self.n_osc)[0]) and not self.lost_recent.any()
            bound = max(self._oscillation_share(settled) * a, lim.floor_m)
            if hf > bound:
                return self._trip(len(rows) - 1, float(t[-1]), "oscillation", hf, bound, a)
            tone_bound = max(lim.tone_share * a, lim.tone_floor_m)
            if settled and hf > tone_bound and is_tone(self.e_comb, lim.tone_correlation, lim.tone_sustain ** 2):
                return self._trip(len(rows) - 1, float(t[-1]), "oscillation", hf, tone_bound, a, tone=True)
        cut = np.flatnonzero((span[1:] != span[:-1]) | (cycle[1:] != cycle[:-1])) + 1
        for a, b in zip(np.concatenate([[0], cut]), np.concatenate([cut, [len(rows)]]), strict=True):
            key = (int(span[a]), int(cycle[a]))
            if key != self.cycle_key:
                trip = self._cycle_done(int(a), float(t[a]))
                if trip is not None:
                    return trip
                if key[0] != self.cycle_key[0]:
                    self.previous_share, self.best_shares, self.steady_judged = None, (None, None), 0
                self.cycle_key, self.cycle_sum, self.cycle_n = key, 0.0, 0
                self.cycle_steady = bool(steady[a])
            part = e[a:b][closed[a:b] & ~lost[a:b]]  # a lost period's reading is an older one: not judged
            self.cycle_sum += float(np.dot(part, part))
            self.cycle_n += part.size
        return None

    def _oscillation_share(self, settled: bool) -> float:
        """The oscillation bound's share of the amplitude: lower in the steady cycles (FollowLimits)."""
        lim = self.limits
        return min(lim.oscillation_share, lim.steady_oscillation_share) if settled else lim.oscillation_share

    def _cycle_done(self, i: int, t: float) -> FollowTrip | None:
        """The cycle being summed has ended: judge it if it was a steady one after its block's first
        ``learning_cycles``."""
        b, c = self.cycle_key
        if b < 0 or not self.cycle_steady or self.cycle_n < 0.9 * self.reference.periods[b]:
            return None
        a = float(self.reference.amplitudes[b])
        share = math.sqrt(self.cycle_sum / self.cycle_n) / a if a > 0 else 0.0
        previous, self.previous_share = self.previous_share, share
        best_last, best_before = self.best_shares
        best = share if best_last is None else min(best_last, share)
        self.best_shares = (best, best_last)
        self.steady_judged += 1
        lim = self.limits
        if self.steady_judged <= lim.learning_cycles:
            return None  # the learning's transient
        held = (best_last is not None) + (best_before is not None)
        gains = learning_gains(share, previous or 0.0, best, best_before or 0.0, held, lim.min_improvement)
        stuck = not gains or self.steady_judged > lim.learning_cycles + lim.improving_cycles
        if share > lim.rms_share and stuck:
            return self._trip(i, t, "tracking", share * a, lim.rms_share * a, a)
        return None

    def _high_pass(self, x: np.ndarray) -> np.ndarray:
        """The fourth-order Butterworth high-pass at ``corner_hz`` (two sections), sample by sample (ten at a
        time in the worker: a loop here costs less than scipy's call)."""
        b0, b1, b2, a1, a2, c0, c1, c2, d1, d2 = self.biquad
        z1, z2, z3, z4 = self.z
        out = np.empty(x.size)
        for i, xi in enumerate(x.tolist()):
            yi = b0 * xi + z1
            z1 = b1 * xi - a1 * yi + z2
            z2 = b2 * xi - a2 * yi
            wi = c0 * yi + z3
            z3 = c1 * yi - d1 * wi + z4
            z4 = c2 * yi - d2 * wi
            out[i] = wi
        self.z = [z1, z2, z3, z4]
        return out

    def _less_last_period(self, v: np.ndarray, k: np.ndarray, periods: np.ndarray) -> np.ndarray:
        """The high-passed error ``v`` less its value one test period (``periods``, of each row's block) earlier:
        what repeats from cycle to cycle (the error's harmonics of the test frequency) is gone, an oscillation of
        its own is not. Unknown a period earlier (not a number): nothing taken off. A time history has no period:
        ``v`` as it is."""
        ring = self.hf_ring
        n = ring.size
        out = np.empty(v.size)
        for i in range(v.size):
            p = int(periods[i])
            vi = float(v[i])
            old = float(ring[(int(k[i]) - p) % n]) if p > 0 else 0.0
            out[i] = vi - (old if math.isfinite(old) else 0.0)
            ring[int(k[i]) % n] = vi
        return out

    def _trip(self, i: int, t: float, kind: str, value: float, bound: float, amplitude: float,
              tone: bool = False) -> FollowTrip:
        share = value / amplitude if amplitude > 0 else math.inf
        correlation = None
        if kind == "oscillation" and tone:  # told by its signature (FollowLimits.tone_correlation)
            f = oscillation_frequency_hz(self.e_comb)
            correlation = tone_correlation(self.e_comb)
            what = (f"a sustained oscillation near {f:.0f} Hz: {value * 1e3:.3g} mm RMS over the last "
                    f"{self.limits.oscillation_window_s:g} s ({100 * share:.2g} % of the amplitude), a tone of its "
                    f"own in the steady cycles (the error that does not repeat with the test repeats every period "
                    f"of it, correlation {correlation:.2f}, through the whole window; a tone is stopped above "
                    f"{bound * 1e3:.3g} mm)")
        elif kind == "oscillation":
            f = oscillation_frequency_hz(self.e_hf)
            steady = bound < max(self.limits.oscillation_share * amplitude, self.limits.floor_m)
            what = (f"a sustained oscillation near {f:.0f} Hz: {value * 1e3:.3g} mm RMS over the last "
                    f"{self.limits.oscillation_window_s:g} s ({100 * share:.2g} % of the amplitude; at most "
                    f"{bound * 1e3:.3g} mm{' in the steady cycles' if steady else ''})")
        else:
            f = None
            what = (f"|y - r| {value * 1e3:.3g} mm RMS over the last cycle, {100 * share:.2g} % of the "
                    f"{amplitude * 1e3:.4g} mm amplitude (at most {100 * self.limits.rms_share:g} %), and the "
                    "learning is not bringing it down")
        lost = int(np.count_nonzero(self.lost_recent))
        advice = self.advice
        # over the last test period (at least the oscillation's window): a stall at the limit is followed by the
        # table's jerks as it catches up, which the oscillation rule may judge only after the limit is left
        limited = diagnosis(self.force_ring, self.supply_pa, self.actuator) if self.actuator is not None else None
        if self.commissioning is not None:  # the rig is what the controller was told: not "commission it"
            if kind == "oscillation":
                advice = controller_advice(self.controller, self.commissioning, f, self.controller_options)
            else:
                when = f" on {self.commissioning['date'][:10]}" if self.commissioning.get("date") else ""
                advice = (f"the rig was commissioned{when}: if it changed since (a specimen, a valve, the oil), "
                          "commission it again (isorig identify rig, or the console's Commissioning page); "
                          + ("else the learning does not reach this test on it: try a lower learning gain "
                             "(--controller-option learning_gain=0.4)" if self.controller == "servo" else
                             f"the {self.controller} controller does not follow this rig; the default servo "
                             "controller does (docs/compare.md)"))
        if lost > LOST_SHARE_BLAMED * LOST_WINDOW_PERIODS:  # the host or the link, not the rig's description
            advice = (f"{lost} of the last {LOST_WINDOW_PERIODS} periods were lost on the link (a host that stalls "
                      "or a link that drops packets: see the link figures), so the controller held its command "
                      "through them; make the host's real-time path steadier before commissioning the rig")
        if limited is not None:  # the rig had no more to give: neither the controller's nor the rig file's fault
            advice = limited[1]
        message = f"the table does not follow its target at t = {t:.3f} s: {what}; {advice}"
        values = {"time_s": t, "kind": kind, "value_m": value, "limit_m": bound, "amplitude_m": amplitude,
                  "share": share, "frequency_hz": f, "lost_periods_last_s": lost,
                  "commissioned": self.commissioning is not None, "tone_correlation": correlation,
                  "cause": "force_limit" if limited is not None else None,
                  "force_limit_share": None if limited is None else limited[0]}
        self.tripped = FollowTrip(i, t, kind, message, values)
        return self.tripped


def late(r: np.ndarray, periods: float) -> np.ndarray:
    """r ``periods`` earlier (linear between periods; NaN before the start)."""
    if periods <= 0.0:
        return r
    k = np.arange(r.size, dtype=float)
    return np.interp(k - periods, k, r, left=np.nan)


def tone_correlation(w: np.ndarray) -> float:
    """How periodic of itself a window ``w`` (finite) is: the mean of w(t) w(t + T) over the mean of w(t)^2 (1 for a
    steady sine), T one of its own periods (in control periods, rounded) from its zero crossings; 0 without a
    crossing, for a period as long as the window or a window of zeros. The compiled judge's ``_tone`` to the last
    bit."""
    n = w.size
    negative = w < 0.0
    crossings = int(np.count_nonzero(negative[1:] != negative[:-1]))
    if crossings == 0:
        return 0.0
    lag = (2 * n + crossings // 2) // crossings
    total = float(np.sum(w ** 2))
    if lag >= n or not total > 0.0:
        return 0.0
    return (float(np.sum(w[lag:] * w[:-lag])) / (n - lag)) / (total / n)


def is_tone(w: np.ndarray, correlation_min: float, sustain_sq: float) -> bool:
    """Is the window ``w`` a sustained tone: ``tone_correlation`` at least ``correlation_min`` and the mean
    square of each half of it at least ``sustain_sq`` of the other's (FollowLimits.tone_correlation,
    tone_sustain squared)?"""
    h = w.size // 2
    if h == 0:
        return False
    first = float(np.sum(w[:h] ** 2)) / h
    second = float(np.sum(w[h:] ** 2)) / (w.size - h)
    return min(first, second) >= sustain_sq * max(first, second) and tone_correlation(w) >= correlation_min


def oscillation_frequency_hz(x: np.ndarray) -> float:
    """The dominant frequency of a zero-mean signal from its zero crossings."""
    x = x[np.isfinite(x)]
    if x.size < 3:
        return float("nan")
    crossings = np.count_nonzero(np.signbit(x[1:]) != np.signbit(x[:-1]))
    return crossings / (2.0 * x.size * CONTROL_PERIOD_S)


#: a commissioned latency is judged anywhere within this many of its standard deviations: the identification's
#: own measure of a right value (docs/commissioning.md: "within 3 sigma"; issue 32's wrong_trusted)
LATENCY_SIGMAS = 3.0


def judged_latencies_s(latency_s: float, commissioning: dict | None = None) -> tuple[list[float], float | None]:
    """The position latencies a verdict judges with (the worst figure counts) and the one-sigma uncertainty they
    come from: the declared latency alone for a rig nobody commissioned; for a commissioned one, the declared
    latency and LATENCY_SIGMAS of the commissioning's uncertainty either side (never below 0: where the latency
    is that unsure, the unshifted target is one of them)."""
    facts = commissioning_facts(commissioning) or {}
    std = facts.get("position_latency_std_s")
    latency_s = max(0.0, float(latency_s))
    if not std or std <= 0.0:
        return [latency_s], None
    spread = LATENCY_SIGMAS * std
    return sorted({latency_s, max(0.0, latency_s - spread), latency_s + spread}), std


def _worst_block_share(samples, ref: Reference, latency_s: float) -> float | None:
    """The worst block's RMS (reading - target of ``latency_s`` ago) over its judged steady cycles / amplitude."""
    n = len(samples)
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
    return worst


def tracking_verdict(samples, profile, history_criteria: dict | None = None,
                     limits: FollowLimits | None = None, advice: str = ADVICE, latency_s: float = 0.0,
                     commissioning: dict | None = None) -> dict:
    """How well the table followed: ``verdict`` (``followed``: within LAB_TARGET_SHARE; ``outside_target``:
    within the monitor's ``rms_share``; ``did_not_follow``; ``not_judged``: no steady cycle ran), the figure
    it rests on (``rms_share``: the worst block's RMS |y - r| over its judged cycles / its amplitude; a time
    history: J2 / 100), and words for a person. Judged as the monitor judges: the position reading against the
    target of ``latency_s`` (the rig's declared position latency) ago, so that a real rig's record (its reading)
    and a simulation's are judged alike. A latency measured by commissioning (``commissioning``: the rig file's
    section) is judged with its uncertainty: the worst figure with the latency anywhere in +-LATENCY_SIGMAS of
    it (``judged_latencies_s``), so a biased estimate never makes the verdict better than the table's own
    error (``latency_s``: the latency of that figure, ``latency_std_s``)."""
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
    if len(samples) == 0 or not profile:
        return {"verdict": "not_judged", "words": "not judged (no steady cycle ran)"}
    ref = reference_for(profile)
    latencies, std = judged_latencies_s(latency_s, commissioning)
    worst, worst_latency = None, latencies[0]
    for latency in latencies:
        share = _worst_block_share(samples, ref, latency)
        if share is not None and (worst is None or share > worst):
            worst, worst_latency = share, latency
    if worst is None:
        return {"verdict": "not_judged", "words": "not judged (no steady cycle ran)"}
    basis = "RMS |y - r| over each block's last two steady cycles, over its amplitude"
    if std is not None:
        basis += (f"; the reading against the target of the latency ago, the worst with the commissioned latency "
                  f"anywhere within +-{LATENCY_SIGMAS:g} sigma ({1e3 * max(0.0, latency_s):.3g} +- "
                  f"{1e3 * LATENCY_SIGMAS * std:.2g} ms)")
    out = _verdict(worst, limits, basis, advice)
    out.update(latency_s=worst_latency, latency_std_s=std)
    return out


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


# ---------------------------------------------------------------------------------------------------------------
# the compiled judge: ``FollowMonitor.check`` and ``feed`` over many blocks in one call, bit for bit the per-block
# numpy path (``FollowMonitor._check_reference``), which stays as the reference tests/test_follow.py compares with

@njit(cache=True, error_model="numpy")
def learning_gains(share: float, previous: float, best: float, best_before: float, held: int,
                   min_improvement: float) -> bool:
    """The tracking rule's "the learning still gains ``min_improvement`` a cycle" (FollowLimits), for the monitor
    and its compiled judge alike: the cycle's RMS ``share`` that much below the cycle before's (``previous``), or
    the smallest share of the block's steady cycles so far (``best``, this one's included) (1 - min_improvement)^2
    of the smallest of two cycles earlier (``best_before``). ``held``: how many of the two earlier figures the
    block has (0: none; 1: ``previous``; 2: both)."""
    keep = 1.0 - min_improvement
    return held >= 1 and (share <= keep * previous or (held >= 2 and best <= keep * keep * best_before))


#: the fast path's largest block: a block's sums of squares are numpy.dot's of at most this many numbers, which
#: OpenBLAS adds one product at a time (from 16 on it adds them in SIMD lanes, in an order not reproduced here)
FAST_BLOCK_MAX = 15
_F_Z1, _F_Z2, _F_FRESH_K, _F_FRESH_Y, _F_CYCLE_SUM, _F_PREVIOUS, _F_Z3, _F_Z4, _F_BEST_LAST, _F_BEST_BEFORE = range(10)
(_I_HAS_FRESH, _I_SPAN, _I_CYCLE, _I_CYCLE_N, _I_STEADY, _I_BESTS, _I_JUDGED, _I_OSC_HEAD, _I_OSC_NAN,
 _I_LOST_HEAD, _I_LOST_COUNT) = range(11)  # ... and its integer state
NO_TRIP, OSCILLATION, TRACKING, TONE = 0, 1, 2, 3  # TONE: an oscillation told by its signature


@intrinsic
def _fma(typingctx, x, y, z):
    """x y + z rounded once (llvm.fma), as OpenBLAS's x86 dot kernels add each product."""
    sig = types.float64(types.float64, types.float64, types.float64)

    def codegen(context, builder, signature, args):
        double = ir.DoubleType()
        fn = builder.module.declare_intrinsic("llvm.fma", [double], ir.FunctionType(double, [double] * 3))
        return builder.call(fn, args)

    return sig, codegen


@njit(cache=True, error_model="numpy")
def _sum_of_squares(x: np.ndarray, n: int, fused: bool) -> float:
    """sum x[i]^2 over the first n, one product at a time from 0 (fused: each with a fused multiply-add)."""
    s = 0.0
    for i in range(n):
        s = _fma(x[i], x[i], s) if fused else s + x[i] * x[i]
    return s


@njit(cache=True, error_model="numpy")
def _pairwise_sum(x: np.ndarray, i0: int, n: int) -> float:
    """numpy's sum of x[i0:i0 + n] (its pairwise summation, eight partial sums in blocks of up to 128), to the
    last bit."""
    if n < 8:
        s = 0.0
        for i in range(i0, i0 + n):
            s += x[i]
        return s
    if n <= 128:
        r = x[i0:i0 + 8].copy()
        m = n - n % 8
        i = 8
        while i < m:
            for j in range(8):
                r[j] += x[i0 + i + j]
            i += 8
        s = ((r[0] + r[1]) + (r[2] + r[3])) + ((r[4] + r[5]) + (r[6] + r[7]))
        while i < n:
            s += x[i0 + i]
            i += 1
        return s
    n2 = n // 2
    n2 -= n2 % 8
    return _pairwise_sum(x, i0, n2) + _pairwise_sum(x, i0 + n2, n - n2)


@njit(cache=True, error_model="numpy")
def _interp(x: float, xp: np.ndarray, fp: np.ndarray, n: int) -> float:
    """numpy.interp(x, xp[:n], fp[:n]) for one x (xp increasing; constant beyond the ends), to the last bit."""
    if n == 1 or x <= xp[0]:
        return fp[0]
    if x >= xp[n - 1]:
        return fp[n - 1]
    j = 0
    while xp[j + 1] <= x:
        j += 1
    if xp[j] == x:
        return fp[j]
    slope = (fp[j + 1] - fp[j]) / (xp[j + 1] - xp[j])
    out = slope * (x - xp[j]) + fp[j]
    if np.isnan(out):
        out = slope * (x - xp[j + 1]) + fp[j + 1]
        if np.isnan(out) and fp[j] == fp[j + 1]:
            out = fp[j]
    return out


@njit(cache=True, error_model="numpy")
def _late_at(r_ext: np.ndarray, b0: int, i: int, h: int, lag_periods: float) -> float:
    """r ``lag_periods`` before row i of the block that starts at b0 (``late`` over the block's targets after the
    ``h`` kept, r_ext[b0:], with the same local positions, so the same rounding)."""
    if lag_periods <= 0.0:
        return r_ext[b0 + h + i]
    x = float(h + i) - lag_periods
    if x < 0.0:
        return np.nan
    j = int(np.floor(x))
    f0 = r_ext[b0 + j]
    if float(j) == x:
        return f0
    f1 = r_ext[b0 + j + 1]
    slope = (f1 - f0) / (float(j + 1) - float(j))
    out = slope * (x - float(j)) + f0
    if np.isnan(out):
        out = slope * (x - float(j + 1)) + f1
        if np.isnan(out) and f0 == f1:
            out = f0
    return out


@njit(cache=True, error_model="numpy")
def _tone(w: np.ndarray, w_sq: np.ndarray, head: int, n: int, lagged: np.ndarray, correlation_min: float,
          sustain_sq: float) -> bool:
    """``is_tone`` of the window w[head:head + n] (w_sq: its squares), to the last bit (lagged: scratch as long as
    w; the lagged products are summed from lagged[head]: ``_pairwise_sum`` called with a literal start is a second
    specialisation of a recursive function, whose cached code crashed the process that loaded it)."""
    h = n // 2
    if h == 0:
        return False
    first = _pairwise_sum(w_sq, head, h) / h
    second = _pairwise_sum(w_sq, head + h, n - h) / (n - h)
    if not min(first, second) >= sustain_sq * max(first, second):
        return False
    crossings = 0
    for i in range(head + 1, head + n):
        if (w[i] < 0.0) != (w[i - 1] < 0.0):
            crossings += 1
    correlation = 0.0
    if crossings > 0:
        lag = (2 * n + crossings // 2) // crossings
        total = _pairwise_sum(w_sq, head, n)
        if lag < n and total > 0.0:
            for i in range(head, head + n - lag):
                lagged[i] = w[i + lag] * w[i]
            correlation = (_pairwise_sum(lagged, head, n - lag) / (n - lag)) / (total / n)
    return correlation >= correlation_min


@njit(cache=True, error_model="numpy")
def _judge_blocks(k, y, r_ext, lost, span, cycle, steady, settled, block, rollback, fused, lag_periods, h, biquad,
                  amplitudes, ref_periods, limits_f, limits_i, fs, ist, osc, osc_sq, lost_ring, hf_ring, osc_c,
                  osc_c_sq):
    """``FollowMonitor._check_reference`` over rows cut into blocks of ``block``, in one call: the state (fs, ist,
    the oscillation window osc / osc_sq twice over so that the last ``n_osc`` are contiguous, the lost periods'
    ring) is updated in place. Stops at the first trip: (kind, row, value, bound, amplitude, rows taken); with
    ``rollback`` the block that trips is not taken (the state is that of its start)."""
    n = k.size
    n_osc = osc.size // 2
    n_lost = lost_ring.size
    b0c, b1c, b2c, a1c, a2c = biquad[0], biquad[1], biquad[2], biquad[3], biquad[4]
    c0c, c1c, c2c, d1c, d2c = biquad[5], biquad[6], biquad[7], biquad[8], biquad[9]
    n_ring = hf_ring.size
    osc_share, floor_m, rms_share, min_improvement = limits_f[0], limits_f[1], limits_f[2], limits_f[3]
    steady_share = limits_f[4]
    tone_share, tone_floor_m, tone_min, sustain_sq = limits_f[5], limits_f[6], limits_f[7], limits_f[8]
    lagged = np.empty(2 * n_osc)
    learning_cycles, improving_cycles = limits_i[0], limits_i[1]
    known_k = np.empty(block + 1)
    known_y = np.empty(block + 1)
    e = np.empty(block)
    part = np.empty(block)
    judged = np.empty(block, dtype=np.bool_)
    saved_osc = np.empty(block)
    saved_osc_c = np.empty(block)
    saved_ring = np.empty(block)
    saved_lost = np.empty(block, dtype=lost_ring.dtype)
    saved_fs = fs.copy()
    saved_ist = ist.copy()
    b0 = 0
    while b0 < n:
        b1 = min(b0 + block, n)
        m = b1 - b0
        saved_fs[:] = fs
        saved_ist[:] = ist
        # the readings, each lost one bridged between the fresh ones around it (those of this block and before)
        nk = 0
        if ist[_I_HAS_FRESH]:
            known_k[0] = fs[_F_FRESH_K]
            known_y[0] = fs[_F_FRESH_Y]
            nk = 1
        for i in range(b0, b1):
            if not lost[i] and np.isfinite(y[i]):
                known_k[nk] = float(k[i])
                known_y[nk] = y[i]
                nk += 1
        if nk > 0:
            ist[_I_HAS_FRESH] = 1
            fs[_F_FRESH_K] = known_k[nk - 1]
            fs[_F_FRESH_Y] = known_y[nk - 1]
        z1, z2, z3, z4 = fs[_F_Z1], fs[_F_Z2], fs[_F_Z3], fs[_F_Z4]
        for i in range(m):
            row = b0 + i
            yi = y[row]
            if lost[row] and nk > 0:
                yi = _interp(float(k[row]), known_k, known_y, nk)
            p = ist[_I_LOST_HEAD]
            saved_lost[i] = lost_ring[p]
            ist[_I_LOST_COUNT] += int(lost[row]) - int(lost_ring[p])
            lost_ring[p] = lost[row]
            ist[_I_LOST_HEAD] = (p + 1) % n_lost
            ei = yi - _late_at(r_ext, b0, i, h, lag_periods)
            closed = np.isfinite(ei)
            e[i] = ei
            judged[i] = closed and not lost[row]
            xi = ei if closed else 0.0
            hp = b0c * xi + z1
            z1 = b1c * xi - a1c * hp + z2
            z2 = b2c * xi - a2c * hp
            hp2 = c0c * hp + z3
            z3 = c1c * hp - d1c * hp2 + z4
            z4 = c2c * hp - d2c * hp2
            v = hp2 if closed else np.nan
            # less the high-passed error of one test period earlier (the error's harmonics of the test)
            period = ref_periods[span[row]]
            old = hf_ring[(k[row] - period) % n_ring] if period > 0 else 0.0
            c = v - (old if np.isfinite(old) else 0.0)
            q = k[row] % n_ring
            saved_ring[i] = hf_ring[q]
            hf_ring[q] = v
            p = ist[_I_OSC_HEAD]
            saved_osc[i] = osc[p]
            saved_osc_c[i] = osc_c[p]
            ist[_I_OSC_NAN] += int(np.isnan(v)) - int(np.isnan(osc[p]))
            osc[p] = v
            osc[p + n_osc] = v
            osc_sq[p] = v * v
            osc_sq[p + n_osc] = v * v
            osc_c[p] = c
            osc_c[p + n_osc] = c
            osc_c_sq[p] = c * c
            osc_c_sq[p + n_osc] = c * c
            ist[_I_OSC_HEAD] = (p + 1) % n_osc
        fs[_F_Z1], fs[_F_Z2], fs[_F_Z3], fs[_F_Z4] = z1, z2, z3, z4
        kind, at, value, bound, amplitude = NO_TRIP, -1, 0.0, 0.0, 0.0
        # an oscillation: the high-passed error's RMS over the window, at the block's end
        a = amplitudes[span[b1 - 1]]
        if ist[_I_OSC_NAN] == 0:
            hf = min(np.sqrt(_pairwise_sum(osc_sq, ist[_I_OSC_HEAD], n_osc) / n_osc),
                     np.sqrt(_pairwise_sum(osc_c_sq, ist[_I_OSC_HEAD], n_osc) / n_osc))
            steady_window = settled[b1 - 1] and ist[_I_LOST_COUNT] == 0
            bound = max((steady_share if steady_window else osc_share) * a, floor_m)
            if hf > bound:
                kind, at, value, amplitude = OSCILLATION, b1 - 1, hf, a
            else:
                tone_bound = max(tone_share * a, tone_floor_m)
                if steady_window and hf > tone_bound and _tone(osc_c, osc_c_sq, ist[_I_OSC_HEAD], n_osc, lagged,
                                                               tone_min, sustain_sq):
                    kind, at, value, bound, amplitude = TONE, b1 - 1, hf, tone_bound, a
        # tracking: each cycle's RMS error, judged when the next one begins
        s0 = b0
        while kind == NO_TRIP and s0 < b1:
            s1 = s0 + 1
            while s1 < b1 and span[s1] == span[s0] and cycle[s1] == cycle[s0]:
                s1 += 1
            if span[s0] != ist[_I_SPAN] or cycle[s0] != ist[_I_CYCLE]:
                b = ist[_I_SPAN]
                if b >= 0 and ist[_I_STEADY] and ist[_I_CYCLE_N] >= 0.9 * ref_periods[b]:
                    ab = amplitudes[b]
                    share = np.sqrt(fs[_F_CYCLE_SUM] / ist[_I_CYCLE_N]) / ab if ab > 0 else 0.0
                    held, previous = ist[_I_BESTS], fs[_F_PREVIOUS]
                    best_last, best_before = fs[_F_BEST_LAST], fs[_F_BEST_BEFORE]
                    best = share if held == 0 else min(best_last, share)
                    fs[_F_PREVIOUS], fs[_F_BEST_LAST], fs[_F_BEST_BEFORE] = share, best, best_last
                    ist[_I_BESTS] = min(held + 1, 2)
                    ist[_I_JUDGED] += 1
                    if ist[_I_JUDGED] > learning_cycles:
                        gains = learning_gains(share, previous, best, best_before, held, min_improvement)
                        stuck = not gains or ist[_I_JUDGED] > learning_cycles + improving_cycles
                        if share > rms_share and stuck:
                            kind, at, value, bound, amplitude = TRACKING, s0, share * ab, rms_share * ab, ab
                            break
                if span[s0] != ist[_I_SPAN]:
                    ist[_I_BESTS], ist[_I_JUDGED] = 0, 0
                ist[_I_SPAN], ist[_I_CYCLE] = span[s0], cycle[s0]
                fs[_F_CYCLE_SUM], ist[_I_CYCLE_N] = 0.0, 0
                ist[_I_STEADY] = int(steady[s0])
            count = 0
            for i in range(s0 - b0, s1 - b0):  # the judged rows in order, summed as numpy.dot sums them
                if judged[i]:
                    part[count] = e[i]
                    count += 1
            fs[_F_CYCLE_SUM] += _sum_of_squares(part, count, fused)
            ist[_I_CYCLE_N] += count
            s0 = s1
        if kind != NO_TRIP:
            if not rollback:
                return kind, at, value, bound, amplitude, b1
            for i in range(m - 1, -1, -1):  # back to the block's start, last write first
                p = (saved_ist[_I_OSC_HEAD] + i) % n_osc
                osc[p] = saved_osc[i]
                osc[p + n_osc] = saved_osc[i]
                osc_sq[p] = saved_osc[i] * saved_osc[i]
                osc_sq[p + n_osc] = osc_sq[p]
                osc_c[p] = saved_osc_c[i]
                osc_c[p + n_osc] = saved_osc_c[i]
                osc_c_sq[p] = saved_osc_c[i] * saved_osc_c[i]
                osc_c_sq[p + n_osc] = osc_c_sq[p]
                hf_ring[k[b0 + i] % n_ring] = saved_ring[i]
                lost_ring[(saved_ist[_I_LOST_HEAD] + i) % n_lost] = saved_lost[i]
            fs[:] = saved_fs
            ist[:] = saved_ist
            return kind, at, value, bound, amplitude, b0
        b0 = b1
    return NO_TRIP, -1, 0.0, 0.0, 0.0, n


_DOT_FUSED: list = []


def dot_is_fused() -> bool | None:
    """How numpy.dot adds up to ``FAST_BLOCK_MAX`` products here (the tracking sums of ``_check_reference``):
    True, one fused multiply-add at a time (OpenBLAS's x86 kernels); False, a plain product and sum at a time;
    None, neither (the compiled judge is then not used). Tried once per process on fixed numbers."""
    if not _DOT_FUSED:
        rng = np.random.default_rng(20261129)
        probes = [rng.normal(size=n) * 10.0 ** rng.uniform(-7.0, -2.0, size=n)
                  for n in range(1, FAST_BLOCK_MAX + 1) for _ in range(20)]
        dots = [float(np.dot(x, x)) for x in probes]
        found = None
        for fused in (True, False):
            if all(d == _sum_of_squares(x, x.size, fused) for x, d in zip(probes, dots, strict=True)):
                found = fused
                break
        _DOT_FUSED.append(found)
    return _DOT_FUSED[0]


def fast_path(block: int) -> bool:
    """The compiled judge gives the numpy path's result, bit for bit, for blocks of ``block`` rows here."""
    return 0 < block <= FAST_BLOCK_MAX and dot_is_fused() is not None


_WARM: list = []


def warm_up() -> None:
    """Load the compiled judge (compile it, the first time after a change to sim/) now, once per process, and
    not in a test's first check, where a real rig's watchdog would not wait."""
    if _WARM:
        return
    _WARM.append(True)
    if not fast_path(1):
        return
    from .samples import N_FIELDS, Samples

    rows = np.zeros((2, N_FIELDS))
    rows[1, 0] = CONTROL_PERIOD_S
    reference = Reference(np.array([0]), np.array([0.01]), np.array([1000]), np.array([0]), np.array([1]))
    FollowMonitor(reference).feed(Samples(rows))
