"""Closed-loop engine: controller at 1 kHz with zero-order hold, plant by fixed-step RK4.

Plant step: 0.2 ms (5 RK4 substeps per control period). The closed-loop eigenvalues of the rig
model are about -176 +- 180j (valve) and -90 +- 365j (oil column), so RK4 is stable well beyond
1 ms; at 0.2 ms the displacement agrees with a 0.02 ms reference to far below 1 um (see
``scripts/step_size_study.py`` and docs/engine.md). Everything is deterministic: no random
numbers, no threads inside one run.

A ``Simulation`` advances in chunks (``advance(n_periods)``) so a worker can pace it in real time;
``run_batch`` runs many scenarios on all cores.
"""

from __future__ import annotations

import os
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, field

import numpy as np
from numba import njit

from .controllers import DEFAULT_CONTROLLER, Controller, controller_step, make_controller
from .controllers.base import (
    M_LOAD_PRESSURE,
    M_POSITION,
    M_SUPPLY_PRESSURE,
    M_TARGET,
    M_TARGET_RATE,
    M_TIME,
    N_MEAS,
    N_REPORT,
)
from .isolator import Isolator, load_isolator
from .profiles import SineProfile, pack_profile, profile_duration_s, target, validate_profile
from .rig import (
    BAR_PA,
    DEFAULT_RIG,
    N_STATES,
    P_KD,
    P_KW,
    P_SUPPLY,
    P_ULIM,
    X_PL,
    X_V,
    X_VE,
    X_W,
    X_Y,
    RigParameters,
    load_flow,
    pack_plant,
    rk4_step,
    valve_command,
)

CONTROL_PERIOD_S = 1.0e-3
PLANT_SUBSTEPS = 5  # 0.2 ms RK4 step

# Sample columns. The first ten are the CSV columns of `isorig simulate`.
CSV_COLUMNS = ("time_s", "target_m", "model_m", "displacement_m", "voltage_v", "force_n",
               "load_pressure_pa", "ar_hat", "ay_hat", "as_hat")
EXTRA_COLUMNS = ("velocity_m_per_s", "flow_m3_per_s", "command_raw_v", "valve_v")
COLUMNS = CSV_COLUMNS + EXTRA_COLUMNS
(C_TIME, C_TARGET, C_MODEL, C_Y, C_U, C_FORCE, C_PL, C_AR, C_AY, C_AS,
 C_VEL, C_FLOW, C_URAW, C_VALVE) = range(len(COLUMNS))


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

    @classmethod
    def sine(cls, isolator: str | Isolator, supply_bar: float, amplitude_m: float, frequency_hz: float,
             cycles: int, controller: str = DEFAULT_CONTROLLER, taper_cycles: int = 1, offset_m: float = 0.0,
             **kwargs) -> Scenario:
        iso = isolator if isinstance(isolator, Isolator) else load_isolator(isolator)
        prof = SineProfile(amplitude_m, frequency_hz, cycles, taper_cycles, offset_m)
        return cls(iso, supply_bar * BAR_PA, [prof], controller, **kwargs)

    @property
    def duration_s(self) -> float:
        return profile_duration_s(self.profile)

    @property
    def n_periods(self) -> int:
        return int(round(self.duration_s / CONTROL_PERIOD_S))

    def validate(self) -> None:
        validate_profile(self.profile, self.rig, self.isolator, self.supply_pa)

    def describe(self) -> dict:
        return {
            "label": self.label,
            "isolator": self.isolator.to_dict(),
            "supply_bar": self.supply_pa / BAR_PA,
            "profile": [b.to_dict() for b in self.profile],
            "controller": self.controller,
            "controller_options": self.controller_options,
            "duration_s": self.duration_s,
            "control_period_s": CONTROL_PERIOD_S,
            "plant_step_s": CONTROL_PERIOD_S / PLANT_SUBSTEPS,
        }


