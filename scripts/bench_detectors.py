"""What the service's detectors cost a study: runs of the documented Monte Carlo campaign (docs/compare.md, "The
campaign file": drawn plants, servo and pid, 10 cycles at 1 Hz) judged as isorig compare judges them
(sim.engine.run_judged: the rig's default limits, the sensor and follow detectors) and not judged
(--no-limit-detectors), in this one process, passes alternated; prints each pass's CPU and wall time and the
figure: time with the detectors / time without. --reference adds a pass with the detectors on their per-block
numpy path fed as before the compiled follow judge (the figure before it) and checks that it gives the same trips.

Usage: .venv/bin/python scripts/bench_detectors.py [--runs 100] [--rounds 2] [--reference] [--campaign FILE]
(--runs plants, each run with every controller of the campaign: 100 plants are 200 runs.)

--oscillations (issue 32 item 5): the follow detector's delay on oscillations that start mid-test (our rig, the
oil column's bulk modulus or mass changed at 4.3 s, the servo told the rig as it was) and its false trips on good
runs (the paper's scenarios with mrac and servo, our rig with servo and pid, rigs told exactly, --runs plants of
the campaign, and the commissioned foreign rigs of --foreign-seeds): each record is made once without detectors
and judged by the monitor (nothing acts before the first trip, so it is the run's first trip) as it is and with
the rules before the tone rule (FollowLimits.tone_share = inf: an oscillation told by its size alone). A good run
is one whose tracking verdict is followed or outside_target; a trip on it is a false trip. A stop by the tone rule
is marked "tone"; the good runs are judged again with the tone rule's bounds loosened (LOOSER_TONE), to show its
margin. Exits 1 when an oscillation is stopped later than 2 s after the change or a good run's first trip changed.
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


INJECTED_AT_S = 4.3
INJECTIONS = {"bulk 2e8 Pa": {"bulk_modulus_pa": 2.0e8}, "bulk 2.5e8 Pa": {"bulk_modulus_pa": 2.5e8},
              "bulk 3e8 Pa": {"bulk_modulus_pa": 3.0e8},
              "5000 kg, 3e8 Pa": {"mass_kg": 5000.0, "bulk_modulus_pa": 3.0e8},
              "3000 kg, 4.5e8 Pa": {"mass_kg": 3000.0, "bulk_modulus_pa": 4.5e8}}
SINES = [(0.02, 0.5), (0.01, 1.0), (0.005, 0.5), (0.002, 1.0), (0.03, 1.0)]


def judged_twice(scenario, samples):
    """The follow monitor's first trip on a record, today's and with the rules before the tone rule (size alone)."""
    import dataclasses
    import math

    from sim.detectors import follow_monitor

    now = follow_monitor(scenario)
    before = follow_monitor(scenario)
    before.limits = dataclasses.replace(before.limits, tone_share=math.inf)
    return now.feed(samples), before.feed(samples)


#: the tone rule's bounds loosened, to show the margin of today's on the good runs
LOOSER_TONE = {"tone_correlation 0.85": {"tone_correlation": 0.85}, "tone_correlation 0.8": {"tone_correlation": 0.8},
               "tone_floor_m 5 um": {"tone_floor_m": 5e-6}}


def judged_looser(scenario, samples) -> dict:
    """The follow monitor's first trip on a record with each of LOOSER_TONE's bounds."""
    import dataclasses

    from sim.detectors import follow_monitor

    out = {}
    for name, change in LOOSER_TONE.items():
        monitor = follow_monitor(scenario)
        monitor.limits = dataclasses.replace(monitor.limits, **change)
        out[name] = monitor.feed(samples)
    return out


def describe(trip) -> str:
    if trip is None:
        return "not stopped"
    f = trip.values.get("frequency_hz")
    tone = trip.values.get("tone_correlation") is not None
    return f"{trip.kind} at {trip.time_s:.3f} s" + (f" ({f:.0f} Hz{', tone' if tone else ''})" if f else "")


def good_runs(args) -> list:
    """(label, scenario) of runs without a change mid-test: the paper's, our rig, rigs told exactly, the campaign's."""
    import numpy as np

    from sim.engine import Scenario
    from sim.paper import paper_scenarios
    from sim.rig import DEFAULT_RIG

    runs = [(f"paper {s.label} {c}", s) for c in ("mrac", "servo") for s in paper_scenarios(c)]
    for iso, bar in (("IUT_a", 100.0), ("IUT_b", 70.0)):
        for a, f in [(0.02, 0.5), (0.002, 1.0), (0.0005, 1.0), (0.03, 1.0), (0.01, 2.0)]:
            for c in ("servo", "pid"):
                runs.append((f"{iso} {a * 1e3:g} mm {f:g} Hz {c}", Scenario.sine(iso, bar, a, f, 12, controller=c)))
    told = {"soft": {"mass_kg": 3000.0, "bulk_modulus_pa": 4.5e8}, "heavy": {"mass_kg": 5000.0, "bulk_modulus_pa": 3e8},
            "drawn": {"mass_kg": 1686.0, "bulk_modulus_pa": 3.9e8, "valve_natural_frequency_rad_s": 2 * np.pi * 52.7,
                      "dead_zone_v": 0.75, "position_latency_s": 1.83e-3}}
    for name, plant in told.items():
        for a, f in [(0.02, 0.5), (0.002, 1.0), (0.0005, 1.0)]:
            runs.append((f"told {name} {a * 1e3:g} mm {f:g} Hz", Scenario.sine(
                "IUT_a", 100.0, a, f, 12, rig=DEFAULT_RIG.with_changes(**plant), plant_changes=plant)))
    if args.runs:
        runs += [(f"campaign {s.label}", s) for s in campaign_scenarios(campaign_of(args))]
    return runs


def foreign_runs(seeds) -> list:
    """(label, scenario) of the foreign rigs commissioned as isorig compare --foreign-rigs does (the trusted ones)."""
    from foreign_rigs import draw_rig
    from sim.commission import foreign_campaign as fc
    from sim.engine import Scenario

    runs = []
    for seed in seeds:
        spec = draw_rig(seed)
        run = fc.ForeignRun(seed)
        ident = fc.commission(spec, fc.declared_rig(spec.lab_knows()), run.max_stroke_m, run.max_velocity_m_per_s)
        if not ident.trusted:
            print(f"  foreign rig {seed}: not commissioned on the first attempt, left out")
            continue
        section = fc.commissioning_section(ident, run.max_velocity_m_per_s)
        for label, a, f, _target in run.cases:
            runs.append((f"foreign {seed} {label}", Scenario.sine(
                fc.load_isolator(fc.CONTROLLER_ISOLATOR), fc.SUPPLY_PA / 1e5, a, f, fc.TEST_CYCLES, rig=ident.rig,
                vertical_load_n=float(spec.drawn["table.vertical_load_n"]), foreign_rig=spec,
                rig_commissioning=section)))
    return runs


def oscillations(args) -> int:
    """Print the detection delays on injected oscillations and the false trips on good runs."""
    from sim.engine import Scenario, Simulation

    print(f"oscillations that start at {INJECTED_AT_S} s (servo, IUT_a, 100 bar; told the rig as it was):")
    delays, before_delays, late_or_missed = [], [], 0
    for a, f in SINES:
        for name, change in INJECTIONS.items():
            s = Scenario.sine("IUT_a", 100.0, a, f, 8 if f <= 0.5 else 14,
                              timed_changes=[(INJECTED_AT_S, k, v) for k, v in change.items()])
            result = Simulation(s, validate=False).run()
            now, before = judged_twice(s, result.samples)
            if now is None and before is None:
                print(f"  {a * 1e3:4g} mm {f:g} Hz, {name:18s}: not stopped (either rule)")
                continue
            d = None if now is None else now.time_s - INJECTED_AT_S
            b = None if before is None else before.time_s - INJECTED_AT_S
            delays.append(d)
            before_delays.append(b)
            late_or_missed += d is None or d > 2.0
            print(f"  {a * 1e3:4g} mm {f:g} Hz, {name:18s}: {describe(now):32s} delay "
                  f"{'-' if d is None else f'{d:.2f} s':7s} (before: {describe(before)}, "
                  f"{'-' if b is None else f'{b:.2f} s'})")
    stopped = [d for d in delays if d is not None]
    new = sum(b is None for b in before_delays)
    worst_before = max(x for x in before_delays if x is not None)
    print(f"stopped {len(stopped)} of {len(delays)} (that either rule stops); delay from the change: max "
          f"{max(stopped):.2f} s, median {sorted(stopped)[len(stopped) // 2]:.2f} s; later than 2 s or not stopped: "
          f"{late_or_missed}; {new} the rules before did not stop at all (before: max {worst_before:.2f} s, "
          f"later than 2 s or not stopped {sum(x is None or x > 2.0 for x in before_delays)}); load average "
          f"{os.getloadavg()[0]:.1f}")

    runs = good_runs(args)
    if args.foreign_seeds:
        runs += foreign_runs(args.foreign_seeds)
    good = false_now = false_before = good_changed = 0
    changed = []
    looser = {name: [] for name in LOOSER_TONE}
    for label, s in runs:
        result = Simulation(s, validate=False).run()
        verdict = result.summary()["tracking_verdict"]["verdict"]
        now, before = judged_twice(s, result.samples)
        if verdict in ("followed", "outside_target"):
            good += 1
            false_now += now is not None
            false_before += before is not None
            good_changed += describe(now) != describe(before)
            if now is not None or before is not None:
                print(f"  a good run stopped: {label} ({verdict}): {describe(now)}, before {describe(before)}")
            for name, trip in judged_looser(s, result.samples).items():
                if describe(trip) != describe(now):
                    looser[name].append(f"{label}: {describe(trip)}")
        if describe(now) != describe(before):
            changed.append(f"  {label} ({verdict}): {describe(now)}, before {describe(before)}")
    print(f"runs without a change mid-test: {len(runs)}; good runs (followed or outside the target): {good}; "
          f"false trips among them: {false_now} (before: {false_before})")
    print(f"runs whose first trip changed: {len(changed)}, of them good runs: {good_changed}")
    print("\n".join(changed))
    for name, runs_changed in looser.items():
        print(f"good runs whose first trip would change with {name} (the tone rule's margin): {len(runs_changed)}"
              + "".join(f"\n  {x}" for x in runs_changed))
    return 0 if late_or_missed == 0 and good_changed == 0 else 1


def campaign_of(args):
    """The campaign (--campaign, or the one docs/compare.md shows), with --runs plants."""
    from sim.campaign import load_campaign

    if args.campaign:
        campaign = load_campaign(args.campaign)
    else:
        with tempfile.TemporaryDirectory() as folder:
            path = Path(folder) / "lab_spread.toml"
            path.write_text(documented_campaign())
            campaign = load_campaign(path)
    campaign.runs = args.runs
    return campaign


def campaign_scenarios(campaign) -> list:
    """Every run of the campaign as a scenario."""
    return [point.scenario(campaign.cycles) for point in campaign.points()]


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--runs", type=int, default=100, help="plants drawn (each run with every controller)")
    p.add_argument("--rounds", type=int, default=2, help="passes of each kind, alternated (the best is shown)")
    p.add_argument("--reference", action="store_true", help="also time the per-block numpy path (before)")
    p.add_argument("--campaign", help="a campaign file (default: the one docs/compare.md shows)")
    p.add_argument("--oscillations", action="store_true", help="the follow detector's delays and false trips")
    p.add_argument("--foreign-seeds", type=int, nargs="*", default=[], help="with --oscillations: foreign rigs")
    args = p.parse_args(argv)
    if args.oscillations:
        return oscillations(args)

    from sim.engine import Simulation, run_judged, warm_up
    from sim.safety import default_limits

    campaign = campaign_of(args)
    scenarios = campaign_scenarios(campaign)
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
