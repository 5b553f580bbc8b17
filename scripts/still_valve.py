"""A still target gets a still valve (issue 32, item 4): the valve command where the target barely moves, and the
tracking figures that must not get worse.

Quiet figure: over every 1 s window (sliding by 50 ms) in which the target moves less than 0.5 mm (its range),
the standard deviation of the valve command; the worst such window is printed (target: <= 0.2 V), with where it
is and how many quiet windows there were. Measured on
  (a) a hybrid test's quiet end: `isorig hybrid --structure docs/examples/structure_3_storey.json --ground-motion
      near_field_short [--scale S]` on the default simulated rig, through the service's worker as the command runs
      it (isorig.commands.hybrid._simulated), the building ringing down before the table's rest;
  (b) a sine test's end: 2 mm at 1 Hz and 20 mm at 0.5 Hz (12 cycles, taper 1), run on for HOLD_S with the target
      at rest (the loop's target holds past its end);
  (c) a manual move's end (sim.motion.move_target: 10 mm at 5 mm/s and 1 mm at 1 mm/s), its hold lengthened to
      HOLD_S.
Hybrid: also the quiet end's RMS |y - r|, and the J2 the run would have with the table holding the target's centred
1 s mean in its quiet end (a still valve cannot follow swings that reverse within its dead zone: the least a still
quiet end costs).
Tracking: 20 mm 0.5 Hz (<= 0.1 %), 2 mm 1 Hz (<= 0.5 %), 0.5 mm 1 Hz (<= 1 %), 12 cycles with 1 taper cycle: the
RMS of |y - r| over the last two full cycles over the amplitude, %; and for 0.5 mm the dead-zone crossings of the
command per cycle over the last two cycles (2: one per reversal; more: the valve rings at the reversals). On the
default rig and on drawn rigs (scripts/unknown_plants.py's range, seed 1, told each rig exactly).

Run: .venv/bin/python scripts/still_valve.py [--plants 0,1,2,3,77,88] [--processes 2] [--option NAME=VALUE ...]
"""

from __future__ import annotations

import argparse
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
# appended, not first: scripts/foreign_rigs.py would hide the foreign_rigs package from a process that imports this
# module (tests/test_still_valve_hybrid.py), and foreign_campaign's ``from foreign_rigs import draw_rig`` with it
sys.path.append(str(ROOT / "scripts"))

from sim.engine import Scenario, Simulation  # noqa: E402
from sim.loop import CONTROL_PERIOD_S  # noqa: E402
from sim.rig import DEFAULT_RIG  # noqa: E402
from sim.samples import Samples  # noqa: E402
from sim.tracking import tracking_summary  # noqa: E402

QUIET_RANGE_M = 0.5e-3  # a window in which the target moves less than this is "still"
WINDOW_S = 1.0
STEP_S = 0.05
TARGET_STD_V = 0.2
HOLD_S = 3.0  # how long a sine's end and a move's end are held in (b) and (c)
TRACKING = ((0.02, 0.5, 0.1), (0.002, 1.0, 0.5), (0.0005, 1.0, 1.0))  # amplitude m, frequency Hz, target %
CYCLES = 12
STRUCTURE = ROOT / "docs" / "examples" / "structure_3_storey.json"


def quiet_windows(target_m: np.ndarray, command_v: np.ndarray, dt: float = CONTROL_PERIOD_S) -> dict:
    """The worst command std (V) over the 1 s windows in which the target's range is below QUIET_RANGE_M (``std_v``,
    where it starts ``at_s``, how many ``windows``), and over those of them that follow a second as still
    (``settled_std_v``: the target was still for the second before too, so the window holds no motion a controller
    had to follow a moment before)."""
    n = int(round(WINDOW_S / dt))
    step = int(round(STEP_S / dt))
    worst, where, count, settled = 0.0, float("nan"), 0, 0.0
    for i0 in range(0, max(len(target_m) - n, 0) + 1, step):
        r = target_m[i0:i0 + n]
        if not np.all(np.isfinite(r)) or np.ptp(r) >= QUIET_RANGE_M:
            continue
        count += 1
        sd = float(np.std(command_v[i0:i0 + n]))
        if sd > worst:
            worst, where = sd, i0 * dt
        before = target_m[max(i0 - n, 0):i0 + n]
        if i0 >= n and np.all(np.isfinite(before)) and np.ptp(before) < QUIET_RANGE_M:
            settled = max(settled, sd)
    return {"std_v": worst, "at_s": where, "windows": count, "settled_std_v": settled}