@njit(cache=True)
def run_periods(x, plant, kind, cparams, cstate, blocks, k0, n, substeps, dt, out, u_hold=np.nan):
    """Advance the closed loop n control periods from period k0; one row of ``out`` per period.

    Each row holds the measurement at the start of the period and the command applied over it.
    With a finite ``u_hold`` the loop is open: the controller is not stepped, that command is held, and
    the target, model and adapted columns are NaN. Returns the number of rows written (fewer than n if
    the state became non-finite).
    """
    meas = np.empty(N_MEAS)
    report = np.empty(N_REPORT)
    k1 = np.empty(N_STATES)
    k2 = np.empty(N_STATES)
    k3 = np.empty(N_STATES)
    k4 = np.empty(N_STATES)
    tmp = np.empty(N_STATES)
    h = dt / substeps
    ulim = plant[P_ULIM]
    for i in range(n):
        t = (k0 + i) * dt
        if np.isfinite(u_hold):
            r = np.nan
            report[:] = np.nan
            u_raw = u_hold
        else:
            r, rdot = target(t, blocks)
            meas[M_TIME] = t
            meas[M_TARGET] = r
            meas[M_TARGET_RATE] = rdot
            meas[M_POSITION] = x[X_Y]
            meas[M_LOAD_PRESSURE] = x[X_PL]
            meas[M_SUPPLY_PRESSURE] = plant[P_SUPPLY]
            u_raw = controller_step(kind, cparams, cstate, meas, dt, report)
        u = min(max(u_raw, -ulim), ulim)
        if not np.isfinite(u):
            u = 0.0
        row = out[i]
        row[C_TIME] = t
        row[C_TARGET] = r
        row[C_MODEL] = report[0]
        row[C_Y] = x[X_Y]
        row[C_U] = u
        row[C_FORCE] = plant[P_KD] * x[X_Y] + plant[P_KW] * x[X_W]
        row[C_PL] = x[X_PL]
        row[C_AR] = report[1]
        row[C_AY] = report[2]
        row[C_AS] = report[3]
        row[C_VEL] = x[X_V]
        row[C_FLOW] = load_flow(x[X_VE], x[X_PL], plant)
        row[C_URAW] = u_raw
        row[C_VALVE] = x[X_VE]
        v_c = valve_command(u, plant)
        for _ in range(substeps):
            rk4_step(x, v_c, plant, h, k1, k2, k3, k4, tmp)
        for j in range(N_STATES):
            if not np.isfinite(x[j]):
                return i + 1
    return n


class Simulation:
    """A scenario in progress; ``advance`` runs it forward in chunks and returns the new samples."""

    def __init__(self, scenario: Scenario, validate: bool = True, controller: Controller | None = None,
                 plant_substeps: int = PLANT_SUBSTEPS):
        if validate:
            scenario.validate()
        self.scenario = scenario
        self.controller = controller or make_controller(scenario.controller, **scenario.controller_options)
        self.plant = pack_plant(scenario.rig, scenario.isolator, scenario.supply_pa)
        self.blocks = pack_profile(scenario.profile)
        self.state = np.zeros(N_STATES)
        self.controller_state = self.controller.new_state()
        self.period = 0
        self.total_periods = scenario.n_periods
        self.diverged = False
        self.plant_substeps = plant_substeps

    @property
    def done(self) -> bool:
        return self.period >= self.total_periods or self.diverged

    @property
    def time_s(self) -> float:
        return self.period * CONTROL_PERIOD_S

    def advance(self, n_periods: int) -> np.ndarray:
        """Run up to n_periods more control periods; returns an array (rows, len(COLUMNS))."""
        n = max(0, min(int(n_periods), self.total_periods - self.period))
        if self.diverged or n == 0:
            return np.empty((0, len(COLUMNS)))
        out = np.empty((n, len(COLUMNS)))
        written = run_periods(self.state, self.plant, self.controller.kind, self.controller.params,
                              self.controller_state, self.blocks, self.period, n, self.plant_substeps,
                              CONTROL_PERIOD_S, out)
        self.period += written
        if written < n:
            self.diverged = True
        return out[:written]

    def advance_open_loop(self, n_periods: int, command_v: float) -> np.ndarray:
        """Hold the valve command ``command_v`` (saturated at the limit) for n periods, controller idle.

        Not bounded by the profile's end: a controlled stop ramps the command after the test time is over.
        """
        n = max(0, int(n_periods))
        if self.diverged or n == 0:
            return np.empty((0, len(COLUMNS)))
        out = np.empty((n, len(COLUMNS)))
        u = float(command_v) if np.isfinite(command_v) else 0.0
        written = run_periods(self.state, self.plant, self.controller.kind, self.controller.params,
                              self.controller_state, self.blocks, self.period, n, self.plant_substeps,
                              CONTROL_PERIOD_S, out, u)
        self.period += written
        if written < n:
            self.diverged = True
        return out[:written]

    def run(self, chunk_periods: int = 5000, progress=None) -> Result:
        """Run to the end; ``progress(fraction)`` is called after each chunk."""
        chunks = []
        while not self.done:
            chunks.append(self.advance(chunk_periods))
            if progress is not None:
                progress(self.period / max(self.total_periods, 1))
        samples = np.concatenate(chunks) if chunks else np.empty((0, len(COLUMNS)))
        return Result(self.scenario, samples, self.diverged)


@dataclass
class Result:
    scenario: Scenario
    samples: np.ndarray
    diverged: bool = False

    def column(self, name: str) -> np.ndarray:
        return self.samples[:, COLUMNS.index(name)]

    def summary(self) -> dict:
        from .tracking import tracking_summary

        return {"scenario": self.scenario.describe(), "diverged": self.diverged,
                **tracking_summary(self.samples, self.scenario)}


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
    """Compile the engine's kernels for every controller (cached on disk after the first time)."""
    from .controllers import CONTROLLER_NAMES

    for name in CONTROLLER_NAMES:
        s = Scenario.sine("IUT_a", 100.0, 0.01, 1.0, 1, controller=name, taper_cycles=0)
        Simulation(s).advance(2)

