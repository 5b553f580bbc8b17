"""Offline engine: a test's closed loop (sim.loop) around the simulated rig (sim.plant), as fast as it runs.

``Simulation(scenario)`` builds the scenario's ``ClosedLoop`` and ``SimulatedPlant`` and advances them
together in chunks (``advance(n_periods)``, one compiled call per chunk), so a worker can pace it in real
time; ``run()`` goes to the end and returns a ``Result`` with named samples (sim.samples). ``run_batch``
runs many scenarios on all cores. Everything is deterministic: the sensor noise (zero by default) is a
pure function of the seed and the period.
"""

from __future__ import annotations

import dataclasses
import os
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, field

import numpy as np

from .controllers import DEFAULT_CONTROLLER, Controller, make_controller
from .isolator import Isolator, load_isolator
from .loop import CONTROL_PERIOD_S, ClosedLoop
from .plant import PLANT_SUBSTEPS, SimulatedPlant
from .profiles import SineProfile, check_vertical_load, profile_duration_s, validate_profile
from .rig import BAR_PA, DEFAULT_RIG, RigParameters
from .samples import N_FIELDS, Samples

__all__ = ["CONTROL_PERIOD_S", "PLANT_SUBSTEPS", "Result", "Scenario", "Simulation", "run_batch", "run_scenario",
           "warm_up"]


