"""One rig commissioned several times: does it get one verdict, and do its values agree within their stated
uncertainty? (issue 32 item 3: "the same rig commissioned 5 times gives one verdict and values within their stated
uncertainty").

    .venv/bin/python scripts/foreign_repeat.py --rigs 40 [--seed 0] [--repeats 5] [--workers 2] [--json F]

Each repeat is the first attempt on the same drawn rig (foreign_rigs.draw_rig) with another realisation of its
sensors' noise (the rig's noise seed), as a lab that runs `isorig identify rig` again on the same rig gets: the
physics, the excitation's plan and the bounds are the same, the readings' noise is not. For each rig: how many
repeats were trusted, and for the values the controller relies on (foreign_campaign.judged_values), the largest
difference between two trusted repeats in units of their combined stated sigma (sqrt(s_i^2 + s_j^2)), and any
value trusted outside 3 sigma of its truth. Prints the rigs whose verdict changed and the worst spreads.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from itertools import combinations
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

#: the noise seed of repeat k of rig s: s itself for k = 0 (the campaign's record), else one far from any rig's
NOISE_SEED_STEP = 1_000_003


def repeat_row(seed: int, repeats: int) -> dict:
    """Rig ``seed`` commissioned ``repeats`` times, each with its own sensor noise."""
    import numpy as np

    from sim.commission import foreign_campaign as fc

    np.seterr(all="ignore")
    started = time.perf_counter()
    runs = []
    for k in range(repeats):
        spec, declared, ident = fc.first_attempt(seed, noise_seed=seed + k * NOISE_SEED_STEP)
        run = {"trusted": ident.trusted, "problems": list(ident.problems)}
        if ident.fit is not None:
            values = fc.judged_values(ident, spec, declared)
            run["values"] = {name: list(v) for name, v in values.items()}
            run["wrong"] = fc.wrong_values(values) if ident.trusted else []
        runs.append(run)
    trusted = [r for r in runs if r["trusted"]]
    spread = {}
    for a, b in combinations(trusted, 2):
        for name, (va, sa, _truth) in a["values"].items():
            if name not in b["values"]:
                continue
            vb, sb, _ = b["values"][name]
            z = abs(va - vb) / math.hypot(sa, sb) if math.hypot(sa, sb) > 0 else math.inf
            spread[name] = max(spread.get(name, 0.0), z)
    return {"seed": seed, "rig": spec.name, "repeats": repeats, "trusted": len(trusted),
            "runs": runs, "spread_sigmas": spread, "wrong": sorted({w for r in trusted for w in r["wrong"]}),
            "seconds": round(time.perf_counter() - started, 1)}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rigs", type=int, default=40, help="how many rigs (default 40)")
    parser.add_argument("--seed", type=int, default=0, help="the first rig's seed (default 0)")
    parser.add_argument("--repeats", type=int, default=5, help="commissionings of each rig (default 5)")
    parser.add_argument("--workers", type=int, default=2, help="processes (default 2)")
    parser.add_argument("--json", help="write every row to this file")
    args = parser.parse_args(argv)
    if args.rigs < 1 or args.repeats < 2 or args.workers < 1:
        parser.error("--rigs >= 1, --repeats >= 2, --workers >= 1")
    seeds = list(range(args.seed, args.seed + args.rigs))
    started = time.perf_counter()
    rows = []
    with ProcessPoolExecutor(args.workers) as pool:
        for row in pool.map(repeat_row, seeds, [args.repeats] * len(seeds)):
            rows.append(row)
            print(f"  rig {row['seed']}: trusted {row['trusted']} of {row['repeats']}"
                  + (f", wrong {row['wrong']}" if row["wrong"] else "")
                  + (f", largest spread {max(row['spread_sigmas'].values()):.2f} sigma"
                     if row["spread_sigmas"] else ""), file=sys.stderr, flush=True)
    if args.json:
        Path(args.json).write_text(json.dumps(rows, indent=1))
    mixed = [r for r in rows if 0 < r["trusted"] < r["repeats"]]
    always = [r for r in rows if r["trusted"] == r["repeats"]]
    never = [r for r in rows if r["trusted"] == 0]
    print(f"{len(rows)} rigs, each commissioned {args.repeats} times with its own sensor noise "
          f"({time.perf_counter() - started:.0f} s)")
    print(f"  one verdict: {len(always) + len(never)} ({len(always)} always trusted, {len(never)} always refused); "
          f"verdict changed: {len(mixed)}" + (" (" + ", ".join(f"rig {r['seed']} {r['trusted']}/{r['repeats']}"
                                                               for r in mixed) + ")" if mixed else ""))
    for r in mixed:
        reasons = sorted({p.split(";")[0][:90] for run in r["runs"] if not run["trusted"] for p in run["problems"]})
        print(f"    rig {r['seed']} refused for: " + " | ".join(reasons))
    wrong = [r for r in rows if r["wrong"]]
    print(f"  trusted with a value outside 3 sigma of its truth: {len(wrong)}"
          + (" (" + ", ".join(f"rig {r['seed']}: {r['wrong']}" for r in wrong) + ")" if wrong else ""))
    spreads = sorted(((z, name, r["seed"]) for r in rows for name, z in r["spread_sigmas"].items()), reverse=True)
    beyond = [s for s in spreads if s[0] > 3.0]
    print(f"  pairs of trusted repeats whose values differ by more than 3 combined sigmas: {len(beyond)} "
          f"(of the values of {sum(1 for r in rows if r['trusted'] >= 2)} rigs trusted at least twice)")
    for z, name, seed in spreads[:8]:
        print(f"    rig {seed} {name}: {z:.2f} sigma")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
