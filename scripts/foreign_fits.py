"""The commissioning fit alone on foreign rigs: how well each balance explains a foreign rig's record, how close
each value the controller relies on comes to the rig's physics, and why each fit was refused.

    .venv/bin/python scripts/foreign_fits.py --rigs 40 [--seed 0] [--workers 2] [--json rows.json]
        [--second-attempt]

For each rig (foreign_rigs.draw_rig): the excitation at the default bounds from what its lab knows, then
sim.commission.identify. No test is run (that is `isorig compare --foreign-rigs`): this is the fit's own
edit-measure loop, about 5 s a rig. With --second-attempt a refused rig whose refusal suggests other bounds is
commissioned once more with them (as `isorig compare` and an operator do) and that attempt is the one judged.
Prints the medians of the balances' R^2 and of the replay's error, the count of each refusal reason, and each
value's error in sigmas of its stated uncertainty.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from collections import Counter
from concurrent.futures import ProcessPoolExecutor
from functools import partial
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

def fit_row(seed: int, second_attempt: bool = False) -> dict:
    """One rig: the excitation, the fit, the values against the truth; with ``second_attempt``, the second
    attempt's where the first was refused and suggested one (``first_trusted`` and ``attempts`` say which)."""
    import numpy as np

    from sim.commission import foreign_campaign as fc

    np.seterr(all="ignore")
    started = time.perf_counter()
    if second_attempt:
        lab = fc.commission_as_a_lab(fc.ForeignRun(seed))
        spec, declared, ident = lab.spec, lab.declared, lab.last
        extra = {"first_trusted": lab.first.trusted, "attempts": lab.attempts,
                 "max_velocity_m_per_s": lab.max_velocity_m_per_s}
    else:
        spec, declared, ident = fc.first_attempt(seed)
        extra = {"first_trusted": ident.trusted, "attempts": 1}
    row = {"seed": seed, "rig": spec.name, "trusted": ident.trusted, "problems": ident.problems,
           "seconds": round(time.perf_counter() - started, 1), **extra}
    if ident.fit is not None:
        values = fc.judged_values(ident, spec, declared)
        row.update(flow_r2=ident.fit.flow_r2, force_r2=ident.fit.force_r2,
                   values={k: list(v) for k, v in values.items()}, wrong=fc.wrong_values(values),
                   presliding_m=getattr(ident.fit.estimates.get("presliding_m"), "value", None),
                   estimates={k: [e.value, e.std] for k, e in ident.fit.estimates.items()},
                   noise_shift=ident.fit.noise_shift, disagreement=ident.fit.disagreement)
    if ident.response is not None:
        row["replay_error"] = ident.response.velocity_nrmse
    return row


def reason_counts(rows: list[dict]) -> Counter:
    """How many rigs gave each refusal reason, by the campaign's categories (foreign_campaign.problem_categories)."""
    from sim.commission.foreign_campaign import problem_categories

    counts = Counter()
    for row in rows:
        counts.update(set().union(*(problem_categories(p) for p in row["problems"])) if row["problems"] else set())
    return counts


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rigs", type=int, default=40)
    parser.add_argument("--seed", type=int, default=0, help="the first rig's seed")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--json", help="write every row to this file")
    parser.add_argument("--second-attempt", action="store_true",
                        help="commission a refused rig once more at the bounds its refusal suggests, and judge that")
    args = parser.parse_args(argv)
    import numpy as np

    seeds = range(args.seed, args.seed + args.rigs)
    started = time.perf_counter()
    with ProcessPoolExecutor(args.workers) as pool:
        rows = list(pool.map(partial(fit_row, second_attempt=args.second_attempt), seeds))
    if args.json:
        Path(args.json).write_text(json.dumps(rows, indent=1))
    fitted = [r for r in rows if "flow_r2" in r]
    trusted = [r for r in rows if r["trusted"]]
    print(f"{len(rows)} foreign rigs (seeds {seeds.start}-{seeds.stop - 1}), {time.perf_counter() - started:.0f} s")
    print(f"trusted: {len(trusted)} ({sum(1 for r in rows if r['first_trusted'])} at the first attempt); "
          f"trusted with a value outside 3 sigma of its truth: {sum(1 for r in trusted if r['wrong'])} "
          f"(seeds {[r['seed'] for r in trusted if r['wrong']]})")
    for key, label in (("flow_r2", "flow balance R^2"), ("force_r2", "force balance R^2"),
                       ("replay_error", "replay's velocity error")):
        values = [r[key] for r in fitted if key in r and math.isfinite(r[key])]
        if values:
            print(f"{label}: median {np.median(values):.4g}, 10 % {np.percentile(values, 10):.4g}, "
                  f"90 % {np.percentile(values, 90):.4g}")
    print("refusals:", ", ".join(f"{label} {n}" for label, n in reason_counts(rows).most_common()))
    names = sorted({k for r in fitted for k in r["values"]})
    for name in names:
        sigmas = [abs(v[0] - v[2]) / v[1] for r in fitted if name in r["values"]
                  for v in [r["values"][name]] if v[1] > 0 and math.isfinite(v[0])]
        within = sum(1 for s in sigmas if s <= 3)
        line = f"  {name}: within 3 sigma of its truth {within}/{len(sigmas)}"
        if not name.endswith("_v"):  # a dead zone or a null's error is in volts, not a share
            errors = [abs(v[0] / v[2] - 1) for r in fitted if name in r["values"]
                      for v in [r["values"][name]] if v[2] and math.isfinite(v[0])]
            line += f", error median {100 * np.median(errors):.1f} %"
        print(line)
    return 0


if __name__ == "__main__":
    sys.exit(main())
