"""Engine benchmark: the compiled fixed-step loop against scipy's solve_ivp (LSODA) on the same model.

Both integrate the same right-hand side (sim.rig.rig_derivatives) under the same closed loop (sim.loop,
one period at a time for solve_ivp); solve_ivp is restarted at every control period, as a zero-order-hold
controller requires. The engine's real-time factor is the median of ``ENGINE_REPEATS`` runs, so one cold
start (page faults, the first call of each kernel) does not set it. Beside the wall-clock figure, the same runs
give one per CPU second of the process (``engine_cpu_rtf``): on a machine shared with other jobs the wall figure
falls with the CPU share the process gets, the CPU figure much less.
"""

from __future__ import annotations

import time

import numpy as np
from scipy.integrate import solve_ivp

from .controllers import make_controller
from .engine import CONTROL_PERIOD_S, Scenario, Simulation, warm_up
from .loop import ClosedLoop
from .measurement import Measurement
from .rig import N_STATES, P_KD, P_KW, X_PL, X_W, X_Y, pack_plant, rig_derivatives_py, valve_command

PAPER_BENCH = dict(isolator="IUT_a", supply_bar=100.0, amplitude_m=0.02, frequency_hz=1.0, cycles=30,
                   controller="mrac", taper_cycles=0)
ENGINE_REPEATS = 5
# Absolute tolerances per state: y (m), y' (m/s), P_L (Pa), v_e (V), v_e' (V/s), w (-).
ATOL = np.array([1e-10, 1e-8, 1.0, 1e-7, 1e-4, 1e-9])


def run_solve_ivp(scenario: Scenario, rtol: float = 1e-6) -> np.ndarray:
    """Displacement at each control period with LSODA restarted every period; returns y samples."""
    loop = ClosedLoop(scenario.profile, make_controller(scenario.controller, **scenario.controller_options),
                      scenario.rig.command_limit_v)
    plant = pack_plant(scenario.rig, scenario.isolator, scenario.supply_pa)
    x = np.zeros(N_STATES)
    n = scenario.n_periods
    y = np.empty(n)
    for k in range(n):
        t = k * CONTROL_PERIOD_S
        force = plant[P_KD] * x[X_Y] + plant[P_KW] * x[X_W]
        u, _rows = loop.step(Measurement(k, t, float(x[X_Y]), float(force), float(x[X_PL]), scenario.supply_pa))
        y[k] = x[X_Y]
        v_c = valve_command(u, plant)
        sol = solve_ivp(rig_derivatives_py, (t, t + CONTROL_PERIOD_S), x, method="LSODA", rtol=rtol,
                        atol=ATOL, args=(v_c, plant))
        x = sol.y[:, -1].copy()
    return y


def bench(duration_s: float | None = None, progress=None) -> dict:
    """Real-time factors of both integrators on the paper scenario and their largest |dy|."""
    params = dict(PAPER_BENCH)
    if duration_s is not None:
        params["cycles"] = max(1, int(round(duration_s * params["frequency_hz"])))
    scenario = Scenario.sine(**params)
    warm_up()
    times, cpu_times = [], []
    for _ in range(ENGINE_REPEATS):
        t0, c0 = time.perf_counter(), time.process_time()
        result = Simulation(scenario).run()
        times.append(time.perf_counter() - t0)
        cpu_times.append(time.process_time() - c0)
    engine_s = float(np.median(times))
    if progress:
        progress("engine done; running solve_ivp (slow)")
    t0 = time.perf_counter()
    y_ref = run_solve_ivp(scenario)
    ivp_s = time.perf_counter() - t0
    sim_s = scenario.duration_s
    return {
        "scenario": f"IUT_a, 100 bar, 1 Hz, 20 mm, {sim_s:g} s, mrac",
        "engine_rtf": sim_s / engine_s,
        "engine_cpu_rtf": sim_s / float(np.median(cpu_times)),
        "solve_ivp_rtf": sim_s / ivp_s,
        "speedup": ivp_s / engine_s,
        "engine_runs": ENGINE_REPEATS,
        "max_abs_dy_m": float(np.max(np.abs(result.samples["displacement_m"] - y_ref))),
    }
