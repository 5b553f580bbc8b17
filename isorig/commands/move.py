"""`isorig move`: move a rig's table to a position at a safe speed, without the service (manual motion).

Same loop, limits and stop paths as a test (backend.worker.run_here); the target is a minimum-jerk move
from where the rig says its table rests (sim.motion; the worker plans it again from the reading at arming). Ctrl-C
stops the move where it is (valve closed); a table that runs away from it is stopped by the move's guard
(sim.motion.MoveGuard: valve closed at once).
"""

from __future__ import annotations

from isorig.cli import UsageError


def register(sub) -> None:
    from sim.isolator import PRESETS
    from sim.motion import DEFAULT_SPEED_M_PER_S, MAX_DURATION_S, MAX_SPEED_M_PER_S, MIN_SPEED_M_PER_S

    p = sub.add_parser("move", help="move a rig's table to a position (default 0) at a safe speed")
    p.add_argument("--rig", required=True, help="udp://HOST:PORT (a real-time I/O target or `isorig rig-emulator`)")
    p.add_argument("--position-m", type=float, default=0.0, help="where to move the table, m (default 0: zero)")
    p.add_argument("--speed-m-per-s", type=float, default=DEFAULT_SPEED_M_PER_S,
                   help=f"peak speed of the move, m/s (default {DEFAULT_SPEED_M_PER_S:g}; {MIN_SPEED_M_PER_S:g} "
                        f"to {MAX_SPEED_M_PER_S:g}; a move lasts at most {MAX_DURATION_S:g} s)")
    p.add_argument("--isolator", default="IUT_a", help=f"the specimen mounted: a preset ({', '.join(PRESETS)})")
    p.add_argument("--supply-bar", type=float, default=100.0, help="supply pressure in bar (default 100)")
    p.add_argument("--rig-file", default=None, help="the rig file in force (what `isorig identify rig` wrote; default: "
                   "ISORIG_RIG_FILE, else isorig's default rig): the controller settles the table on it")
    p.add_argument("--rig-set", action="append", default=[], metavar="NAME=VALUE",
                   help="change one rig parameter (after --rig-file; repeatable)")
    from .rig_key import add_link_flags

    add_link_flags(p)
    p.set_defaults(func=run)


def rig_in_force(args):
    """(the rig description, its parameters with --rig-set): --rig-file, else ISORIG_RIG_FILE, else the defaults."""
    import os

    from sim.rig import DEFAULT_RIG
    from sim.rigfile import RigDescription, load_rig_file, with_assignments

    path = args.rig_file or os.environ.get("ISORIG_RIG_FILE")
    described = load_rig_file(path) if path else RigDescription(DEFAULT_RIG)
    return described, with_assignments(described.parameters, args.rig_set, "--rig-set")


def run(args) -> int:
    from backend.drivers import rig_kind
    from sim.engine import Scenario
    from sim.isolator import PRESETS
    from sim.motion import MotionError, check_move, check_speed, move_guard_m_per_s, move_target
    from sim.profiles import ProfileError
    from sim.rig import BAR_PA

    from .rig_run import resting_position_m, rig_job, run_job

    try:
        if rig_kind(args.rig) != "udp":
            raise ValueError("manual motion needs a rig that keeps its table where it is: udp://HOST:PORT")
    except ValueError as exc:
        raise UsageError(f"isorig move: --rig: {exc}") from None
    if args.isolator not in PRESETS:
        raise UsageError(f"isorig move: --isolator {args.isolator!r} is not a preset ({', '.join(PRESETS)})")
    try:
        check_speed(args.speed_m_per_s)  # before the rig is asked anything
    except MotionError as exc:
        raise UsageError(f"isorig move: --speed-m-per-s: {exc}") from None
    from .rig_key import link_options, link_security

    options = link_options(link_security("move", args.rig, args), args)
    start_m = resting_position_m("move", args.rig, options)
    described, rig = rig_in_force(args)
    try:
        check_move(start_m, args.position_m, args.speed_m_per_s, rig.stroke_m)
        scenario = Scenario(PRESETS[args.isolator], args.supply_bar * BAR_PA, [], "servo", rig=rig,
                            history=move_target(start_m, args.position_m, args.speed_m_per_s))
        scenario.validate()
    except (MotionError, ProfileError) as exc:
        raise UsageError(f"isorig move: {exc}") from None
    motion = {"start_m": start_m, "end_m": args.position_m, "speed_m_per_s": args.speed_m_per_s}
    job = rig_job(args.rig, scenario, security=options, motion=motion, history_target=None)
    print(f"moving the table on {args.rig} from {start_m * 1e3:.2f} mm to {args.position_m * 1e3:.2f} mm at "
          f"{args.speed_m_per_s * 1e3:g} mm/s ({scenario.duration_s:.1f} s; Ctrl-C stops it where it is; the valve "
          f"closes if the table runs faster than {move_guard_m_per_s(args.speed_m_per_s) * 1e3:.3g} mm/s); rig: "
          f"{described.name} ({described.source})")
    _run, sent, status, reason, wall_s = run_job(job, interrupt="stop")
    samples = sent.samples()
    end = float(samples["measured_displacement_m"][-1]) if len(samples) else start_m
    print(f"move {status}{': ' + reason if reason else ''}; the table is at {end * 1e3:.3f} mm, "
          f"{(end - args.position_m) * 1e3:+.3f} mm from the target ({wall_s:.1f} s)")
    return 0 if status == "completed" else 1
