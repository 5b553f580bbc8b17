"""`isorig bench`: the engine against scipy's solve_ivp on the paper scenario."""

from __future__ import annotations

import json
import sys


def register(sub) -> None:
    p = sub.add_parser("bench", help="engine vs scipy solve_ivp on the paper scenario (IUT_a, 100 bar, 1 Hz, 30 s)")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.add_argument("--duration-s", type=float, default=None, help="shorten the 30 s scenario (for quick checks)")
    p.set_defaults(func=run)


def run(args) -> int:
    from sim.bench import bench

    res = bench(duration_s=args.duration_s, progress=None if args.json else lambda m: print(m, file=sys.stderr))
    if args.json:
        print(json.dumps({k: res[k] for k in ("engine_rtf", "engine_cpu_rtf", "solve_ivp_rtf", "speedup",
                                             "max_abs_dy_m")}))
    else:
        print(f"scenario: {res['scenario']}")
        print(f"engine (numba RK4, 0.2 ms): {res['engine_rtf']:8.1f} x real time "
              f"({res['engine_cpu_rtf']:.1f} x per CPU second of this process)")
        print(f"solve_ivp (LSODA, rtol 1e-6): {res['solve_ivp_rtf']:6.2f} x real time")
        print(f"speed-up: {res['speedup']:.1f} x;  "
              f"largest |y_engine - y_solve_ivp|: {res['max_abs_dy_m'] * 1e6:.3f} um")
    return 0
