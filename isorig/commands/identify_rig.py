"""`isorig identify rig`: commission a rig. A bounded excitation from where the table rests, a fit of every
parameter the controller relies on, and a rig file with its provenance, or a refusal that says why.

The run goes through the service's loop, detectors and stop paths (backend.worker.run_here) on the simulated
rig (as fast as it computes) or on a UDP rig (in real time); the fit is sim.commission's. Not registered on
its own: `isorig identify` adds it as its ``rig`` subcommand.
"""

from __future__ import annotations

import datetime as dt
import json
from pathlib import Path

from isorig.cli import UsageError

SIMULATED_SPEED = 1000.0  # the simulated rig's run is paced at this many times real time


def register(isub, parser_class) -> None:
    from sim.commission.bounds import DEFAULT_MAX_STROKE_M, DEFAULT_MAX_VELOCITY_M_PER_S
    from sim.isolator import PRESETS

    r = isub.add_parser("rig", help="commission a rig: a bounded excitation, a fit of the rig's parameters with "
                                    "their uncertainties, a rig file with its provenance")
    r.add_argument("--rig", default="simulated",
                   help="udp://HOST:PORT (a lab's I/O target or `isorig rig-emulator`) or 'simulated' (default)")
    r.add_argument("--supply-bar", type=float, required=True, help="supply pressure of the run in bar")
    r.add_argument("--isolator", default="none",
                   help=f"the specimen mounted: none (default), a preset ({', '.join(PRESETS)}) or an isolator "
                        ".json file; its force is measured, not assumed")
    r.add_argument("--vertical-load-n", type=float, default=None,
                   help="vertical load of the jack in N (default: the specimen's design load; 0 with no specimen)")
    r.add_argument("--rig-file", default=None, metavar="START",
                   help="the rig file to start from (piston area, oil volume and the ranges are kept from it)")
    r.add_argument("--rig-set", action="append", default=[], metavar="NAME=VALUE",
                   help="change one parameter of the starting rig (after --rig-file; repeatable)")
    r.add_argument("--plant-set", action="append", default=[], metavar="NAME=VALUE",
                   help="simulated rig only: the rig as it truly is, unknown to isorig (repeatable)")
    r.add_argument("--max-stroke-m", type=float, default=DEFAULT_MAX_STROKE_M,
                   help=f"the table stays within this of where it rests (default {DEFAULT_MAX_STROKE_M:g} m)")
    r.add_argument("--max-velocity-m-per-s", type=float, default=DEFAULT_MAX_VELOCITY_M_PER_S,
                   help=f"... and below this velocity (default {DEFAULT_MAX_VELOCITY_M_PER_S:g} m/s)")
    r.add_argument("--out", required=True, metavar="RIG.json", help="the rig file to write (JSON)")
    r.add_argument("--name", default=None, help="the rig file's name (default: the starting rig's, commissioned)")
    r.add_argument("--record", default=None, metavar="FILE.csv", help="also write the run's record (1 kHz CSV)")
    r.add_argument("--json", action="store_true", help="print the identification as JSON instead of a table")
    from .rig_key import add_link_flags

    add_link_flags(r)
    r.set_defaults(func=run)


def starting_rig(args):
    """(the rig description to start from, the rig with --rig-set, plant changes)."""
    from sim.engine import ISOLATOR_PARAMETERS
    from sim.rig import DEFAULT_RIG
    from sim.rigfile import RIG_FIELDS, RigDescription, load_rig_file, parse_assignment, with_assignments

    described = load_rig_file(args.rig_file) if args.rig_file else RigDescription(DEFAULT_RIG)
    declared = with_assignments(described.parameters, args.rig_set, "--rig-set")
    plant = dict(parse_assignment(a, RIG_FIELDS + ISOLATOR_PARAMETERS, "rig or isolator parameter")
                 for a in args.plant_set)
    return described, declared, plant


