"""`isorig compare`: every controller on the grid of issue 7 (isolators x supply x frequency x rig), the robustness
suite of issue 15 (small amplitudes, soft oil columns, sensor latency, stiffness changes), or a Monte Carlo campaign
over the rig and the isolator, on dask.distributed (a local cluster, or --scheduler ADDRESS). ``--rig-file`` /
``--rig-set`` give the lab's rig (what the controllers assume), ``--plant-set`` changes the simulated plant only."""

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
    p.add_argument("--robustness", action="store_true",
                   help="run the robustness suite of issue 15 (small amplitudes, soft oil columns, sensor latency, "
                        "stiffness changes) and print each case's figure against its target (docs/compare.md)")
    p.add_argument("--groups", default=None,
                   help="with --robustness: comma-separated groups to run (default: the four of the issue; also the "
                        "sensitivity groups 'valve null off' and 'more oil than declared')")
    p.add_argument("--rig-file", default=None, metavar="FILE",
                   help="the lab's rig: a .json or .toml file of RigParameters names (SI) over the defaults; what "
                        "the controllers assume and, unless --plant-set says otherwise, the simulated plant")
    p.add_argument("--rig-set", action="append", default=[], metavar="NAME=VALUE",
                   help="change one rig parameter (after --rig-file), e.g. mass_kg=3000 (repeatable)")
    p.add_argument("--controller-option", action="append", default=[], metavar="NAME=VALUE",
                   help="a controller option for every run (docs/controller.md), e.g. "
                        "pressure_feedback_max_damping=0 to see what a piece buys (repeatable)")
    p.add_argument("--plant-set", action="append", default=[], metavar="NAME=VALUE",
                   help="change one rig parameter of the simulated plant only (the rig as it truly is, unknown to "
                        "the controllers), e.g. bulk_modulus_pa=5e8 (repeatable)")
    p.add_argument("--monte-carlo", metavar="FILE", default=None,
                   help="run the Monte Carlo campaign of FILE (.json or .toml: distributions of rig and isolator "
                        "parameters of the simulated plant; docs/compare.md, Campaigns) instead of the grid")
    p.add_argument("--foreign-rigs", metavar="N", type=whole_number, default=None,
                   help="commission N rigs of the foreign family (foreign_rigs: written from the physics, not from "
                        "isorig's model) from what their labs know, then run 20 mm 0.5 Hz, 2 mm 1 Hz and 0.5 mm 1 Hz "
                        "on each with its rig file (docs/commissioning.md, 'Foreign rigs')")
    p.add_argument("--seed", metavar="S", type=whole_number, default=0,
                   help="with --foreign-rigs: the first rig's seed (rigs S .. S+N-1)")
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
    p.add_argument("--no-limit-detectors", action="store_true",
                   help="do not judge the runs by the rig's default limits and the sensor and follow detectors, "
                        "which the service applies to every test; by default a run the service would stop is "
                        "counted ABORTED (its status and reason in --json and --csv), its figures going on past "
                        "the trip")
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
    modes = [flag for flag, on in (("--robust", args.robust), ("--ablation", args.ablation),
                                   ("--robustness", args.robustness)) if on]
    if len(modes) > 1:
        raise UsageError(f"isorig compare: choose one of {', '.join(modes)}, not several")
    if args.groups is not None and not args.robustness:
        raise UsageError("isorig compare: --groups applies to --robustness only")
    if args.robustness:
        if args.cycles is not None:
            raise UsageError("isorig compare: --cycles cannot go with --robustness (each case has its own cycles)")
        if args.figure is not None:
            raise UsageError("isorig compare: --figure draws the grid's error distribution; with --robustness use "
                             "--csv or --json for the cases' figures")
    if args.monte_carlo is not None:
        given = [flag for flag, on in (("--robust", args.robust), ("--ablation", args.ablation),
                                       ("--robustness", args.robustness),
                                       ("--controllers", args.controllers is not None),
                                       ("--cycles", args.cycles is not None),
                                       ("--rig-file", args.rig_file is not None), ("--rig-set", bool(args.rig_set)),
                                       ("--plant-set", bool(args.plant_set)),
                                       ("--controller-option", bool(args.controller_option))) if on]
        if given:
            raise UsageError(f"isorig compare: {', '.join(given)} cannot go with --monte-carlo (the campaign file "
                             "names its controllers, cycles, nominal rig and plant distributions)")
    elif args.cycles is not None and args.cycles < 2 * cmp.TAPER_CYCLES + 2:
        raise UsageError(f"isorig compare: --cycles {args.cycles} is too few; need at least "
                         f"{2 * cmp.TAPER_CYCLES + 2} (tapers plus two full cycles)")


