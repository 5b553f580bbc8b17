"""Tracking on a simulated single-rod actuator, the servo told the rig exactly: 20 mm at 0.5 Hz, 2 mm and 0.5 mm at
1 Hz (IUT_a, 100 bar, position latency 1 ms, 12 cycles, taper 1, the service's follow monitor), for A_B / A_A of 1
(double-rod), 0.6 and 0.5 (sim.rig's docstring: the valve law of such an actuator). Prints the tracking verdict's
RMS share of each case and any stop.

    .venv/bin/python scripts/single_rod_tracking.py [--ratios 1,0.6,0.5]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

CASES = ((0.02, 0.5), (0.002, 1.0), (0.0005, 1.0))  # amplitude m, frequency Hz


def main(argv=None) -> int:
    import numpy as np

    from sim.engine import Scenario, Simulation
    from sim.rig import DEFAULT_RIG

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--ratios", default="1,0.6,0.5", help="A_B / A_A values, comma-separated")
    args = parser.parse_args(argv)
    np.seterr(all="ignore")
    for ratio in (float(x) for x in args.ratios.split(",")):
        area_b = 0.0 if ratio == 1.0 else ratio * DEFAULT_RIG.piston_area_m2
        rig = DEFAULT_RIG.with_changes(piston_area_b_m2=area_b, position_latency_s=1e-3)
        row = [f"A_B/A_A {ratio:g}"]
        for amplitude_m, frequency_hz in CASES:
            scenario = Scenario.sine("IUT_a", 100.0, amplitude_m, frequency_hz, 12, rig=rig)
            result = Simulation(scenario, validate=False).run(follow=True)
            share = result.summary()["tracking_verdict"].get("rms_share", float("nan"))
            stop = f" stopped ({result.trip.detector})" if result.trip else ""
            row.append(f"{amplitude_m * 1e3:g} mm {100 * share:.3f} %{stop}")
        print(" | ".join(row), flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