@dataclass
class Scenario:
    """One closed-loop test: isolator, supply pressure, profile, controller, rig."""

    isolator: Isolator
    supply_pa: float
    profile: list[SineProfile]
    controller: str = DEFAULT_CONTROLLER
    controller_options: dict = field(default_factory=dict)
    rig: RigParameters = DEFAULT_RIG
    label: str = ""
    noise_seed: int = 0  # sensor noise (sim.sensors); only matters when the rig declares noise
    #: the vertical load on the specimen, N (friction mu N + F_c of eq. 1); None: the isolator's design load,
    #: else the rig's default (the paper's 1.25e5 N)
    vertical_load_n: float | None = None
    #: the simulated plant only (the rig as it truly is, unknown to the controller): rig or isolator
    #: parameters by name, from the start ...
    plant_changes: dict = field(default_factory=dict)
    #: ... and in the middle of the test: (time_s, name, value), e.g. an isolator that softens as it heats
    timed_changes: list = field(default_factory=list)
    #: a displacement time history (sim.history.HistoryTarget) instead of the sine ``profile``
    history: object | None = None
    #: a foreign rig (foreign_rigs.ForeignRigSpec: a rig written from the physics, not from sim's model) as the
    #: plant instead of ``plant_rig`` and ``plant_isolator``; ``rig`` stays what the controller is told
    foreign_rig: object | None = None
    #: how the rig the controller is told was measured: the rig file's ``commissioning`` section
    #: (sim.rigfile.RigDescription.commissioning) or its few facts (sim.follow.commissioning_facts); None for a rig
    #: nobody commissioned. The follow monitor names an oscillation on a commissioned rig as the controller's, and
    #: the tracking verdict judges with the latency's uncertainty (sim.follow)
    rig_commissioning: dict | None = None

    def make_plant(self, substeps: int = PLANT_SUBSTEPS):
        """The simulated hardware of this scenario: sim's model (SimulatedPlant), or the foreign rig."""
        if self.foreign_rig is not None:
            from .foreign_plant import ForeignPlant

            return ForeignPlant(self.foreign_rig, self.supply_pa, self.effective_vertical_load_n)
        return SimulatedPlant(self.plant_rig, self.plant_isolator, self.supply_pa, self.noise_seed, substeps=substeps)

    @classmethod
    def sine(cls, isolator: str | Isolator, supply_bar: float, amplitude_m: float, frequency_hz: float,
             cycles: int, controller: str = DEFAULT_CONTROLLER, taper_cycles: int = 1, offset_m: float = 0.0,
             **kwargs) -> Scenario:
        iso = isolator if isinstance(isolator, Isolator) else load_isolator(isolator)
        prof = SineProfile(amplitude_m, frequency_hz, cycles, taper_cycles, offset_m)
        return cls(iso, supply_bar * BAR_PA, [prof], controller, **kwargs)

    @property
    def effective_vertical_load_n(self) -> float:
        if self.vertical_load_n is not None:
            return self.vertical_load_n
        if self.isolator.design_vertical_load_n is not None:
            return self.isolator.design_vertical_load_n
        return self.rig.vertical_load_n

    @property
    def plant_rig(self) -> RigParameters:
        """The simulated rig: the rig the controller assumes, under this test's vertical load (its friction
        follows, eq. 1), with the plant-only changes."""
        return plant_at(self, {})[0]

    @property
    def plant_isolator(self) -> Isolator:
        return plant_at(self, {})[1]

    @property
    def duration_s(self) -> float:
        if self.history is not None:
            return self.history.n_samples * CONTROL_PERIOD_S
        return profile_duration_s(self.profile)

    @property
    def n_periods(self) -> int:
        if self.history is not None:
            return self.history.n_samples
        return int(round(self.duration_s / CONTROL_PERIOD_S))

    def effective_controller_options(self) -> dict:
        """The options the controller runs with: for the servo on a rig isorig commissioned (a trusted
        ``rig_commissioning``) its commissioned mode, for a time history (no repeating cycle to learn) its tracking
        mode (sim.controllers.servo COMMISSIONED_MODE, HISTORY_MODE), each under what the test asks."""
        if self.controller != "servo":
            return dict(self.controller_options)
        from .controllers.servo import COMMISSIONED_MODE, HISTORY_MODE
        from .follow import commissioning_facts

        modes = {}
        if commissioning_facts(self.rig_commissioning) is not None:
            modes.update(COMMISSIONED_MODE)
        if self.history is not None:
            modes.update(HISTORY_MODE)
        return {**modes, **self.controller_options}

    def target_table(self):
        """The table of (r, r', r'') per period for a time history (a copy: a stop fades it), else None."""
        if self.history is None:
            return None
        h = self.history
        return np.column_stack([h.r_m, h.r_dot_m_per_s, h.r_ddot_m_per_s2])

    def validate(self) -> None:
        """The vertical load, the plant's changes, the envelope (on the rig the controller assumes, under the
        test's load)."""
        check_vertical_load(self.effective_vertical_load_n, self.rig)  # against the jack, with its own field
        self.check_plant()
        rig = self.rig.with_changes(vertical_load_n=self.effective_vertical_load_n)
        if self.history is not None:
            from .history import history_envelope_problem
            from .profiles import check_supply

            check_supply(self.supply_pa, rig)
            problem = history_envelope_problem(self.history, rig, self.isolator, self.supply_pa)
            if problem is not None:
                raise problem
            return
        validate_profile(self.profile, rig, self.isolator, self.supply_pa)

    def check_plant(self) -> None:
        """Every plant the test will see (with its plant changes, then after each timed change) must be a rig
        and an isolator: a clear FieldError naming the parameter otherwise."""
        from .isolator import isolator_from_dict
        from .rig import RigError

        timed: dict = {}
        for when in [None, *sorted(self.timed_changes)]:
            if when is not None:
                t_s, name, value = when
                if not (isinstance(t_s, (int, float)) and 0.0 <= t_s <= self.duration_s):
                    raise RigError("plant_change", t_s, f"[0, {self.duration_s:g}] s",
                                   f"a plant change at t = {t_s!r} s is outside the test (0 to {self.duration_s:g} s)")
                timed[name] = value
            rig, isolator = plant_at(self, timed)
            rig.check()
            isolator_from_dict(isolator.to_dict())

    def describe(self) -> dict:
        return {
            "label": self.label,
            "isolator": self.isolator.to_dict(),
            "supply_bar": self.supply_pa / BAR_PA,
            "vertical_load_n": self.effective_vertical_load_n,
            "profile": [b.to_dict() for b in self.profile],
            "history": self.history.to_dict() if self.history is not None else None,
            "controller": self.controller,
            "controller_options": self.controller_options,
            "controller_options_in_force": self.effective_controller_options(),
            "rig_changes": {f.name: getattr(self.rig, f.name) for f in dataclasses.fields(self.rig)
                            if getattr(self.rig, f.name) != getattr(DEFAULT_RIG, f.name)},
            "plant_changes": dict(self.plant_changes),
            "timed_changes": [list(c) for c in sorted(self.timed_changes)],
            "duration_s": self.duration_s,
            "control_period_s": CONTROL_PERIOD_S,
            "plant_step_s": CONTROL_PERIOD_S / PLANT_SUBSTEPS,
        }