def rig_arguments(args):
    """(the nominal rig, its description or None, plant-only changes) from --rig-file, --rig-set, --plant-set."""
    from sim.rig import DEFAULT_RIG
    from sim.rigfile import RIG_FIELDS, load_rig_file, parse_assignment, rig_from_mapping, with_assignments

    described = load_rig_file(args.rig_file) if args.rig_file else None
    rig = described.parameters if described is not None else DEFAULT_RIG
    rig = with_assignments(rig, args.rig_set, "--rig-set")
    plant = dict(parse_assignment(a, RIG_FIELDS, "rig parameter (--plant-set changes the simulated rig; the "
                                  "isolator parameters differ per isolator of the grid)") for a in args.plant_set)
    if plant:
        rig_from_mapping(plant, rig, "--plant-set")  # the plant must be a rig too: one clear error otherwise
    return rig, described, plant


def supplies_in_range(rig, cmp) -> tuple[tuple[float, ...], list[float]]:
    """The grid's supply pressures the rig allows, and those it does not (skipped, with a note)."""
    from sim.rig import BAR_PA

    inside = tuple(b for b in cmp.SUPPLIES_BAR if rig.min_supply_pa <= b * BAR_PA <= rig.max_supply_pa)
    return inside, [b for b in cmp.SUPPLIES_BAR if b not in inside]