def run(args) -> int:
    from backend.drivers import rig_kind
    from backend.worker import run_here
    from sim.commission.identify import Conditions, excitation_limits, excitation_scenario, identify
    from sim.isolator import load_isolator
    from sim.profiles import check_supply
    from sim.rig import BAR_PA

    from .rig_run import resting_position_m, rig_job, run_job

    try:
        kind = rig_kind(args.rig)
    except ValueError as exc:
        raise UsageError(f"isorig identify rig: --rig: {exc}") from None
    if kind != "simulated" and args.plant_set:
        raise UsageError("isorig identify rig: --plant-set changes the simulated rig only; a real rig is as it is")
    out_path = Path(args.out)
    if out_path.suffix.lower() != ".json":
        raise UsageError(f"isorig identify rig: --out {out_path} must end in .json (a rig file is written as JSON)")
    described, declared, plant = starting_rig(args)
    isolator = load_isolator(args.isolator)
    supply_pa = args.supply_bar * BAR_PA
    check_supply(supply_pa, declared)
    load_n = args.vertical_load_n
    if load_n is None:
        load_n = isolator.design_vertical_load_n if isolator.design_vertical_load_n is not None \
            else declared.vertical_load_n
    start_m, options = 0.0, None
    if kind == "udp":
        from .rig_key import link_options, link_security

        options = link_options(link_security("identify rig", args.rig, args), args)
        start_m = resting_position_m("identify rig", args.rig, options)
    conditions = Conditions(args.rig, supply_pa, load_n, isolator.name, start_m, args.max_stroke_m,
                            args.max_velocity_m_per_s)
    scenario = excitation_scenario(isolator, conditions, declared, plant)
    scenario.validate()
    job = rig_job(args.rig, scenario, security=options)
    job["scenario"]["plant_changes"] = plant
    job["limits"] = {**job["limits"], **excitation_limits(conditions)}
    job["start_tolerance_m"] = 1e-3 if kind == "udp" else 1e-6
    print(f"commissioning {args.rig} at {args.supply_bar:g} bar, {isolator.name} mounted, vertical load "
          f"{load_n / 1e3:g} kN: the table moves at most +-{args.max_stroke_m * 1e3:g} mm about "
          f"{start_m * 1e3:.2f} mm, below {args.max_velocity_m_per_s * 1e3:g} mm/s, for at most "
          f"{scenario.duration_s:.0f} s (Ctrl-C stops it: valve closed)")
    if kind == "simulated":
        job.update(speed=SIMULATED_SPEED, realtime=False)
        started = dt.datetime.now(dt.UTC)
        _run, sent, status, reason = run_here(job)
    else:
        started = dt.datetime.now(dt.UTC)
        _run, sent, status, reason, _wall = run_job(job, interrupt="abort")
    samples = sent.samples()
    if args.record:
        from sim.records import write_csv

        write_csv(Path(args.record), samples)
    print(f"run {status}" + (f": {reason}" if reason else "") + f" after {len(samples) / 1000:.1f} s of rig time; "
          "fitting ...")
    ident = identify(samples, declared, conditions)
    if status != "completed":
        ident.problems.insert(0, f"the run ended {status}" + (f": {reason}" if reason else ""))
    return report(args, ident, described, started, out_path)


def report(args, ident, described, started, out_path: Path) -> int:
    """Print the identification; write the rig file when it is trusted. Exit 0 only then."""
    from sim.commission.identify import provenance
    from sim.rigfile import rig_file_data, write_rig_file

    if args.json:
        print(json.dumps(ident.to_dict(), default=float))
    else:
        print(format_identification(ident))
    if not ident.trusted:
        print(f"no rig file written: the fit cannot be trusted ({len(ident.problems)} reason(s) above)")
        retry = ident.second_attempt()
        if retry is not None and not args.json:
            print(f"a second attempt may help: run it again with --max-velocity-m-per-s "
                  f"{retry['max_velocity_m_per_s']:g} (the other options as before): {retry['why']}")
        return 1
    name = args.name or f"{described.name}, commissioned"
    data = rig_file_data(ident.rig, name[:100], f"commissioned by isorig identify rig on {args.rig} at "
                         f"{started.date().isoformat()}", provenance(ident, described.source, started),
                         always=tuple(ident.changed()))
    write_rig_file(out_path, data)
    print(f"wrote {out_path}: use it with --rig-file (isorig serve, simulate, move ...)")
    return 0


def format_identification(ident) -> str:
    """The fitted values beside the declared ones, with their uncertainties; the fit's figures; the verdict."""
    lines = []
    rec = ident.record
    lines.append(f"excitation: {rec.get('rig_time_s', 0):.1f} s, table within "
                 f"+-{rec.get('peak_excursion_m', 0) * 1e3:.2f} mm, |velocity| up to "
                 f"{rec.get('peak_velocity_m_per_s', 0) * 1e3:.1f} mm/s, |command| up to "
                 f"{rec.get('peak_command_v', 0):.2f} V")
    if ident.fit is not None:
        lines.append(f"{'parameter':32s} {'fitted':>12s} {'+- 1 sigma':>11s} {'declared':>12s}  unit")
        for name, e in ident.fit.estimates.items():
            declared = getattr(ident.declared, name, None)
            shown = f"{declared:12.5g}" if isinstance(declared, float) else f"{'-':>12s}"
            lines.append(f"{name:32s} {e.value:12.5g} {e.std:11.2g} {shown}  {e.unit}")
        r = ident.response
        lines.append(f"fit: flow balance R^2 {ident.fit.flow_r2:.5f}, force balance R^2 {ident.fit.force_r2:.4f}"
                     + (f"; replay of the dither: velocity {100 * r.velocity_nrmse:.1f} % RMS, load pressure "
                        f"{100 * r.pressure_nrmse:.1f} % RMS" if r else ""))
    if ident.trusted:
        lines.append("verdict: trusted")
    else:
        lines.append("verdict: NOT trusted")
        lines += [f"  - {p}" for p in ident.problems]
    return "\n".join(lines)
