"""Issue 16's targets, measured: prints J1-J3 of time-history tracking and J4-J5 of virtual hybrid simulation.

Histories: the isolator's displacement demand under each synthetic ground motion (sim.ground_motion presets,
through sim.history.isolation_displacement with the mass the rig's default vertical load carries), scaled
down by 0.8 steps until the rig's envelope accepts it, on IUT_a at 100 bar and IUT_b at 70 bar, with the
default controller in its automatic tracking mode and no retuning between cases.
Targets: J1 <= 1 ms, J2 <= 1 %, J3 <= 3 %.

Hybrid: the demo building (docs/examples/structure_3_storey.json) on each isolator under each ground motion
(scaled like the histories), virtual RTHS on the simulated rig against the full-numerical reference.
Targets: J4 <= 2 %, J5 <= 3 %.

Run: .venv/bin/python scripts/earthquake_targets.py [--option NAME=VALUE ...]   (servo options to try)
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from sim.engine import Scenario, Simulation  # noqa: E402
from sim.ground_motion import GROUND_MOTIONS, synthetic_ground_motion  # noqa: E402
from sim.history import history_envelope_problem, isolation_displacement, prepare_history  # noqa: E402
from sim.hybrid import HybridSubstructure, compare_with_reference, ground_at_periods, reference, run_virtual  # noqa: E402
from sim.isolator import PRESETS  # noqa: E402
from sim.rig import DEFAULT_RIG  # noqa: E402
from sim.structure import load_structure  # noqa: E402

CASES = (("IUT_a", 100.0), ("IUT_b", 70.0))
G = 9.80665


def fitting_history(name: str, isolator, supply_pa: float):
    """The preset's displacement demand, scaled by 0.8 until the envelope accepts it; (target, scale, t, acc)."""
    t, acc, _info = synthetic_ground_motion(name)
    mass = DEFAULT_RIG.vertical_load_n / G
    scale = 1.0
    for _ in range(20):
        d = isolation_displacement(t, scale * acc, isolator, mass)
        target = prepare_history(t, d, source=f"{name} x {scale:.3g}")
        if history_envelope_problem(target, DEFAULT_RIG, isolator, supply_pa) is None:
            return target, scale, t, acc
        scale *= 0.8
    raise RuntimeError(f"{name} does not fit the rig on {isolator.name}")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--option", action="append", default=[], metavar="NAME=VALUE", help="a servo option to try")
    args = ap.parse_args()
    options = {k: float(v) for k, v in (o.split("=", 1) for o in args.option)}
    building = load_structure(ROOT / "docs" / "examples" / "structure_3_storey.json")
    t0 = time.perf_counter()
    worst = {"j1": 0.0, "j2": 0.0, "j3": 0.0, "j4": 0.0, "j5": 0.0}
    print("history tracking (J1 <= 1 ms, J2 <= 1 %, J3 <= 3 %) and virtual RTHS (J4 <= 2 %, J5 <= 3 %)")
    print(f"{'isolator':8s} {'ground motion':18s} {'scale':>5s} {'peak mm':>8s} {'J1 ms':>7s} {'J2 %':>6s} "
          f"{'J3 %':>6s} | {'J4 %':>6s} {'J5 %':>6s}")
    for iso_name, bar in CASES:
        isolator = PRESETS[iso_name]
        for name in GROUND_MOTIONS:
            target, scale, t, acc = fitting_history(name, isolator, bar * 1e5)
            scenario = Scenario(isolator, bar * 1e5, [], "servo", options, history=target)
            summary = Simulation(scenario).run().summary()
            c = summary["criteria"]
            ag = ground_at_periods(t, scale * acc)
            sub = HybridSubstructure(building, isolator, ag)
            from sim.controllers import make_controller
            from sim.loop import ClosedLoop
            from sim.plant import SimulatedPlant

            loop = ClosedLoop([], make_controller("servo", **scenario.effective_controller_options()),
                              DEFAULT_RIG.command_limit_v, table=sub.target_table())
            samples, stopped = run_virtual(sub, loop, SimulatedPlant(DEFAULT_RIG, isolator, bar * 1e5))
            j45 = compare_with_reference(sub.results(samples), reference(building, isolator, ag))
            print(f"{iso_name:8s} {name:18s} {scale:5.2f} {1e3 * np.max(np.abs(target.r_m)):8.1f} "
                  f"{c['j1_delay_ms']:7.3f} {c['j2_rms_percent']:6.2f} {c['j3_peak_percent']:6.2f} | "
                  f"{j45['j4_rms_percent']:6.2f} {j45['j5_peak_percent']:6.2f}" + ("  STOPPED" if stopped else ""))
            worst["j1"] = max(worst["j1"], abs(c["j1_delay_ms"]))
            worst["j2"] = max(worst["j2"], c["j2_rms_percent"])
            worst["j3"] = max(worst["j3"], c["j3_peak_percent"])
            worst["j4"] = max(worst["j4"], j45["j4_rms_percent"])
            worst["j5"] = max(worst["j5"], j45["j5_peak_percent"])
    met = (worst["j1"] <= 1.0 and worst["j2"] <= 1.0 and worst["j3"] <= 3.0 and worst["j4"] <= 2.0
           and worst["j5"] <= 3.0)
    print(f"worst: |J1| {worst['j1']:.3f} ms, J2 {worst['j2']:.2f} %, J3 {worst['j3']:.2f} %, J4 {worst['j4']:.2f} %, "
          f"J5 {worst['j5']:.2f} %: targets {'met' if met else 'NOT met'}; options {options or 'default'}; "
          f"{time.perf_counter() - t0:.1f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
