"""The issue's cases on commissioned foreign rigs, with the servo's options varied: what a change to the controller
does on rigs it was not built from, in seconds instead of the campaign's hour (issue 32 item 4).

    .venv/bin/python scripts/foreign_cases.py --rigs 300 [--seed 0] [--cache F.json] [--cases 0.5mm_1Hz ...]
        [--option NAME=VALUE ...] [--workers 2] [--json]

Each rig is commissioned once as its lab would (``foreign_campaign.commission_as_a_lab``: the first attempt and the
second one a refusal suggests, as ``isorig compare --foreign-rigs`` does); the trusted ones' rig files and
commissioning sections are kept in ``--cache`` (JSON; commissioning is deterministic in the seed, so a cache made at
the same fit is the campaign's). Then each case runs on each trusted rig with ``foreign_campaign.tested`` (the
service's follow monitor; one run each) and the figures print as the campaign counts them: within the case's target,
the median, and the stops by kind. The campaign's figures for its cases are these: at cbe8117 this gave the eleventh
session's campaign table to the digit (docs/commissioning.md, twelfth session).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))


def commissioned(seed: int) -> tuple[int, dict | None]:
    """Rig ``seed`` commissioned as a lab would: (seed, {"rig": RigParameters fields, "section": ...}) if trusted."""
    from sim.commission import foreign_campaign as fc

    lab = fc.commission_as_a_lab(fc.ForeignRun(seed))
    if not lab.last.trusted:
        return seed, None
    return seed, {"rig": dataclasses.asdict(lab.last.rig),
                  "section": fc.commissioning_section(lab.last, lab.max_velocity_m_per_s)}


def run_case(job: tuple) -> tuple[int, str, dict]:
    """One case on one commissioned rig: (seed, case, foreign_campaign.tested's outcome)."""
    from foreign_rigs import draw_rig
    from sim.commission import foreign_campaign as fc
    from sim.rig import RigParameters

    seed, entry, label, options = job
    _label, amplitude_m, frequency_hz, _target = next(c for c in fc.CASES if c[0] == label)
    outcome = fc.tested(draw_rig(seed), RigParameters(**entry["rig"]), amplitude_m, frequency_hz, entry["section"],
                        options or None)
    return seed, label, outcome


def figures(outcomes: dict, target: float) -> dict:
    """The campaign's figures of one case (foreign_campaign.case_figures), and its stops by their detector's kind."""
    from sim.commission.foreign_campaign import case_figures

    stops: dict = {}
    for o in outcomes.values():
        if o["stopped_s"] is not None:
            stops[o["stop_kind"]] = stops.get(o["stop_kind"], 0) + 1
    return {**case_figures(list(outcomes.values()), target), "stops": stops}


def option(text: str) -> tuple[str, float]:
    name, sep, value = text.partition("=")
    try:
        if not sep or not name:
            raise ValueError
        return name, float(value)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not NAME=VALUE with a number (e.g. learning_gain=0.5)") from None


def main() -> None:
    from sim.commission.foreign_campaign import CASES

    labels = [c[0] for c in CASES]
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--rigs", type=int, required=True, help="rigs SEED .. SEED + RIGS - 1")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--cache", type=Path, help="JSON of the commissioned rigs: read if there, else written")
    parser.add_argument("--cases", nargs="+", choices=labels, default=labels)
    parser.add_argument("--option", type=option, action="append", default=[], metavar="NAME=VALUE",
                        help="a servo controller option for every run (repeatable)")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--json", action="store_true", help="print one JSON object")
    args = parser.parse_args()
    if args.rigs < 1 or args.workers < 1:
        parser.error("--rigs and --workers must be at least 1")
    options = dict(args.option)
    try:  # a name or value the servo does not take is said before anything runs
        from sim.controllers import make_controller

        make_controller("servo", **options)
    except ValueError as bad:
        parser.error(f"--option: {bad}")
    os.environ.setdefault("OMP_NUM_THREADS", "1")  # a worker a core: the fit's BLAS on one thread
    seeds = list(range(args.seed, args.seed + args.rigs))
    started = time.perf_counter()
    with ProcessPoolExecutor(args.workers) as pool:
        cache = {}
        if args.cache is not None and args.cache.exists():
            cache = {int(k): v for k, v in json.loads(args.cache.read_text()).items()}
        missing = [s for s in seeds if s not in cache]
        for done, (seed, entry) in enumerate(pool.map(commissioned, missing), 1):
            cache[seed] = entry
            print(f"commissioned {done}/{len(missing)}: rig {seed} {'trusted' if entry else 'refused'}",
                  file=sys.stderr)
        if args.cache is not None and missing:
            args.cache.write_text(json.dumps({str(k): v for k, v in sorted(cache.items())}))
        trusted = {s: cache[s] for s in seeds if cache.get(s)}
        commissioned_s = time.perf_counter() - started
        jobs = [(s, trusted[s], label, options) for label in args.cases for s in sorted(trusted)]
        outcomes: dict = {label: {} for label in args.cases}
        for seed, label, outcome in pool.map(run_case, jobs, chunksize=4):
            outcomes[label][seed] = outcome
    targets = {c[0]: c[3] for c in CASES}
    cases_s = time.perf_counter() - started - commissioned_s
    out = {"rigs": len(seeds), "commissioned": len(trusted), "options": options,
           "commission_s": round(commissioned_s, 1), "cases_s": round(cases_s, 1),
           "cases": {label: figures(outcomes[label], targets[label]) for label in args.cases}}
    if args.json:
        out["runs"] = {label: {str(s): o for s, o in sorted(v.items())} for label, v in outcomes.items()}
        print(json.dumps(out, indent=1))
        return
    print(f"{out['commissioned']} of {out['rigs']} rigs commissioned ({out['commission_s']} s); "
          f"options {options or 'none'}")
    for label in args.cases:
        f = out["cases"][label]
        median = "-" if f["median_pct"] is None else f"{f['median_pct']:.3f} %"
        print(f"  {label}: {f['within_target']} of {f['runs']} within {100 * targets[label]:g} %, median {median}, "
              f"stops {f['stops'] or 'none'}")
    print(f"cases in {out['cases_s']} s")


if __name__ == "__main__":
    main()
