"""A lab's rig is not isorig's default rig (issue 20): the default servo on plants drawn from the range labs have,
told each plant exactly, and told it as an identification would leave it.

Plant range (any combination, drawn uniformly; the bulk modulus log-uniformly): mass 800-4000 kg, bulk modulus
3e8-1.6e9 Pa, oil volume per side +-50 %, valve flow gain +-30 %, valve natural frequency 40-150 Hz, dead zone
0-1.2 V, friction (mu and F_c) +-50 %, position latency 0-2 ms; the rest is sim.rig.DEFAULT_RIG.
Tests: 20 mm at 0.5 Hz and 2 mm at 1 Hz, 10 cycles with 1 taper cycle; the figure is the RMS of |y - r| over the
last two full cycles over the amplitude. Targets: 0.1 % and 0.5 %.
Declared exactly: the rig file says the plant (``rig = DEFAULT_RIG.with_changes(**plant)``). With errors: mass,
bulk modulus, valve frequency and damping +-10 %, latency +-0.2 ms, dead zone +-0.05 V, flow gain +-5 % (uniform;
``--errors plus`` or ``minus``: all at one end, ``plus`` declaring the column stiffer and the valve faster).

Run: .venv/bin/python scripts/unknown_plants.py [--plants 100] [--seed 1] [--isolator IUT_a --supply-bar 100]
     [--errors random|plus|minus|none] [--option NAME=VALUE ...] [--processes 2]
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from sim.engine import Scenario, Simulation  # noqa: E402
from sim.rig import DEFAULT_RIG  # noqa: E402

TESTS = ((0.02, 0.5, 0.1), (0.002, 1.0, 0.5))  # amplitude m, frequency Hz, target % (issue 20)
CYCLES = 10


def draw_plant(rng: np.random.Generator) -> dict:
    """One plant from the range labs have (rig parameter name -> value)."""
    r = DEFAULT_RIG
    return dict(mass_kg=rng.uniform(800, 4000),
                bulk_modulus_pa=math.exp(rng.uniform(math.log(3e8), math.log(1.6e9))),
                half_volume_m3=r.half_volume_m3 * rng.uniform(0.5, 1.5),
                flow_gain_m3_per_s_v_sqrt_pa=r.flow_gain_m3_per_s_v_sqrt_pa * rng.uniform(0.7, 1.3),
                valve_natural_frequency_rad_s=2 * math.pi * rng.uniform(40, 150),
                dead_zone_v=rng.uniform(0, 1.2),
                friction_coefficient=r.friction_coefficient * rng.uniform(0.5, 1.5),
                coulomb_force_n=r.coulomb_force_n * rng.uniform(0.5, 1.5),
                position_latency_s=rng.uniform(0, 2e-3))


def declared_with_errors(plant: dict, u) -> dict:
    """What an identification leaves: ``u()`` in [-1, 1] per value (+1: the column declared stiffer, the valve
    faster and less damped, less latency, more dead zone and flow gain)."""
    d = dict(plant)
    d["mass_kg"] = plant["mass_kg"] * (1 - 0.1 * u())
    d["bulk_modulus_pa"] = plant["bulk_modulus_pa"] * (1 + 0.1 * u())
    d["valve_natural_frequency_rad_s"] = plant["valve_natural_frequency_rad_s"] * (1 + 0.1 * u())
    d["valve_damping_ratio"] = DEFAULT_RIG.valve_damping_ratio * (1 - 0.1 * u())
    d["position_latency_s"] = max(0.0, plant["position_latency_s"] - 0.2e-3 * u())
    d["dead_zone_v"] = max(0.0, plant["dead_zone_v"] + 0.05 * u())
    d["flow_gain_m3_per_s_v_sqrt_pa"] = plant["flow_gain_m3_per_s_v_sqrt_pa"] * (1 + 0.05 * u())
    return d


def oil_column_hz(rig) -> float:
    return math.sqrt(2 * rig.bulk_modulus_pa * rig.piston_area_m2 ** 2 / (rig.half_volume_m3 * rig.mass_kg)) \
        / (2 * math.pi)


def figure(plant: dict, declared: dict, amplitude_m: float, frequency_hz: float, isolator: str, supply_bar: float,
           options: dict) -> float:
    """The last two full cycles' RMS |y - r| over the amplitude, %."""
    s = Scenario.sine(isolator, supply_bar, amplitude_m, frequency_hz, CYCLES, rig=DEFAULT_RIG.with_changes(**declared),
                      plant_changes=plant, controller_options=options)
    return Simulation(s, validate=False).run().summary()["last_two_cycles"]["rms_y_minus_r_over_amplitude"] * 100


