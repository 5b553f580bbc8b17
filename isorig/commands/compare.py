"""`isorig compare`: every controller on the grid of issue 7 (isolators x supply x frequency x rig), or a Monte
Carlo campaign over the rig and the isolator, on dask.distributed (a local cluster, or --scheduler ADDRESS)."""

from __future__ import annotations

import json
import sys
import time

from isorig.cli import UsageError, whole_number


def register(sub) -> None:
    p = sub.add_parser("compare", help="run the controller comparison grid or a Monte Carlo campaign on a dask "
                                       "cluster and print a table per controller (see docs/compare.md)")
    p.add_argument("--json", action="store_true", help="print one JSON object instead of tables")
    p.add_argument("--robust", action="store_true",
                   help="run the learning controller with its nominal piston area, flow gain and dead zone "
                        "each off by -30 %% / +30 %% (8 corners)")
    p.add_argument("--ablation", action="store_true",
                   help="run the learning controller with one piece switched off at a time")
    p.add_argument("--monte-carlo", metavar="FILE", default=None,
                   help="run the Monte Carlo campaign of FILE (.json or .toml: distributions of rig and isolator "
                        "parameters of the simulated plant; docs/compare.md, Campaigns) instead of the grid")
    p.add_argument("--controllers", default=None,
                   help="comma-separated controllers (default: servo,mrac,pid; --robust: servo)")
    p.add_argument("--cycles", type=whole_number, default=None, help="cycles per run (default 10, taper 1)")
    p.add_argument("--processes", type=whole_number, default=None,
                   help="worker processes of the local cluster (default: all cores)")
    p.add_argument("--scheduler", metavar="ADDRESS", default=None,
                   help="run on the dask cluster of this scheduler (e.g. tcp://10.0.0.5:8786; its workers need this "
                        "isorig) instead of a local cluster")
    p.add_argument("--scheduler-timeout", metavar="SECONDS", type=float, default=None,
                   help="how long to wait for the scheduler and its first worker (default 5)")
    p.add_argument("--csv", metavar="FILE", default=None, help="write every run's figures to this CSV file")
    p.add_argument("--figure", metavar="FILE", default=None,
                   help="draw the distribution of the last-two-cycles RMS error per group (.png, .svg or .pdf)")
    p.add_argument("--compare-backends", action="store_true",
                   help="also run the same runs in one process and on the process pool it replaces, one after the "
                        "other, and print the per-run overhead of each path")
    p.add_argument("--markdown", action="store_true", help="print the tables as Markdown")
    p.add_argument("--summary-only", action="store_true",
                   help="print only the worst case of each group (controller, corner or ablation)")
    p.set_defaults(func=run)


class ProgressBar:
    """``[#####-----]  52 %  520/1000 runs  3.1 s`` on a terminal (stderr); silent otherwise."""

    def __init__(self, stream=None, width: int = 30):
        self.stream = stream or sys.stderr
        self.active = self.stream.isatty()
        self.width = width
        self.t0 = time.perf_counter()

    def __call__(self, done: int, total: int) -> None:
        if self.active:
            filled = int(self.width * done / max(total, 1))
            self.stream.write(f"\r[{'#' * filled}{'-' * (self.width - filled)}] {100 * done / max(total, 1):3.0f} %  "
                              f"{done}/{total} runs  {time.perf_counter() - self.t0:.1f} s")
            self.stream.flush()

    def close(self) -> None:
        if self.active:
            self.stream.write("\n")
            self.stream.flush()


def check_arguments(args, cmp) -> None:
    if args.processes is not None and args.processes < 1:
        raise UsageError("isorig compare: --processes must be at least 1")
    if args.scheduler is not None and args.processes is not None:
        raise UsageError("isorig compare: --processes sets the local cluster; with --scheduler the cluster's "
                         "workers run the tests")
    if args.scheduler_timeout is not None:
        if not (0.1 <= args.scheduler_timeout <= 600.0):
            raise UsageError("isorig compare: --scheduler-timeout must be between 0.1 and 600 s")
        if args.scheduler is None:
            raise UsageError("isorig compare: --scheduler-timeout applies to --scheduler only")
    if args.compare_backends and args.scheduler is not None:
        raise UsageError("isorig compare: --compare-backends measures both paths on this machine; leave out "
                         "--scheduler")
    if args.robust and args.ablation:
        raise UsageError("isorig compare: choose --robust or --ablation, not both")
    if args.monte_carlo is not None:
        given = [flag for flag, on in (("--robust", args.robust), ("--ablation", args.ablation),
                                       ("--controllers", args.controllers is not None),
                                       ("--cycles", args.cycles is not None)) if on]
        if given:
            raise UsageError(f"isorig compare: {', '.join(given)} cannot go with --monte-carlo (the campaign file "
                             "names its controllers and cycles)")
    elif args.cycles is not None and args.cycles < 2 * cmp.TAPER_CYCLES + 2:
        raise UsageError(f"isorig compare: --cycles {args.cycles} is too few; need at least "
                         f"{2 * cmp.TAPER_CYCLES + 2} (tapers plus two full cycles)")