class Simulation:
    """A scenario in progress; ``advance`` runs it forward in chunks and returns the new samples."""

    def __init__(self, scenario: Scenario, validate: bool = True, controller: Controller | None = None,
                 plant_substeps: int = PLANT_SUBSTEPS):
        if validate:
            scenario.validate()
        self.scenario = scenario
        controller = controller or make_controller(scenario.controller, rig=scenario.rig,
                                                   **scenario.effective_controller_options())
        self.loop = ClosedLoop(scenario.profile, controller, scenario.rig.command_limit_v,
                               table=scenario.target_table())
        self.plant = scenario.make_plant(plant_substeps)
        self.pending_changes = sorted(scenario.timed_changes)
        self.changes_applied: dict = {}

    @property
    def controller(self) -> Controller:
        return self.loop.controller

    @property
    def period(self) -> int:
        return self.loop.period

    @property
    def total_periods(self) -> int:
        return self.loop.end_period

    @property
    def diverged(self) -> bool:
        return self.plant.diverged

    @property
    def done(self) -> bool:
        return self.loop.done or self.plant.diverged

    @property
    def time_s(self) -> float:
        return self.loop.time_s

    def advance(self, n_periods: int, out: np.ndarray | None = None) -> Samples:
        """Run up to n_periods more control periods; returns their rows. A timed plant change takes effect at
        the first period at or after its time. ``out``: write the rows into it (C-contiguous, N_FIELDS
        columns; at most its length run) and return a view of them, instead of new arrays."""
        if out is not None:
            return self._advance_into(out[: max(0, int(n_periods))])
        parts, left = [], max(0, int(n_periods))
        while left > 0 and not self.done:  # more than one part only if a braking stop lengthens the test
            parts.append(self._advance_into(np.empty((min(left, self.total_periods - self.period), N_FIELDS))))
            left -= len(parts[-1])
        return parts[0] if len(parts) == 1 else Samples.concatenate(parts)

    def _advance_into(self, out: np.ndarray) -> Samples:
        """Run as many periods as ``out`` has rows (fewer if the test ends); the rows written, a view of out."""
        filled = 0
        while filled < out.shape[0] and not self.done:
            if self.pending_changes and self.pending_changes[0][0] <= self.time_s + 1e-12:
                _t, name, value = self.pending_changes.pop(0)
                self.changes_applied[name] = value
                rig, isolator = plant_at(self.scenario, self.changes_applied)
                self.plant.rebuild(rig, isolator)
                continue
            n = out.shape[0] - filled
            if self.pending_changes:
                n = min(n, max(1, int(np.ceil(self.pending_changes[0][0] / CONTROL_PERIOD_S - 1e-9)) - self.period))
            filled += len(self.plant.run_closed(self.loop, n, out[filled:]))
        return Samples(out[:filled])

    def run(self, chunk_periods: int = 5000, progress=None, follow: bool = False, limits=None,
            act: bool = True, reference_detectors: bool = False, follow_action: str | None = None) -> Result:
        """Run to the end; ``progress(fraction)`` is called after each chunk. ``limits`` (sim.safety.SafetyLimits)
        and ``follow``: with the service's detectors (the limits and sensor detectors; ``follow``: the detector
        of a rig the controller cannot follow, sim.follow), judged every 10 periods and acted on as the worker
        does (sim.detectors): a trip closes the valve (0 V over 0.1 s, at once after a sensor fault or a
        controller that does not follow) or, with ``controlled_stop``, brakes the target to rest; the run ends
        there, ``aborted`` (Result.status).

        With detectors the run goes to its end in compiled chunks first and the detectors judge it at once;
        only a run that trips is run again, to its first trip's block in one call and on from there a block
        at a time (the same rows as the worker's checks every 10 periods, at a fraction of their cost).
        ``act`` False: the detectors judge only; the run goes on past a trip (``Result.ran_past_trip``), its
        status and reason still the service's (a study, isorig compare). ``reference_detectors``: the detectors
        on their per-block path, each fed as before the compiled follow judge (tests/test_detectors.py compares
        the two). ``follow_action``: the follow detector's action without ``limits`` (with them:
        ``limits.actions.follow``); ``indicate`` records its findings (``Result.indications``) and goes on."""
        from .detectors import CHECK_PERIODS, RunDetectors

        if not (follow or limits is not None):
            return Result(self.scenario, self._run_rows(chunk_periods, progress), self.diverged)
        start = self.period
        table = self.scenario.target_table()
        detectors = RunDetectors(self.scenario, self.loop, limits, follow=follow, table=table,
                                 reference=reference_detectors, follow_action=follow_action)
        rows = self._run_rows(chunk_periods, progress)
        if not act:
            trip = detectors.first_trip(rows)
            return Result(self.scenario, rows, self.diverged, trip, detectors.all_indications,
                          ran_past_trip=trip is not None, follow_action=detectors.follow_action)
        first = detectors.first_trip_period(rows)
        if first is None:
            detectors.prime(rows)  # the indications of indicate limits
            return Result(self.scenario, rows, self.diverged, None, detectors.all_indications,
                          follow_action=detectors.follow_action)
        if start != 0:
            raise ValueError("a run with detectors that trips is run again from its start: begin it at period 0")
        self._restart()
        judged = detectors
        detectors = RunDetectors(self.scenario, self.loop, limits, follow=follow, table=table,
                                 reference=reference_detectors, follow_action=follow_action)
        detectors.take_follow(judged)  # fed up to the first trip's block by first_trip_period: the same rows
        before = self.advance(first)
        detectors.prime(before)
        parts = [before]
        while not self.done:
            block = self.advance(CHECK_PERIODS)
            detectors.check(block)
            parts.append(block)
        return Result(self.scenario, Samples.concatenate(parts), self.diverged, detectors.trip,
                      detectors.all_indications, follow_action=detectors.follow_action)

    def _restart(self) -> None:
        """Back to period 0: a new loop (the same controller, a fresh state) and plant."""
        controller = self.loop.controller
        scenario = self.scenario
        self.loop = ClosedLoop(scenario.profile, controller, scenario.rig.command_limit_v,
                               table=scenario.target_table())
        self.plant = scenario.make_plant(getattr(self.plant, "substeps", PLANT_SUBSTEPS))
        self.pending_changes = sorted(scenario.timed_changes)
        self.changes_applied = {}

    def _run_rows(self, chunk_periods: int, progress) -> Samples:
        """The rest of the run, no detectors; the rows go into one buffer of the test's length (grown if a
        braking stop lengthens the test)."""
        rows = np.empty((max(0, self.total_periods - self.period), N_FIELDS))
        filled, next_progress = 0, 0
        while not self.done:
            if filled == rows.shape[0]:
                more = max(self.total_periods - self.period, chunk_periods)
                rows = np.concatenate([rows, np.empty((more, N_FIELDS))])
            chunk = self.advance(chunk_periods, out=rows[filled:])
            filled += len(chunk)
            if progress is not None and self.period >= next_progress:
                progress(self.period / max(self.total_periods, 1))
                next_progress = self.period + 5000
        return Samples(rows[:filled])


