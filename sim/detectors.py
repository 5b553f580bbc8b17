"""The service's detectors over a simulated run, and what a trip does to the loop: one verdict everywhere.

The service's worker (backend.worker.Run.chunk) checks every ``CHECK_PERIODS`` periods, in this order: the
limit detectors (sim.safety.SafetyMonitor: the test's limits and the built-in sensor detectors), the
displacement guard of a controlled-stop displacement limit, then the detector of a rig the controller cannot
follow (sim.follow). The first trip acts on the loop: ``controlled_stop`` brakes the target to rest within the
displacement limit, anything else ramps the valve command to 0 V open loop (at once after a sensor fault or a
controller that does not follow); a ``valve_close`` trip during a controlled stop still closes the valve. The
test then ends ``aborted`` with the trip's message as its reason.

``RunDetectors`` does the same over the engine's run (sim.engine.Simulation.run), so ``isorig simulate`` and
``compare`` give a test the verdict the service gives it; ``predict_first_trip`` runs a test's first cycle
with them, for the warning of POST /api/tests/check before the valve opens (tests/test_detectors.py checks
the engine's verdict against the worker's on the same test).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .loop import CONTROL_PERIOD_S
from .measurement import FLAG_GUARD
from .safety import DEFAULT_FOLLOW_ACTION, FOLLOW_KEY, SafetyLimits, SafetyMonitor, Trip, follow_trip

CHECK_PERIODS = 10  # as the worker's detectors (backend.worker.CHECK_PERIODS)
#: the first cycle's prediction simulates at most this much test time (a taper cycle and a steady cycle at
#: 0.05 Hz; the engine runs it in about 0.1 s)
PREDICTION_MAX_S = 40.0


class RunDetectors:
    """The worker's detectors over a run of ``loop`` (sim.loop.ClosedLoop) for ``scenario`` (sim.engine.Scenario):
    ``check(block)`` after every ``CHECK_PERIODS`` periods acts on the first trip as the worker does and keeps it
    (``trip``); later trips are kept in ``escalations``, indications of ``indicate`` limits in ``indications``.
    ``limits`` None: the follow detector alone (``follow``: with it). ``reference``: the follow detector on its
    per-block numpy path and each detector fed as many times as before the compiled judge (a test compares
    the two). The follow detector acts as ``limits.actions.follow`` says (``follow_action`` when there are no
    limits): ``indicate`` keeps its findings in ``follow_indications`` and the run goes on."""

    def __init__(self, scenario, loop, limits: SafetyLimits | None, follow: bool = True, table=None,
                 act: bool = True, reference: bool = False, follow_action: str | None = None):
        self.loop = loop
        self.act = act  # False: judge only (the trip is kept, the loop runs on)
        self.reference = reference
        #: rows of this run each detector has taken already (``first_trip_period`` feeds them on its way)
        self.safety_fed = 0
        self.follow_fed = 0
        self.limits = limits
        self.monitor = None
        self.guard_m = None
        self.displacement_bound_m = math.inf
        if limits is not None:
            self.monitor = SafetyMonitor(limits, scenario.supply_pa, sensor_range_m=scenario.rig.stroke_m)
            if limits.action("displacement_m") != "indicate":
                self.displacement_bound_m = limits.displacement_m
            if limits.action("displacement_m") == "controlled_stop":
                self.guard_m = limits.displacement_m
                self.brake_m_per_s2 = loop.guard_displacement(limits.displacement_m)
        self.follow = follow_monitor(scenario, table) if follow else None
        self.follow_action = follow_action or (limits.action(FOLLOW_KEY) if limits is not None
                                               else DEFAULT_FOLLOW_ACTION)
        self.follow_indications: list[Trip] = []
        self.trip: Trip | None = None
        self.escalations: list[Trip] = []
        self.indications: list[Trip] = []

    def check(self, block) -> Trip | None:
        """The first trip of ``block`` (the rows just run), acted on; None if nothing trips (or it tripped
        before)."""
        loop = self.loop
        trip = None
        if self.monitor is not None:
            trip = self.monitor.check(block, valve_close_only=self.trip is not None)
            if self.trip is None and (trip is None or trip.action == "controlled_stop"):
                trip = self._guard_trip(block) or trip
            self.indications += self.monitor.take_indications()
        if trip is None and self.follow is not None and self.trip is None and not loop.stopping:
            lost = self.follow.check(block, reference=self.reference)
            if lost is not None and self.follow_action == "indicate":
                self._indicate_follow(lost)
            elif lost is not None:
                trip = follow_trip(lost, self.follow_action)
        if trip is not None and self.trip is None:
            self.trip = trip
            if not self.act:
                return trip
            if trip.action == "controlled_stop":
                loop.brake(within_m=self.displacement_bound_m)
            else:
                loop.begin_command_ramp(at_once=trip.close_at_once)
            return trip
        if trip is not None and trip.action == "valve_close" and not loop.ramping and self.act:
            self.escalations.append(trip)  # a controlled stop is running: only a valve close overrules it
            loop.begin_command_ramp(at_once=trip.close_at_once)
        return None

    def prime(self, rows) -> None:
        """Take the rows a run made before its first trip (``first_trip_period``) as the worker's blocks would
        have: the detectors' state (the recent readings, the frozen-reading runs, the follow monitor's cycles, the
        indications) is then where it would be, without a check per block. Each detector takes only the rows
        it has not taken yet."""
        if self.monitor is not None and len(rows) > self.safety_fed:
            if self.monitor.check(self._rest(rows, self.safety_fed)) is not None:
                raise ValueError("prime: these rows trip a detector; give only the rows before the first trip")
            self.safety_fed = len(rows)
        if self.monitor is not None:
            self.indications += self.monitor.take_indications()
        if self.follow is not None and len(rows) > self.follow_fed:
            self._rest(rows, self.follow_fed)
            if self._feed_follow(rows, self.follow_fed, len(rows)) is not None:
                raise ValueError("prime: these rows trip the follow detector")
            self.follow_fed = len(rows)

    @property
    def all_indications(self) -> list[Trip]:
        """The indications of ``indicate`` limits and of the follow detector, in time order."""
        return sorted(self.indications + self.follow_indications, key=lambda t: t.time_s)

    def _indicate_follow(self, lost) -> None:
        """The follow detector's finding (sim.follow.FollowTrip) as an indication; the monitor goes on."""
        trip = follow_trip(lost, "indicate")
        trip.values["indication"] = len(self.follow_indications) + 1
        self.follow_indications.append(trip)
        self.follow.resume()

    def _feed_follow(self, rows, start: int, stop: int):
        """Feed rows[start:stop] (whole blocks) to the follow monitor: its first finding (index in ``rows``), or
        None; set to indicate, each finding is an indication and the monitor goes on to ``stop``."""
        i = start
        while i < stop:
            lost = self.follow.feed(rows[i:stop], CHECK_PERIODS, self.reference)
            if lost is None:
                return None
            lost.index += i
            if self.follow_action != "indicate":
                return lost
            self._indicate_follow(lost)
            i = (lost.index // CHECK_PERIODS + 1) * CHECK_PERIODS
        return None

    @staticmethod
    def _rest(rows, fed: int):
        """The rows past the ``fed`` taken already, which must end a whole block (the worker's blocks)."""
        if fed % CHECK_PERIODS:
            raise ValueError(f"prime: {fed} rows taken, not a whole number of blocks of {CHECK_PERIODS}")
        return rows[fed:] if fed else rows

    def first_trip_period(self, rows) -> int | None:
        """Over a whole run made without acting (the same rows up to the first trip, since nothing acts
        before it): the first period of the block of ``CHECK_PERIODS`` in which the worker would meet its first
        trip, or None. The limit detectors judge the run on a fresh monitor (kept as this object's own when
        nothing trips); this object's follow monitor takes the rows up to that block (or all of them), so
        ``prime`` then feeds each detector only what it has not taken, and the follow monitor of a run made
        again to its first trip can be taken over (``take_follow``). Call it before ``prime`` or ``check``."""
        if self.safety_fed or self.follow_fed:
            raise ValueError("first_trip_period: these detectors have taken rows already")
        candidates = []
        fresh = None
        if self.limits is not None:
            fresh = SafetyMonitor(self.monitor.limits, self.monitor.supply_pa, self.monitor.sensor_range_m)
            trip = fresh.check(rows)
            if trip is not None:
                candidates.append(trip.index)
            if self.guard_m is not None:
                hits = np.flatnonzero(np.nan_to_num(rows["flags"]).astype(np.int64) & FLAG_GUARD)
                if hits.size:
                    candidates.append(int(hits[0]))
        if self.follow is not None and self.follow_action == "indicate":
            # its findings stop nothing: indications up to the limit detectors' first trip's block
            stop = min(candidates) // CHECK_PERIODS * CHECK_PERIODS if candidates else len(rows)
            self._feed_follow(rows, 0, stop)
            self.follow_fed = stop
        elif self.follow is not None and self.reference:  # as before the compiled judge: a fresh monitor
            end = (min(candidates) // CHECK_PERIODS + 1) * CHECK_PERIODS if candidates else len(rows)
            lost = follow_monitor_like(self.follow).feed(rows[:end], CHECK_PERIODS, reference=True)
            if lost is not None:
                candidates.append(lost.index)
        elif self.follow is not None:
            # the first trip's block is at or before the limit detectors' one: the follow monitor judges up to
            # that block (a trip of its own in that block comes after theirs in the worker's order)
            stop = min(candidates) // CHECK_PERIODS * CHECK_PERIODS if candidates else len(rows)
            lost_index = self.follow.feed_to_trip(rows[:stop], CHECK_PERIODS)
            if lost_index is not None:
                candidates.append(lost_index)
            self.follow_fed = stop if lost_index is None else lost_index // CHECK_PERIODS * CHECK_PERIODS
        if not candidates and fresh is not None and not self.reference:
            self.monitor, self.safety_fed = fresh, len(rows)  # it has judged the whole run: prime need not
        return min(candidates) // CHECK_PERIODS * CHECK_PERIODS if candidates else None

    def take_follow(self, other: RunDetectors) -> None:
        """Take over ``other``'s follow monitor, fed by its ``first_trip_period`` up to the first trip's block
        of the same run: a run made again to that block has the same rows (nothing acted before it)."""
        if not self.reference and self.follow is not None and other.follow is not None and not self.follow_fed:
            self.follow, self.follow_fed = other.follow, other.follow_fed
            self.follow_indications = list(other.follow_indications)

    def first_trip(self, rows) -> Trip | None:
        """Judge a whole run made without acting (``first_trip_period``): its first trip, in the worker's words,
        or None; nothing acts on the loop."""
        first = self.first_trip_period(rows)
        if first is None:
            self.prime(rows)
            return None
        self.prime(rows[:first])
        act, self.act = self.act, False
        try:
            return self.check(rows[first: first + CHECK_PERIODS])
        finally:
            self.act = act

    def _guard_trip(self, block) -> Trip | None:
        """The displacement guard began a braking stop in this block: the trip that says so (``guard_trip``)."""
        if self.guard_m is None:
            return None
        trip = guard_trip(block, self.guard_m, self.loop.brake_rest_m, self.brake_m_per_s2)
        if trip is not None and self.act:
            self.loop.stopping = True
        return trip


def guard_trip(block, guard_m: float, rest_m: float, brake_m_per_s2: float) -> Trip | None:
    """The displacement guard began a braking stop in this block (FLAG_GUARD): the trip that says so, in the words
    of the service's record (backend.worker.Run.guard_trip uses it too), or None."""
    hits = np.flatnonzero(np.nan_to_num(block["flags"]).astype(np.int64) & FLAG_GUARD)
    if hits.size == 0:
        return None
    i = int(hits[0])
    t, r = float(block["time_s"][i]), float(block["target_m"][i])
    y = float(block["measured_displacement_m"][i])
    message = (f"displacement limit: controlled stop at t = {t:.3f} s before the target carried the table past "
               f"the limit of {guard_m * 1e3:.4g} mm: braking to rest at {rest_m * 1e3:.4g} mm "
               f"(at most {brake_m_per_s2:.3g} m/s2), held there under control")
    values = {"time_s": t, "target_m": r, "displacement_m": y, "rest_m": rest_m, "limit": guard_m,
              "limit_name": "displacement_m", "action": "controlled_stop", "guard": True,
              "brake_m_per_s2": brake_m_per_s2}
    return Trip("displacement", i, t, message, values, "controlled_stop")


def follow_monitor(scenario, table=None):
    """The detector of a rig the controller cannot follow (sim.follow), judged against the rig's declared
    position latency, as the worker builds it; None for the commissioning excitation (it follows no target)."""
    from .controllers import INTERNAL_FACTORIES
    from .follow import FollowMonitor, advice_for, limits_for, reference_for
    from .force_limit import ActuatorLimits

    if scenario.controller in INTERNAL_FACTORIES:
        return None
    if scenario.profile:
        reference = reference_for(scenario.profile)
    else:
        r = table[:, 0] if table is not None and len(table) else scenario.history.r_m
        reference = reference_for([], r)
    return FollowMonitor(reference, scenario.rig.position_latency_s, limits_for(scenario.controller),
                         advice_for(scenario.controller), getattr(scenario, "rig_commissioning", None),
                         scenario.controller, options_in_force(scenario), ActuatorLimits.of_rig(scenario.rig))


def options_in_force(scenario) -> dict:
    """The run's controller options, with the servo's position loop gain as its loop design lowered it
    (sim.controllers.servo.loop_design): what the follow monitor's advice halves."""
    from .controllers import make_controller

    options = dict(getattr(scenario, "effective_controller_options", dict)())
    if scenario.controller == "servo":
        built = make_controller("servo", rig=scenario.rig, **options).options
        options["kp_per_s"] = built["kp_in_force_per_s"]
    return options


def follow_monitor_like(monitor):
    """A fresh follow monitor with the settings of ``monitor``."""
    from .follow import FollowMonitor

    return FollowMonitor(monitor.reference, monitor.lag * CONTROL_PERIOD_S, monitor.limits, monitor.advice,
                         monitor.commissioning, monitor.controller, monitor.controller_options, monitor.actuator)


def verdict(trip: Trip | None, diverged: bool = False, time_s: float = 0.0) -> tuple[str, str | None]:
    """(status, reason) as the service records them: ``aborted`` with the trip's message, ``completed``."""
    if trip is not None:
        return "aborted", trip.message
    if diverged:  # the worker's words for a simulated rig that cannot run on
        return "aborted", f"the simulated rig's state became non-finite at t = {time_s:.3f} s"
    return "completed", None


@dataclass(frozen=True)
class PredictedTrip:
    """A trip the first cycle of a test is expected to meet (``predict_first_trip``)."""

    trip: Trip
    simulated_s: float  # the test time simulated
    controller: str

    def warning(self) -> str:
        """The words of the confirmation's warning."""
        return (f"expected to trip in its first cycle (the {self.controller} controller on the rig model, the first "
                f"{self.simulated_s:.3g} s simulated): {self.trip.message}")

    def to_dict(self) -> dict:
        return {"detector": self.trip.detector, "action": self.trip.action, "time_s": self.trip.time_s,
                "message": self.trip.message, "values": self.trip.values, "simulated_s": self.simulated_s,
                "controller": self.controller}


def first_cycle_s(scenario) -> float:
    """The test time of a sine test's first cycle: the first block's taper-in and its first steady cycle (a
    time history or a block without cycles: 0, nothing to predict), at most ``PREDICTION_MAX_S``."""
    if scenario.history is not None or not scenario.profile:
        return 0.0
    block = scenario.profile[0]
    cycles = min(block.taper_cycles + 1, block.cycles + 2 * block.taper_cycles)
    return min(cycles / block.frequency_hz, scenario.duration_s, PREDICTION_MAX_S)


def predict_first_trip(scenario, limits: SafetyLimits, window_s: float | None = None) -> PredictedTrip | None:
    """The trip the test's first cycle meets on the rig the controller is told of (the simulated plant with the
    test's isolator, load and supply pressure) with the test's limits, the sensor detectors and the guard of a
    controlled-stop displacement limit; None if nothing trips. Only the first cycle (``first_cycle_s``, or
    ``window_s``) runs, in one compiled call, and the detectors judge it at once (the first trip is the one the
    worker's blocks meet: nothing acts before it). The follow detector, which judges the learning over steady
    cycles, is left out: it would cost a check per ten periods."""
    from .engine import Simulation

    window_s = first_cycle_s(scenario) if window_s is None else min(window_s, scenario.duration_s)
    n = int(round(window_s / CONTROL_PERIOD_S))
    if n <= 0:
        return None
    sim = Simulation(scenario, validate=False)
    detectors = RunDetectors(scenario, sim.loop, limits, follow=False)
    rows = sim.advance(n)
    first = detectors.first_trip_period(rows)
    if first is not None:
        detectors.prime(rows[:first])
        trip = detectors.check(rows[first: first + CHECK_PERIODS])
        return PredictedTrip(trip, window_s, scenario.controller)
    if sim.diverged:
        _status, reason = verdict(None, True, sim.time_s)
        return PredictedTrip(Trip("rig_fault", 0, sim.time_s, reason, {"time_s": sim.time_s}), window_s,
                             scenario.controller)
    return None