def run(args) -> int:
    from sim import campaign as cpg
    from sim import compare as cmp
    from sim import robustness as rb
    from sim.controllers import CONTROLLER_NAMES
    from sim.rig import DEFAULT_RIG

    check_arguments(args, cmp)
    if args.foreign_rigs is not None:
        return run_foreign(args)
    campaign = None
    base_rig, described, plant = DEFAULT_RIG, None, {}
    notes: list[str] = []
    if args.monte_carlo is not None:
        campaign = cpg.load_campaign(args.monte_carlo)
        if campaign.commissioning is not None:
            return run_commissioning(args, campaign)
        cycles = campaign.cycles
        points = campaign.points()  # the draws, every plant checked: a bad file stops here
        group_key = "controller"
    else:
        base_rig, described, plant = rig_arguments(args)
        cycles = cmp.CYCLES if args.cycles is None else args.cycles
        if args.controllers is None:
            controllers = ("servo",) if (args.robust or args.ablation or args.robustness) else cmp.CONTROLLERS
        else:
            controllers = tuple(c.strip() for c in args.controllers.split(",") if c.strip())
            bad = [c for c in controllers if c not in CONTROLLER_NAMES]
            if bad or not controllers:
                raise UsageError(f"isorig compare: unknown controller(s) {', '.join(bad) or '(none)'}; "
                                 f"allowed: {', '.join(CONTROLLER_NAMES)}")
        supplies, skipped = supplies_in_range(base_rig, cmp)
        if skipped and not args.robustness:
            notes.append(f"supply {', '.join(f'{b:g}' for b in skipped)} bar skipped: outside the rig's range "
                         f"[{base_rig.min_supply_pa / 1e5:g}, {base_rig.max_supply_pa / 1e5:g}] bar")
        if args.robustness:
            groups_run = rb.GROUPS if args.groups is None else \
                tuple(g.strip() for g in args.groups.split(",") if g.strip())
            bad = [g for g in groups_run if g not in rb.ALL_GROUPS]
            if bad or not groups_run:
                raise UsageError(f"isorig compare: unknown robustness group(s) {', '.join(bad) or '(none)'}; "
                                 f"allowed: {', '.join(repr(g) for g in rb.ALL_GROUPS)}")
            points = rb.robustness_points(controllers=controllers, base_rig=base_rig, plant=plant, groups=groups_run)
            rb.check_points(points)  # every case inside its rig's envelope, before anything runs
            group_key = "group"
        elif args.ablation:
            points = cmp.ablation_points(base_rig=base_rig, plant=plant, supplies_bar=supplies)
            group_key = "corner"
        else:
            points = cmp.grid_points(controllers=controllers, robust=args.robust, supplies_bar=supplies,
                                     base_rig=base_rig, plant=plant)
            group_key = "corner" if args.robust else "controller"
        if args.controller_option:
            from isorig.commands.simulate import option_pair

            extra = {}
            for text in args.controller_option:
                try:
                    name, value = option_pair(text)
                except Exception as exc:  # argparse.ArgumentTypeError: one line
                    raise UsageError(f"isorig compare: --controller-option {exc}") from None
                extra[name] = value
            for p in points:
                p.options = {**(p.options or {}), **extra}
            from sim.controllers import make_controller

            for name in {p.controller for p in points}:  # an unknown or out-of-range option: one error, now
                make_controller(name, **extra)
        if not points:
            raise UsageError("isorig compare: nothing to run (--robust and --ablation apply to servo only; a rig "
                             "whose supply range holds none of the grid's pressures has no grid)")
    if args.no_limit_detectors:
        for p in points:
            p.detectors = False
    outputs = cpg.Outputs(args.csv, args.figure)  # paths checked before anything runs

    timeout = cpg.SCHEDULER_TIMEOUT_S if args.scheduler_timeout is None else args.scheduler_timeout
    with cpg.Engine(scheduler=args.scheduler, workers=args.processes, timeout_s=timeout) as engine:
        if not args.json:
            what = "cases of the robustness suite" if args.robustness else f"closed-loop tests of {cycles} cycles"
            print(f"running {len(points)} {what} on {engine.description} ...", file=sys.stderr)
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
    elif args.robustness:
        title = f"isorig compare, robustness suite: {len(rows)} cases"
    else:
        mode = "ablations" if args.ablation else ("robust corners" if args.robust else "grid")
        title = f"isorig compare, {mode}: {len(rows)} runs of {cycles} cycles"
    outputs.write(rows, groups, title)  # both complete, or neither

    rig_json = {"rig": described.to_dict() if described is not None else
                {"name": "isorig default rig (sim.rig)", "source": "sim.rig defaults"},
                "rig_set": list(args.rig_set), "plant_set": plant} if campaign is None else {}
    if args.robustness:
        if args.json:
            out = {"robustness": rb.description(base_rig), **rig_json, "wall_time_s": wall,
                   "engine": {"where": where, "startup_s": startup},
                   "summary": cmp.jsonable(rb.group_summary(rows)), "rows": cmp.jsonable(rows)}
            print(json.dumps(out, indent=1, allow_nan=False))
            return 0
        for note in rig_notes(described, args, plant) + notes:
            print(note)
        if not args.summary_only:
            print("\n### every case\n")
            print(rb.robustness_table(rows, markdown=args.markdown))
        print("\n### worst case per group\n")
        print(rb.summary_table(rows, markdown=args.markdown))
        met = sum(r["met"] for r in rows)
        print(f"\n{met}/{len(rows)} cases meet their target; {len(rows)} cases in {wall:.1f} s wall time on {where} "
              f"(and {startup:.1f} s to start it)")
        if args.csv:
            print(f"wrote {args.csv}", file=sys.stderr)
        return 0
    if args.json:
        out = {"campaign": campaign.describe()} if campaign is not None else \
            {"grid": cmp.grid_description(cycles, robust=args.robust, ablation=args.ablation), **rig_json}
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
    for note in rig_notes(described, args, plant) + notes:
        print(note)
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


def map_rigs(args, chunk_function, runs: list, what: str) -> tuple[list, float, str, float]:
    """``chunk_function`` over ``runs`` one rig a task on the campaign engine (a local cluster or --scheduler), with
    a progress bar: (rows, wall time s, where, the engine's start-up s)."""
    from sim import campaign as cpg

    timeout = cpg.SCHEDULER_TIMEOUT_S if args.scheduler_timeout is None else args.scheduler_timeout
    with cpg.Engine(scheduler=args.scheduler, workers=args.processes, timeout_s=timeout) as engine:
        print(f"{what}, on {engine.description} ...", file=sys.stderr)
        bar = ProgressBar()
        bar(0, len(runs))
        try:
            rows, wall = engine.map(chunk_function, runs, 1, progress=bar)
        finally:
            bar.close()
        return rows, wall, engine.description, engine.startup_s