def run(args) -> int:
    from sim import campaign as cpg
    from sim import compare as cmp
    from sim.controllers import CONTROLLER_NAMES

    check_arguments(args, cmp)
    campaign = None
    if args.monte_carlo is not None:
        campaign = cpg.load_campaign(args.monte_carlo)
        cycles = campaign.cycles
        points = campaign.points()  # the draws, every plant checked: a bad file stops here
        group_key = "controller"
    else:
        cycles = cmp.CYCLES if args.cycles is None else args.cycles
        if args.controllers is None:
            controllers = ("servo",) if (args.robust or args.ablation) else cmp.CONTROLLERS
        else:
            controllers = tuple(c.strip() for c in args.controllers.split(",") if c.strip())
            bad = [c for c in controllers if c not in CONTROLLER_NAMES]
            if bad or not controllers:
                raise UsageError(f"isorig compare: unknown controller(s) {', '.join(bad) or '(none)'}; "
                                 f"allowed: {', '.join(CONTROLLER_NAMES)}")
        if args.ablation:
            points = cmp.ablation_points()
            group_key = "corner"
        else:
            points = cmp.grid_points(controllers=controllers, robust=args.robust)
            group_key = "corner" if args.robust else "controller"
        if not points:
            raise UsageError("isorig compare: nothing to run (--robust and --ablation apply to servo only)")
    outputs = cpg.Outputs(args.csv, args.figure)  # paths checked before anything runs

    timeout = cpg.SCHEDULER_TIMEOUT_S if args.scheduler_timeout is None else args.scheduler_timeout
    with cpg.Engine(scheduler=args.scheduler, workers=args.processes, timeout_s=timeout) as engine:
        if not args.json:
            print(f"running {len(points)} closed-loop tests of {cycles} cycles on {engine.description} ...",
                  file=sys.stderr)
        bar = ProgressBar()
        bar(0, len(points))
        try:
            rows, wall = engine.run(points, cycles=cycles, progress=bar)
        finally:
            bar.close()
        backends = cpg.compare_backends(points, cycles, engine) if args.compare_backends else None
        startup = engine.startup_s
        where = engine.description

    if campaign is not None:
        rows = [cpg.campaign_row(p, r) for p, r in zip(points, rows, strict=True)]
    groups: dict[str, list[dict]] = {}
    for row in rows:
        groups.setdefault(row[group_key], []).append(row)
    if campaign is not None:
        title = (f"Monte Carlo '{campaign.name}': {campaign.runs} plants, {campaign.isolator.name}, "
                 f"{campaign.supply_bar:g} bar, {campaign.amplitude_m * 1e3:g} mm at {campaign.frequency_hz:g} Hz, "
                 f"{cycles} cycles")
    else:
        mode = "ablations" if args.ablation else ("robust corners" if args.robust else "grid")
        title = f"isorig compare, {mode}: {len(rows)} runs of {cycles} cycles"
    outputs.write(rows, groups, title)  # both complete, or neither

    if args.json:
        out = {"campaign": campaign.describe()} if campaign is not None else \
            {"grid": cmp.grid_description(cycles, robust=args.robust, ablation=args.ablation)}
        out.update({
            "wall_time_s": wall,
            "engine": {"where": where, "startup_s": startup},
            "groups": {name: {"worst_case": cmp.jsonable([cmp.worst_case(g)])[0],
                              **({"error_distribution": cmp.jsonable([cpg.error_distribution(g)])[0]}
                                 if campaign is not None else {}),
                              "rows": cmp.jsonable(g)}
                       for name, g in groups.items()},
        })
        if backends is not None:
            out["backends"] = backends
        print(json.dumps(out, indent=1, allow_nan=False))
        return 0
    table = cmp.markdown_table if args.markdown else cmp.text_table
    if campaign is not None:
        print(f"\n### Monte Carlo campaign {campaign.name}: {campaign.runs} plants x "
              f"{len(campaign.controllers)} controller(s), {campaign.isolator.name}, {campaign.supply_bar:g} bar, "
              f"{campaign.amplitude_m * 1e3:g} mm at {campaign.frequency_hz:g} Hz, {cycles} cycles, seed "
              f"{campaign.seed}\n")
        print(cpg.parameters_table(campaign))
        print("\n### distribution of the last two cycles' RMS |y - r| / amplitude per controller\n")
        print(cpg.distribution_table(groups, markdown=args.markdown))
    elif not args.summary_only:
        for name, g in groups.items():
            print(f"\n### {name}\n")
            print(table(g))
            print("\n" + cmp.worst_case_line(cmp.worst_case(g)))
    print(f"\n### worst case per {'ablation / corner' if args.ablation else group_key}\n")
    print(cmp.summary_table(groups, markdown=args.markdown))
    print(f"\n{len(rows)} runs of {cycles} cycles in {wall:.1f} s wall time on {where} (and {startup:.1f} s to start "
          "it)")
    if backends is not None:
        print("\n### engines\n")
        print(cpg.backends_table(backends))
    for path in (args.csv, args.figure):
        if path:
            print(f"wrote {path}", file=sys.stderr)
    return 0
