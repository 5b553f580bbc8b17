"""The foreign rig family over many rigs, kept as it goes: each rig's row is appended to a JSON-lines file the
moment it is done, so a long campaign (hundreds of rigs, an hour or more on 2 cores) loses nothing when it is
stopped, and is continued by running the same command again (rigs already in the file are skipped).

    .venv/bin/python scripts/foreign_rigs.py --rigs 300 [--seed 0] [--processes 2] --rows rows.jsonl
        [--figure F.png] [--markdown]

The rows and figures are those of ``isorig compare --foreign-rigs N`` (sim.commission.foreign_campaign): the same
``commission_and_test`` per rig, the same ``summary`` (printed as JSON) and tables.
"""

from __future__ import annotations

import argparse
import json
import multiprocessing
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from sim.commission import foreign_campaign as fc  # noqa: E402


def one(seed: int) -> dict:
    return fc.commission_and_test(fc.ForeignRun(seed))


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--rigs", type=int, required=True)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--processes", type=int, default=2)
    parser.add_argument("--rows", required=True, help="the JSON-lines file the rows go to (appended)")
    parser.add_argument("--figure", default=None)
    parser.add_argument("--markdown", action="store_true")
    parser.add_argument("--report-only", action="store_true", help="only summarise the rows already in the file")
    args = parser.parse_args()
    path = Path(args.rows)
    done = {}
    if path.exists():
        for line in path.read_text().splitlines():
            if line.strip():
                row = json.loads(line)
                done[row["seed"]] = row
    seeds = [s for s in range(args.seed, args.seed + args.rigs) if s not in done]
    if seeds and not args.report_only:
        t0 = time.perf_counter()
        print(f"{len(seeds)} rigs to run ({len(done)} already in {path}) on {args.processes} processes",
              file=sys.stderr)
        with multiprocessing.get_context("spawn").Pool(args.processes) as pool, open(path, "a") as out:
            for i, row in enumerate(pool.imap_unordered(one, seeds), 1):
                out.write(json.dumps(row) + "\n")
                out.flush()
                done[row["seed"]] = row
                print(f"  {i}/{len(seeds)} rigs, {time.perf_counter() - t0:.0f} s", file=sys.stderr)
    rows = [done[s] for s in sorted(done) if args.seed <= s < args.seed + args.rigs]
    print(json.dumps(fc.summary(rows)))
    if args.markdown:
        print(fc.markdown(rows))
    if args.figure:
        title = f"foreign rigs: {len(rows)} rigs, 100 bar, {fc.TEST_CYCLES} cycles"
        fc.figure(rows, title).savefig(args.figure, dpi=110, bbox_inches="tight")
        print(f"wrote {args.figure}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