def run_commissioning(args, campaign) -> int:
    """A commissioning campaign (a campaign file with a ``commissioning`` section, sim.commission.campaign): each
    drawn rig commissioned, then tested with its rig file and without it; the tables, and --csv / --figure."""
    from sim import campaign as cpg
    from sim.commission import campaign as cc

    if args.json:
        raise UsageError("isorig compare: a commissioning campaign prints its tables; use --csv for every run's "
                         "figures")
    runs = cc.campaign_runs(campaign)
    outputs = cpg.Outputs(args.csv, args.figure)
    tests = runs[0].tests
    rows, wall, where, startup = map_rigs(args, cc.run_chunk, runs, f"commissioning {len(runs)} drawn rigs, then "
                                          f"{len(tests)} test(s) on each with and without the rig file")
    title = (f"commissioning campaign '{campaign.name}': {len(rows)} rigs, {campaign.isolator.name}, "
             f"{campaign.supply_bar:g} bar, {campaign.cycles} cycles, seed {campaign.seed}")
    figure = cc.figure(rows, tests, title) if args.figure else None
    outputs.write(rows, {}, title, text=cc.csv_text(rows), figure=figure)
    print(f"\n### {title}\n")
    print(cpg.parameters_table(campaign))
    print()
    print(cc.summary_tables(rows, tests, runs[0].max_stroke_m, runs[0].max_velocity_m_per_s))
    print(f"\n{len(rows)} rigs in {wall:.1f} s wall time on {where} (and {startup:.1f} s to start it)")
    for path in (args.csv, args.figure):
        if path:
            print(f"wrote {path}", file=sys.stderr)
    return 0


def run_foreign(args) -> int:
    """``--foreign-rigs N``: the foreign rig family commissioned and tested (sim.commission.foreign_campaign)."""
    from sim.commission import foreign_campaign as fc

    given = [flag for flag, on in (("--robust", args.robust), ("--ablation", args.ablation),
                                   ("--robustness", args.robustness), ("--monte-carlo", args.monte_carlo is not None),
                                   ("--controllers", args.controllers is not None),
                                   ("--cycles", args.cycles is not None), ("--rig-file", args.rig_file is not None),
                                   ("--rig-set", bool(args.rig_set)), ("--plant-set", bool(args.plant_set)),
                                   ("--controller-option", bool(args.controller_option))) if on]
    if given:
        raise UsageError(f"isorig compare: {', '.join(given)} cannot go with --foreign-rigs (each foreign rig is "
                         "commissioned from what its lab knows and tested on the three cases of the issue)")
    if not (1 <= args.foreign_rigs <= 100_000):
        raise UsageError(f"isorig compare: --foreign-rigs {args.foreign_rigs} must be between 1 and 100000")
    if not (0 <= args.seed and args.seed + args.foreign_rigs <= 2 ** 32):
        raise UsageError("isorig compare: --seed S must be >= 0 with S + N below 2**32")
    runs = [fc.ForeignRun(args.seed + i) for i in range(args.foreign_rigs)]
    rows, wall, where, _startup = map_rigs(args, fc.run_chunk, runs, f"commissioning {len(runs)} foreign rigs (seeds "
                                           f"{args.seed}..{args.seed + len(runs) - 1}), then 3 tests on each "
                                           "commissioned one")
    title = f"foreign rigs {args.seed}..{args.seed + len(runs) - 1}: {len(rows)} rigs, 100 bar, {fc.TEST_CYCLES} cycles"
    if args.csv:
        from sim.commission import campaign as cc

        with open(args.csv, "w") as f:
            f.write(cc.csv_text([{k: ("; ".join(map(str, v)) if isinstance(v, list) else v) for k, v in r.items()}
                                 for r in rows]))
    if args.figure:
        fc.figure(rows, title).savefig(args.figure, dpi=110, bbox_inches="tight")
    if args.json:
        print(json.dumps(fc.summary(rows)))
    else:
        print(f"\n### {title}\n")
        print(fc.markdown(rows))
        print(f"\n{len(rows)} rigs in {wall:.1f} s wall time on {where}")
    for path in (args.csv, args.figure):
        if path:
            print(f"wrote {path}", file=sys.stderr)
    return 0


def rig_notes(described, args, plant: dict) -> list[str]:
    """What rig the runs assumed, when it is not the default one."""
    lines = []
    if described is not None:
        changed = ", ".join(f"{k} = {v:g}" for k, v in described.changed().items()) or "the defaults"
        lines.append(f"rig: {described.name} ({described.source}): {changed}")
    if getattr(args, "rig_set", None):
        lines.append(f"rig changes: {', '.join(args.rig_set)}")
    if getattr(args, "controller_option", None):
        lines.append(f"controller options: {', '.join(args.controller_option)}")
    if plant:
        lines.append(f"plant only (unknown to the controllers): {', '.join(f'{k} = {v:g}' for k, v in plant.items())}")
    return lines