@dataclass
class Result:
    scenario: Scenario
    samples: Samples
    diverged: bool = False
    #: the detector that stopped the run (sim.safety.Trip: a limit, a sensor detector, the table not following),
    #: or None
    trip: object | None = None
    #: the excursions beyond a limit whose action is ``indicate`` (sim.safety.Trip), the first ten of each
    indications: list = field(default_factory=list)
    #: the detectors judged only: the run went on past ``trip`` (a study; the service would have stopped there)
    ran_past_trip: bool = False
    #: the follow detector's action (sim.safety.FOLLOW_ACTIONS) when it ran, else None
    follow_action: str | None = None

    @property
    def status(self) -> str:
        """As the service records it: ``aborted`` (a detector stopped it, or the simulated rig diverged) or
        ``completed``."""
        return self._verdict()[0]

    @property
    def reason(self) -> str | None:
        """Why it did not complete, in the service's words (the trip's message), or None."""
        return self._verdict()[1]

    def _verdict(self) -> tuple[str, str | None]:
        from .detectors import verdict

        end_s = float(self.samples["time_s"][-1]) + CONTROL_PERIOD_S if len(self.samples) else 0.0
        return verdict(self.trip, self.diverged, end_s)

    def column(self, name: str):
        return self.samples[name]

    def summary(self) -> dict:
        """Scenario, tracking figures, and per cycle its phase and loop metrics with the headline figures
        over the steady cycles (the same figures the service and the report give)."""
        from .metrics import headline_figures, scenario_cycle_metrics
        from .tracking import tracking_summary

        out = {"scenario": self.scenario.describe(), "diverged": self.diverged,
               **tracking_summary(self.samples, self.scenario)}
        out["status"], out["reason"] = self.status, self.reason
        if self.ran_past_trip:
            out["ran_past_trip"] = True  # the figures go on past the trip the service would have stopped at
        if self.trip is not None:
            out["stopped"] = {"time_s": self.trip.time_s, "detector": getattr(self.trip, "detector", "not_following"),
                              "action": getattr(self.trip, "action", "valve_close"), "reason": self.trip.message,
                              "values": self.trip.values}
        if self.follow_action is not None:
            out["follow_action"] = self.follow_action
        if self.indications:
            out["limit_indications"] = [{"detector": i.detector, "time_s": i.time_s, "message": i.message}
                                        for i in self.indications]
        if self.scenario.history is not None:
            from .hybrid_metrics import tracking_criteria
            from .measurement import measured_rows

            s = self.samples
            if len(s) > 10:
                out["criteria"] = tracking_criteria(s["target_m"], s["displacement_m"], CONTROL_PERIOD_S,
                                                    measured=measured_rows(s["flags"]))
            out["tracking_verdict"] = self._said_indicate(self.verdict(out.get("criteria", {})))
            return out
        loops = {c["cycle"]: c for c in scenario_cycle_metrics(self.samples, self.scenario)} \
            if len(self.samples) else {}
        for c in out["cycles"]:
            loop = loops.get(c["cycle"], {})
            c.update({k: v for k, v in loop.items() if k not in ("i_start", "i_end")})
        out["headline"] = headline_figures(list(loops.values()))
        out["tracking_verdict"] = self._said_indicate(self.verdict())
        return out

    def _said_indicate(self, verdict: dict) -> dict:
        """The verdict, saying when the follow detector was set to indicate (it stopped nothing)."""
        return said_indicate(verdict, self.follow_action,
                             sum(1 for i in self.indications if i.detector == "not_following"))

    def verdict(self, criteria: dict | None = None) -> dict:
        """How well the table followed (sim.follow.tracking_verdict), with the advice for this controller."""
        from .follow import advice_for, tracking_verdict

        return tracking_verdict(self.samples, self.scenario.profile, criteria,
                                advice=advice_for(self.scenario.controller),
                                latency_s=self.scenario.rig.position_latency_s,
                                commissioning=self.scenario.rig_commissioning)


