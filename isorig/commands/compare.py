"""`isorig compare`: every controller on the grid of issue 7 (isolators x supply x frequency x rig), in parallel."""

from __future__ import annotations

import json
import sys

from isorig.cli import UsageError, whole_number


def register(sub) -> None:
    p = sub.add_parser("compare", help="run the controller comparison grid on all cores and print a table per "
                                       "controller (see docs/compare.md)")
    p.add_argument("--json", action="store_true", help="print one JSON object instead of tables")
    p.add_argument("--robust", action="store_true",
                   help="run the learning controller with its nominal piston area, flow gain and dead zone "
                        "each off by -30 %% / +30 %% (8 corners)")
    p.add_argument("--ablation", action="store_true",
                   help="run the learning controller with one piece switched off at a time")
    p.add_argument("--controllers", default=None,
                   help="comma-separated controllers (default: servo,mrac,pid; --robust: servo)")
    p.add_argument("--cycles", type=whole_number, default=None, help="cycles per run (default 10, taper 1)")
    p.add_argument("--processes", type=whole_number, default=None, help="worker processes (default: all cores)")
    p.add_argument("--markdown", action="store_true", help="print the tables as Markdown")
    p.add_argument("--summary-only", action="store_true",
                   help="print only the worst case of each group (controller, corner or ablation)")
    p.set_defaults(func=run)


def run(args) -> int:
    from sim import compare as cmp
    from sim.controllers import CONTROLLER_NAMES

    cycles = cmp.CYCLES if args.cycles is None else args.cycles
    if cycles < 2 * cmp.TAPER_CYCLES + 2:
        raise UsageError(f"isorig compare: --cycles {cycles} is too few; need at least {2 * cmp.TAPER_CYCLES + 2} "
                         "(tapers plus two full cycles)")
    if args.processes is not None and args.processes < 1:
        raise UsageError("isorig compare: --processes must be at least 1")
    if args.robust and args.ablation:
        raise UsageError("isorig compare: choose --robust or --ablation, not both")
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
    if not args.json:
        print(f"running {len(points)} closed-loop tests of {cycles} cycles on "
              f"{args.processes or 'all'} core(s) ...", file=sys.stderr)
    rows, wall = cmp.run_grid(points, cycles=cycles, processes=args.processes)
    groups: dict[str, list[dict]] = {}
    for row in rows:
        groups.setdefault(row[group_key], []).append(row)
    if args.json:
        print(json.dumps({
            "grid": cmp.grid_description(cycles, robust=args.robust, ablation=args.ablation),
            "wall_time_s": wall,
            "groups": {name: {"worst_case": cmp.jsonable([cmp.worst_case(g)])[0], "rows": cmp.jsonable(g)}
                       for name, g in groups.items()},
        }, indent=1, allow_nan=False))
        return 0
    table = cmp.markdown_table if args.markdown else cmp.text_table
    if not args.summary_only:
        for name, g in groups.items():
            print(f"\n### {name}\n")
            print(table(g))
            print("\n" + cmp.worst_case_line(cmp.worst_case(g)))
    print(f"\n### worst case per {'ablation / corner' if args.ablation else group_key}\n")
    print(cmp.summary_table(groups, markdown=args.markdown))
    print(f"\n{len(rows)} runs of {cycles} cycles in {wall:.1f} s wall time")
    return 0
