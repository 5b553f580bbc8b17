"""Justify the plant step: RK4 at several steps against a 0.02 ms RK4 reference, closed loop with ZOH.

Prints, for each plant step, the largest |y - y_ref| and |P_L - P_L,ref| and the real-time factor, on the
paper scenarios with the mrac and pid controllers. Run: .venv/bin/python scripts/step_size_study.py
"""

import time

import numpy as np

from sim.engine import Scenario, Simulation, warm_up

SUBSTEPS = (1, 2, 5, 10)  # 1 ms, 0.5 ms, 0.2 ms, 0.1 ms
REFERENCE_SUBSTEPS = 50  # 0.02 ms


def main():
    warm_up()
    cases = [("IUT_a 100 bar 20 mm 1 Hz servo", Scenario.sine("IUT_a", 100, 0.02, 1.0, 10, controller="servo")),
             ("IUT_b 70 bar 30 mm 1 Hz mrac", Scenario.sine("IUT_b", 70, 0.03, 1.0, 10, controller="mrac",
                                                            taper_cycles=0)),
             ("IUT_a 100 bar 20 mm 0.5 Hz pid", Scenario.sine("IUT_a", 100, 0.02, 0.5, 5, controller="pid"))]
    print(f"{'scenario':34s} {'plant step':>10s} {'max|dy| um':>11s} {'max|dP_L| Pa':>13s} {'x real time':>12s}")
    for label, scenario in cases:
        ref = Simulation(scenario, plant_substeps=REFERENCE_SUBSTEPS).run().samples
        for n in SUBSTEPS:
            t0 = time.perf_counter()
            out = Simulation(scenario, plant_substeps=n).run().samples
            rtf = scenario.duration_s / (time.perf_counter() - t0)
            dy = np.max(np.abs(out["displacement_m"] - ref["displacement_m"]))
            dp = np.max(np.abs(out["load_pressure_pa"] - ref["load_pressure_pa"]))
            print(f"{label:34s} {1.0 / n:8.2f} ms {dy * 1e6:11.4f} {dp:13.1f} {rtf:12.0f}")


if __name__ == "__main__":
    main()
