"""What the service's detectors cost a study: runs of the documented Monte Carlo campaign (docs/compare.md, "The
campaign file": drawn plants, servo and pid, 10 cycles at 1 Hz) judged as isorig compare judges them
(sim.engine.run_judged: the rig's default limits, the sensor and follow detectors) and not judged
(--no-limit-detectors), in this one process, passes alternated; prints each pass's CPU and wall time and the
figure: time with the detectors / time without. --reference adds a pass with the detectors on their per-block
numpy path fed as before the compiled follow judge (the figure before it) and checks that it gives the same trips.

Usage: .venv/bin/python scripts/bench_detectors.py [--runs 100] [--rounds 2] [--reference] [--campaign FILE]
(--runs plants, each run with every controller of the campaign: 100 plants are 200 runs.)
"""

from __future__ import annotations

import argparse
import os
import re
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def documented_campaign() -> str:
    """The campaign file docs/compare.md shows (as scripts/campaign_benchmark.sh takes it)."""
    text = (ROOT / "docs" / "compare.md").read_text()
    section = text[text.index("### The campaign file"):]
    return re.search(r"```toml\n(.*?)```", section, re.S).group(1)


def timed(run, scenarios) -> tuple[float, float, list]:
    """(CPU s, wall s, results) of ``run`` over the scenarios."""
    cpu, wall = time.process_time(), time.perf_counter()
    results = [run(s) for s in scenarios]
    return time.process_time() - cpu, time.perf_counter() - wall, results


def trip_key(result):
    trip = result.trip
    return None if trip is None else (trip.detector, trip.index, trip.time_s, trip.message, repr(trip.values))


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--runs", type=int, default=100, help="plants drawn (each run with every controller)")
    p.add_argument("--rounds", type=int, default=2, help="passes of each kind, alternated (the best is shown)")
    p.add_argument("--reference", action="store_true", help="also time the per-block numpy path (before)")
    p.add_argument("--campaign", help="a campaign file (default: the one docs/compare.md shows)")
    args = p.parse_args(argv)

    from sim.campaign import load_campaign
    from sim.engine import Simulation, run_judged, warm_up
    from sim.safety import default_limits

    if args.campaign:
        campaign = load_campaign(args.campaign)
    else:
        with tempfile.TemporaryDirectory() as folder:
            path = Path(folder) / "lab_spread.toml"
            path.write_text(documented_campaign())
            campaign = load_campaign(path)
    campaign.runs = args.runs
    scenarios = [point.scenario(campaign.cycles) for point in campaign.points()]
    warm_up()
    run_judged(scenarios[0])  # load the detectors' compiled code too

    passes = {"without detectors": lambda s: run_judged(s, detectors=False), "with detectors": run_judged}
    if args.reference:
        passes["with detectors, per-block reference"] = lambda s: Simulation(s).run(
            follow=True, limits=default_limits(s.rig), act=False, reference_detectors=True)
    best: dict[str, tuple[float, float]] = {}
    trips: dict[str, list] = {}
    for _ in range(args.rounds):
        for name, run in passes.items():
            cpu, wall, results = timed(run, scenarios)
            best[name] = min(best.get(name, (cpu, wall)), (cpu, wall))
            trips[name] = [trip_key(r) for r in results]

    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    print(f"{len(scenarios)} runs of campaign '{campaign.name}' ({campaign.cycles} cycles at {campaign.frequency_hz:g} "
          f"Hz), best of {args.rounds} alternated passes, load average {load:.1f}:")
    for name, (cpu, wall) in best.items():
        print(f"  {name:40s} CPU {cpu:7.2f} s   wall {wall:7.2f} s")
    free_cpu, free_wall = best["without detectors"]
    for name in list(passes)[1:]:
        cpu, wall = best[name]
        print(f"{name} / without: {cpu / free_cpu:.2f}x CPU, {wall / free_wall:.2f}x wall")
    stopped = sum(t is not None for t in trips["with detectors"])
    print(f"runs the detectors stop: {stopped} of {len(scenarios)}")
    if args.reference:
        same = trips["with detectors"] == trips["with detectors, per-block reference"]
        print(f"the same trips as the reference: {'yes' if same else 'NO'}")
        return 0 if same else 1
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
