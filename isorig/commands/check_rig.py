"""`isorig check-rig udp://HOST:PORT`: a lab's real-time I/O target against docs/rig-protocol.md, rule by rule
(the check itself: backend/drivers/rig_check/)."""

from __future__ import annotations

import json
import sys

from isorig.cli import UsageError


def register(sub) -> None:
    p = sub.add_parser(
        "check-rig", help="check a rig's real-time I/O target (any language) against the rig protocol: one row per "
        "rule of docs/rig-protocol.md, exit code 0 only if every rule passes",
        description="Checks a rig's real-time I/O target against docs/rig-protocol.md over raw UDP: HELLO, ARM "
        "and its refusals, sessions, sequences, every drop reason, DISARM, the watchdog's time and the period. The "
        "rig must be idle (not armed). Without --motion every command sent is 0.0 V, apart from the ones a "
        "conforming rig must refuse and never applies (NaN, infinite, 1.2 x the command limit); ARMs outside the "
        "rig's ranges are sent too, and a conforming rig refuses them.")
    p.add_argument("rig", metavar="udp://HOST:PORT", help="the rig's target (or isorig rig-emulator)")
    p.add_argument("--motion", action="store_true",
                   help="also move the table a little: --motion-v until it has moved 0.3 mm, then back at minus "
                        "--motion-v (0 V at once beyond 1 mm), to check the direction of the command, the signs of "
                        "load_pressure_pa and force_n, and the position a HELLO reports")
    p.add_argument("--motion-v", type=float, default=1.5,
                   help="the command of --motion in V (default 1.5; beyond the valve's dead zone, at most 3 V)")
    p.add_argument("--json", action="store_true", help="print the report as JSON instead of the table")
    p.add_argument("--timeout-s", type=float, default=1.0,
                   help="how long to wait for the rig's first answer to HELLO and to ARM (default 1 s)")
    p.add_argument("--rig-file", metavar="FILE",
                   help="the lab's rig file (the service's): the supply and jack ranges and the command limit the "
                        "target must refuse beyond (default: isorig's rig: 10-210 bar, 850 kN, +-10 V)")
    p.add_argument("--rig-set", action="append", default=[], metavar="NAME=VALUE",
                   help="change one rig parameter (after --rig-file), e.g. max_supply_pa=150e5 (repeatable)")
    p.add_argument("--supply-bar", type=float, default=20.0,
                   help="supply pressure of the check's ARMs (default 20 bar; within the rig's range)")
    p.add_argument("--vertical-load-n", type=float, default=0.0,
                   help="vertical load of the check's ARMs (default 0 N: the jack not loaded)")
    p.add_argument("--period-s", type=float, default=1e-3,
                   help="the control period the service is set for (ISORIG_RIG_PERIOD_S, default 0.001 s)")
    from .rig_key import add_link_flags

    add_link_flags(p)
    p.set_defaults(func=run)


def run(args) -> int:
    from backend.drivers.rig_check import RigCheck, RigUnreachable
    from sim.rig import DEFAULT_RIG
    from sim.rigfile import load_rig_file, with_assignments

    prog = "isorig check-rig"
    rig = load_rig_file(args.rig_file).parameters if args.rig_file else DEFAULT_RIG
    rig = with_assignments(rig, args.rig_set, "--rig-set")
    from .rig_key import link_security

    security = link_security("check-rig", args.rig, args)
    try:
        check = RigCheck(args.rig, rig, supply_pa=args.supply_bar * 1e5, vertical_load_n=args.vertical_load_n,
                         period_s=args.period_s, timeout_s=args.timeout_s, motion=args.motion,
                         motion_v=args.motion_v, security=security)
    except ValueError as exc:
        raise UsageError(f"{prog}: {exc}") from None
    try:
        report = check.run()  # at real-time priority for the check only (RigCheck.run)
    except RigUnreachable as exc:
        if args.json:
            print(json.dumps({"rig": args.rig, "ok": False, "error": str(exc)}, indent=1))
        print(f"{prog}: {exc}", file=sys.stderr)
        return 1
    if args.json:
        print(json.dumps(report.to_dict(), indent=1))
    else:
        commands = (f"motion at +-{args.motion_v:g} V" if args.motion else
                    "no motion: every command 0.0 V except the ones a conforming rig refuses")
        link = (f"rig protocol 2, authenticated with {security.key_file}" if security.authenticated else
                f"rig protocol 1, NOT AUTHENTICATED ({security.why})")
        print(f"{prog} {args.rig}: {link}; ARMs at {args.supply_bar:g} bar, {args.vertical_load_n:g} N; {commands}")
        print(report.table())
    return 0 if report.ok else 1