def quiet_mask(target_m: np.ndarray, dt: float = CONTROL_PERIOD_S) -> np.ndarray:
    """True at the samples that lie in a quiet window (quiet_windows: a 1 s window in which the target's range is
    below QUIET_RANGE_M)."""
    n = int(round(WINDOW_S / dt))
    step = int(round(STEP_S / dt))
    quiet = np.zeros(len(target_m), dtype=bool)
    for i0 in range(0, max(len(target_m) - n, 0) + 1, step):
        r = target_m[i0:i0 + n]
        if np.all(np.isfinite(r)) and np.ptp(r) < QUIET_RANGE_M:
            quiet[i0:i0 + n] = True
    return quiet


def hybrid_case(scale: float, ground_motion: str = "near_field_short", options: dict | None = None) -> dict:
    """(a) `isorig hybrid` on the simulated rig, as the command builds and runs it."""
    from isorig.commands.hybrid import _simulated
    from sim.ground_motion import synthetic_ground_motion
    from sim.hybrid import ground_at_periods, predicted_history, reference
    from sim.isolator import load_isolator
    from sim.structure import load_structure

    building = load_structure(str(STRUCTURE))
    t, acc, _info = synthetic_ground_motion(ground_motion)
    ag = ground_at_periods(t, scale * acc)
    isolator = load_isolator("IUT_a")
    ref = reference(building, isolator, ag)
    scenario = Scenario(isolator, 100e5, [], "servo", vertical_load_n=building.total_mass_kg * 9.80665,
                        history=predicted_history(ref), controller_options=dict(options or {}))
    scenario.validate()
    sub, s, stopped, status = _simulated(building, ag, scenario)
    res = sub.results(s)
    q = quiet_windows(s["target_m"], s["voltage_v"])
    # the quiet end: the windows after the target's largest displacement (a ground motion's start is quiet too)
    peak = int(np.argmax(np.abs(s["target_m"])))
    end = quiet_windows(s["target_m"][peak:], s["voltage_v"][peak:])
    # how far the table is from the target there (a still valve holds the swings' centre: about their half-size)
    quiet_end = np.zeros(len(s["target_m"]), dtype=bool)
    quiet_end[peak:] = quiet_mask(s["target_m"][peak:])
    error = s["displacement_m"] - s["target_m"]
    end_rms_um = 1e6 * float(np.sqrt(np.mean(error[quiet_end] ** 2))) if quiet_end.any() else float("nan")
    # what J2 would be if the table tracked as in this run where the target moves and, in the quiet end, held the
    # target's centred 1 s mean (the centre of its swings) with a still valve: no reversal followed there
    n = int(round(WINDOW_S / CONTROL_PERIOD_S))
    centre = np.convolve(s["target_m"], np.ones(n) / n, mode="same")
    held = np.where(quiet_end, centre - s["target_m"], error)
    j2_held = 100.0 * float(np.sqrt(np.sum(held ** 2) / np.sum(s["target_m"] ** 2)))
    return {**q, "end_std_v": end["std_v"], "end_settled_std_v": end["settled_std_v"], "status": status,
            "end_rms_error_um": end_rms_um, "j2_centre_held_pct": j2_held,
            "j2_pct": res["criteria"]["j2_rms_percent"], "j3_pct": res["criteria"]["j3_peak_percent"],
            "peak_error_um": 1e6 * float(np.max(np.abs(s["displacement_m"] - s["target_m"])))}


def sine_run(amplitude_m, frequency_hz, plant=None, options=None, hold_s=0.0):
    rig = DEFAULT_RIG.with_changes(**plant) if plant else DEFAULT_RIG
    sc = Scenario.sine("IUT_a", 100.0, amplitude_m, frequency_hz, CYCLES, rig=rig, plant_changes=dict(plant or {}),
                       controller_options=dict(options or {}))
    sim = Simulation(sc, validate=False)
    main = sim.advance(sim.total_periods)
    figure = tracking_summary(main, sc)["last_two_cycles"]["rms_y_minus_r_over_amplitude"] * 100
    s = main
    if hold_s > 0:
        sim.loop.total_periods += int(round(hold_s / CONTROL_PERIOD_S))  # the target rests at its end value
        s = Samples.concatenate([main, sim.advance(sim.loop.total_periods - sim.period)])
    return sc, main, s, figure


def crossings_per_cycle(samples, frequency_hz, dead_zone_v, cycles=2) -> float:
    """Sign changes of the command beyond 0.6 of the dead zone over the last ``cycles`` cycles, per cycle."""
    n = int(round(cycles / frequency_hz / CONTROL_PERIOD_S))
    u = samples["voltage_v"][-n:]
    u = u[np.abs(u) > 0.6 * dead_zone_v]
    return float(np.count_nonzero(np.diff(np.sign(u)) != 0)) / cycles