FOLLOW_CHECK_PERIODS = 10  # as the worker's detectors (backend.worker.CHECK_PERIODS; sim.detectors.CHECK_PERIODS)
ISOLATOR_PARAMETERS = ("rho_bw_per_m", "sigma_bw", "n", "kd_n_per_m", "kw_n")


def said_indicate(verdict: dict, follow_action: str | None, seen: int) -> dict:
    """The tracking verdict (sim.follow.tracking_verdict), saying when the follow detector was set to indicate
    (``follow_action``; it stopped nothing) and how often it indicated (``seen``): the words of the CLI's summary
    and of the service's."""
    if follow_action != "indicate":
        return verdict
    return {**verdict, "follow_action": "indicate",
            "words": f"{verdict['words']} (follow detector set to indicate: {seen} indication"
                     f"{'' if seen == 1 else 's'}, the test was not stopped)"}


def plant_at(scenario: Scenario, timed: dict) -> tuple[RigParameters, Isolator]:
    """The simulated rig and isolator: the scenario's rig under its vertical load with its plant changes, then
    the timed changes made so far (``timed``, name -> value)."""
    changes = {"vertical_load_n": scenario.effective_vertical_load_n, **scenario.plant_changes, **timed}
    rig_changes = {k: v for k, v in changes.items() if k not in ISOLATOR_PARAMETERS}
    iso_changes = {k: v for k, v in changes.items() if k in ISOLATOR_PARAMETERS}
    rig = scenario.rig.with_changes(**rig_changes) if any(
        getattr(scenario.rig, k) != v for k, v in rig_changes.items()) else scenario.rig
    isolator = dataclasses.replace(scenario.isolator, **iso_changes) if iso_changes else scenario.isolator
    return rig, isolator