def run_plant(job: tuple) -> list[float]:
    plant, declared, isolator, supply_bar, options = job
    out = []
    for rig in (plant, declared):
        if rig is None:
            out += [float("nan")] * len(TESTS)
            continue
        out += [figure(plant, rig, a, f, isolator, supply_bar, options) for a, f, _ in TESTS]
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--plants", type=int, default=100)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--isolator", default="IUT_a")
    ap.add_argument("--supply-bar", type=float, default=100.0)
    ap.add_argument("--errors", choices=("random", "plus", "minus", "none"), default="random")
    ap.add_argument("--option", action="append", default=[], metavar="NAME=VALUE", help="a servo option")
    ap.add_argument("--processes", type=int, default=2)
    args = ap.parse_args()
    options = {k: float(v) for k, v in (o.split("=", 1) for o in args.option)}
    rng = np.random.default_rng(args.seed)
    plants = [draw_plant(rng) for _ in range(args.plants)]
    err = np.random.default_rng(args.seed + 1)
    if args.errors == "random":
        declared = [declared_with_errors(p, lambda: err.uniform(-1, 1)) for p in plants]
    elif args.errors == "none":
        declared = [None] * len(plants)
    else:
        sign = 1.0 if args.errors == "plus" else -1.0
        declared = [declared_with_errors(p, lambda: sign) for p in plants]
    jobs = [(p, d, args.isolator, args.supply_bar, options) for p, d in zip(plants, declared, strict=True)]
    t0 = time.perf_counter()
    if args.processes > 1:
        with ProcessPoolExecutor(max_workers=args.processes) as pool:
            rows = list(pool.map(run_plant, jobs, chunksize=4))
    else:
        rows = [run_plant(j) for j in jobs]
    heads = [f"{a * 1e3:g} mm {f:g} Hz" for a, f, _ in TESTS]
    print(f"{args.isolator} {args.supply_bar:g} bar, {args.plants} plants (seed {args.seed}), declared with errors: "
          f"{args.errors}; options: {options or 'default'}")
    columns = [f"exact {h}" for h in heads] + [f"errors {h}" for h in heads]
    print(f"{'#':>3} {'m kg':>6} {'f_h Hz':>6} {'f_v Hz':>6} {'DZ V':>5} {'L ms':>5} "
          + " ".join(f"{c:>20}" for c in columns))
    for i, (p, row) in enumerate(zip(plants, rows, strict=True)):
        rig = DEFAULT_RIG.with_changes(**p)
        print(f"{i:>3} {p['mass_kg']:>6.0f} {oil_column_hz(rig):>6.1f} "
              f"{p['valve_natural_frequency_rad_s'] / (2 * math.pi):>6.1f} {p['dead_zone_v']:>5.2f} "
              f"{p['position_latency_s'] * 1e3:>5.2f} " + " ".join(f"{v:>19.3f}%" for v in row))
    table = np.array(rows)
    print()
    print(f"{'':>34} " + " ".join(f"{c:>20}" for c in columns))
    statistics = (("worst", np.max), ("99th percentile", lambda x: np.percentile(x, 99)),
                  ("95th percentile", lambda x: np.percentile(x, 95)),
                  ("90th percentile", lambda x: np.percentile(x, 90)), ("median", np.median))
    for name, fn in statistics:
        print(f"{name:>34} " + " ".join(f"{fn(table[:, j]):>19.3f}%" if np.isfinite(table[:, j]).all()
                                        else f"{'-':>20}" for j in range(table.shape[1])))
    targets = [t for _, _, t in TESTS] * 2
    print(f"{'over target':>34} " + " ".join(f"{int(np.sum(table[:, j] > targets[j])):>20d}"
                                             for j in range(table.shape[1])))
    worst = [int(np.nanargmax(table[:, j])) if np.isfinite(table[:, j]).any() else -1 for j in range(table.shape[1])]
    print(f"{'worst plant #':>34} " + " ".join(f"{w:>20d}" for w in worst))
    print(f"targets: 20 mm 0.5 Hz <= 0.1 %, 2 mm 1 Hz <= 0.5 %; {time.perf_counter() - t0:.0f} s")


if __name__ == "__main__":
    main()
