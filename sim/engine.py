"""Offline engine: a test's closed loop (sim.loop) around the simulated rig (sim.plant), as fast as it runs.

``Simulation(scenario)`` builds the scenario's ``ClosedLoop`` and ``SimulatedPlant`` and advances them
together in chunks (``advance(n_periods)``, one compiled call per chunk), so a worker can pace it in real
time; ``run()`` goes to the end and returns a ``Result`` with named samples (sim.samples). ``run_batch``
runs many scenarios on all cores. Everything is deterministic: the sensor noise (zero by default) is a
pure function of the seed and the period.
"""

from __future__ import annotations

import os
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, field

from .controllers import DEFAULT_CONTROLLER, Controller, make_controller
from .isolator import Isolator, load_isolator
from .loop import CONTROL_PERIOD_S, ClosedLoop
from .plant import PLANT_SUBSTEPS, SimulatedPlant
from .profiles import SineProfile, profile_duration_s, validate_profile
from .rig import BAR_PA, DEFAULT_RIG, RigParameters
from .samples import Samples

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
        """The rig under this test's vertical load (its friction follows, eq. 1)."""
        load = self.effective_vertical_load_n
        return self.rig if load == self.rig.vertical_load_n else self.rig.with_changes(vertical_load_n=load)

    @property
    def duration_s(self) -> float:
        return profile_duration_s(self.profile)

    @property
    def n_periods(self) -> int:
        return int(round(self.duration_s / CONTROL_PERIOD_S))

    def validate(self) -> None:
        validate_profile(self.profile, self.plant_rig, self.isolator, self.supply_pa)

    def describe(self) -> dict:
        return {
            "label": self.label,
            "isolator": self.isolator.to_dict(),
            "supply_bar": self.supply_pa / BAR_PA,
            "vertical_load_n": self.effective_vertical_load_n,
            "profile": [b.to_dict() for b in self.profile],
            "controller": self.controller,
            "controller_options": self.controller_options,
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
        controller = controller or make_controller(scenario.controller, **scenario.controller_options)
        self.loop = ClosedLoop(scenario.profile, controller, scenario.rig.command_limit_v)
        self.plant = SimulatedPlant(scenario.plant_rig, scenario.isolator, scenario.supply_pa, scenario.noise_seed,
                                    substeps=plant_substeps)

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

    def advance(self, n_periods: int) -> Samples:
        """Run up to n_periods more control periods; returns their rows."""
        return self.plant.run_closed(self.loop, n_periods)

    def run(self, chunk_periods: int = 5000, progress=None) -> Result:
        """Run to the end; ``progress(fraction)`` is called after each chunk."""
        chunks = []
        while not self.done:
            chunks.append(self.advance(chunk_periods))
            if progress is not None:
                progress(self.period / max(self.total_periods, 1))
        return Result(self.scenario, Samples.concatenate(chunks), self.diverged)


@dataclass
class Result:
    scenario: Scenario
    samples: Samples
    diverged: bool = False

    def column(self, name: str):
        return self.samples[name]

    def summary(self) -> dict:
        """Scenario, tracking figures, and per cycle its phase and loop metrics with the headline figures
        over the steady cycles (the same figures the service and the report give)."""
        from .metrics import headline_figures, scenario_cycle_metrics
        from .tracking import tracking_summary

        out = {"scenario": self.scenario.describe(), "diverged": self.diverged,
               **tracking_summary(self.samples, self.scenario)}
        loops = {c["cycle"]: c for c in scenario_cycle_metrics(self.samples, self.scenario)} \
            if len(self.samples) else {}
        for c in out["cycles"]:
            loop = loops.get(c["cycle"], {})
            c.update({k: v for k, v in loop.items() if k not in ("i_start", "i_end")})
        out["headline"] = headline_figures(list(loops.values()))
        return out


def run_scenario(scenario: Scenario) -> Result:
    return Simulation(scenario).run()


def _run_for_pool(scenario: Scenario) -> Result:
    return Simulation(scenario).run()


def run_batch(scenarios: list[Scenario], processes: int | None = None) -> list[Result]:
    """Run many scenarios in parallel on all cores (one process each; results in input order)."""
    for s in scenarios:
        s.validate()
    processes = processes or os.cpu_count() or 1
    if processes == 1 or len(scenarios) == 1:
        return [_run_for_pool(s) for s in scenarios]
    warm_up()  # compile (or load from cache) once before forking, so workers do not each compile
    with ProcessPoolExecutor(max_workers=processes) as pool:
        return list(pool.map(_run_for_pool, scenarios))


def warm_up() -> None:
    """Compile the engine's kernels for every controller (cached on disk after the first time), the compiled
    fast path and the per-period path of a real rig alike."""
    from .controllers import CONTROLLER_NAMES

    for name in CONTROLLER_NAMES:
        s = Scenario.sine("IUT_a", 100.0, 0.01, 1.0, 1, controller=name, taper_cycles=0)
        sim = Simulation(s)
        sim.advance(2)
        sim.loop.step(sim.plant.measure())