def run_scenario(scenario: Scenario) -> Result:
    return Simulation(scenario).run()


def run_judged(scenario: Scenario, detectors: bool = True) -> Result:
    """A study's run (isorig compare), to its end, judged by the service's detectors with the rig's default
    limits and the follow detector: its status and reason are the service's, its figures go past a trip
    (``Result.ran_past_trip``); ``detectors`` False: not judged."""
    if not detectors:
        return Simulation(scenario).run()
    from .safety import default_limits

    return Simulation(scenario).run(follow=True, limits=default_limits(scenario.rig), act=False)


def _run_for_pool(scenario: Scenario, detectors: bool = False) -> Result:
    return run_judged(scenario, detectors)


def run_batch(scenarios: list[Scenario], processes: int | None = None, detectors: bool | list[bool] = False
              ) -> list[Result]:
    """Run many scenarios in parallel on all cores (one process each; results in input order); ``detectors``
    (one flag, or one per scenario): judged by the service's detectors (``run_judged``)."""
    for s in scenarios:
        s.validate()
    flags = list(detectors) if isinstance(detectors, (list, tuple)) else [bool(detectors)] * len(scenarios)
    processes = processes or os.cpu_count() or 1
    if processes == 1 or len(scenarios) == 1:
        return [_run_for_pool(s, d) for s, d in zip(scenarios, flags, strict=True)]
    warm_up()  # compile (or load from cache) once before forking, so workers do not each compile
    with ProcessPoolExecutor(max_workers=processes) as pool:
        return list(pool.map(_run_for_pool, scenarios, flags))


def warm_up() -> None:
    """Compile the engine's kernels for every controller (cached on disk after the first time), the compiled
    fast path and the per-period path of a real rig alike."""
    from .controllers import CONTROLLER_NAMES

    for name in CONTROLLER_NAMES:
        s = Scenario.sine("IUT_a", 100.0, 0.01, 1.0, 1, controller=name, taper_cycles=0)
        sim = Simulation(s)
        sim.advance(2)
        sim.loop.step(sim.plant.measure())