def move_case(distance_m, speed_m_per_s, plant=None, options=None) -> dict:
    from sim.motion import move_target

    rig = DEFAULT_RIG.with_changes(**plant) if plant else DEFAULT_RIG
    sc = Scenario.sine("IUT_a", 100.0, 0.001, 1.0, 1, rig=rig, plant_changes=dict(plant or {}),
                       controller_options=dict(options or {}))
    sc.profile = []
    sc.history = move_target(0.0, distance_m, speed_m_per_s)
    sim = Simulation(sc, validate=False)
    sim.loop.total_periods += int(round((HOLD_S - 0.5) / CONTROL_PERIOD_S))  # the last row holds
    s = sim.advance(sim.loop.total_periods)
    q = quiet_windows(s["target_m"], s["voltage_v"])
    return {**q, "final_error_um": 1e6 * abs(float(s["displacement_m"][-1] - s["target_m"][-1]))}


def rig_row(job) -> dict:
    """Everything but the hybrid test on one rig (plant None: the default rig)."""
    name, plant, options = job
    out = {"rig": name}
    for a, f, _t in TRACKING:
        sc, main, s, figure = sine_run(a, f, plant, options, hold_s=HOLD_S)
        out[f"track {a * 1e3:g}mm"] = figure
        if a == 0.0005:
            dz = (plant or {}).get("dead_zone_v", DEFAULT_RIG.dead_zone_v)
            out["0.5mm crossings/cycle"] = crossings_per_cycle(main, f, max(dz, 0.05))
        q = quiet_windows(s["target_m"], s["voltage_v"])
        out[f"{a * 1e3:g}mm end std"] = q["std_v"]
        out[f"{a * 1e3:g}mm end settled"] = q["settled_std_v"]
    for d, v in ((0.01, 0.005), (0.001, 0.001)):
        q = move_case(d, v, plant, options)
        out[f"move {d * 1e3:g}mm end std"] = q["std_v"]
        out[f"move {d * 1e3:g}mm settled"] = q["settled_std_v"]
        out[f"move {d * 1e3:g}mm final err um"] = q["final_error_um"]
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--plants", default="0,1,2,3,77,88", help="drawn rigs (unknown_plants.py seed 1) by number")
    ap.add_argument("--processes", type=int, default=2)
    ap.add_argument("--option", action="append", default=[], metavar="NAME=VALUE", help="a servo option")
    ap.add_argument("--no-hybrid", action="store_true")
    args = ap.parse_args()
    options = {k: float(v) for k, v in (o.split("=", 1) for o in args.option)}
    from unknown_plants import draw_plant

    rng = np.random.default_rng(1)
    drawn = [draw_plant(rng) for _ in range(100)]
    wanted = [int(i) for i in args.plants.split(",") if i.strip()]
    t0 = time.perf_counter()
    if not args.no_hybrid:
        print("(a) hybrid quiet end: structure_3_storey, IUT_a 100 bar, default simulated rig")
        for gm, scale in (("near_field_short", 1.0), ("near_field_short", 0.6), ("far_field_long", 0.6)):
            h = hybrid_case(scale, gm, options)
            print(f"  {gm} x{scale:g}: worst quiet-window command std {h['std_v']:.3f} V at {h['at_s']:.2f} s "
                  f"({h['windows']} windows; after a still second {h['settled_std_v']:.3f} V); after the peak "
                  f"{h['end_std_v']:.3f} V (after a still second {h['end_settled_std_v']:.3f} V), RMS |y - r| there "
                  f"{h['end_rms_error_um']:.0f} um; {h['status']}, "
                  f"J2 {h['j2_pct']:.2f} % (quiet end held at its centre: {h['j2_centre_held_pct']:.2f} %), "
                  f"J3 {h['j3_pct']:.2f} %, "
                  f"peak |y - r| {h['peak_error_um']:.0f} um")
    jobs = [("default", None, options)] + [(f"#{i}", drawn[i], options) for i in wanted]
    if args.processes > 1:
        with ProcessPoolExecutor(max_workers=args.processes) as pool:
            rows = list(pool.map(rig_row, jobs))
    else:
        rows = [rig_row(j) for j in jobs]
    keys = [k for k in rows[0] if k != "rig"]
    print("(b) a sine's end, held 3 s, (c) a manual move's end, held 3 s: worst quiet-window command std, V (target "
          "<= 0.2; 'settled': windows after a still second); tracking, % of amplitude (20 mm <= 0.1, 2 mm <= 0.5, "
          "0.5 mm <= 1); 0.5 mm: dead-zone crossings per cycle (2: one per reversal)")
    width = max(len(k) for k in keys) + 1
    print(f"{'rig':>{width}} " + " ".join(f"{r['rig']:>8}" for r in rows))
    for k in keys:
        print(f"{k:>{width}} " + " ".join(f"{r[k]:>8.3f}" for r in rows))
    print(f"options: {options or 'default'}; {time.perf_counter() - t0:.0f} s")


if __name__ == "__main__":
    main()
