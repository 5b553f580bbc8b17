"""`isorig rig-emulator`: the rig model in real time behind the UDP rig protocol, with fault injection."""

from __future__ import annotations

import gc
import os
import signal
import sys

from isorig.cli import UsageError


def register(sub) -> None:
    from sim.emulator.defects import DEFECTS
    from sim.isolator import PRESETS

    p = sub.add_parser("rig-emulator", help="run the rig model in real time behind the UDP rig protocol "
                       "(what a lab's real-time I/O target runs), until stopped")
    p.add_argument("--port", type=int, required=True, help="UDP port to listen on (0: any free port, printed)")
    p.add_argument("--host", default="127.0.0.1", help="interface to listen on (default 127.0.0.1)")
    p.add_argument("--isolator", default="IUT_a",
                   help=f"the specimen mounted: a preset ({', '.join(PRESETS)}) or an isolator .json file")
    p.add_argument("--period-s", type=float, default=1e-3, help="control period in s (default 0.001)")
    p.add_argument("--watchdog-ms", type=float, default=18.0,
                   help="no valid command for this long and the rig closes its valve (default 18 ms)")
    p.add_argument("--seed", type=int, default=0, help="seed of the injected faults' randomness and sensor noise")
    p.add_argument("--status-file", help="JSON file with the rig's counters and timings, rewritten twice a second")
    p.add_argument("--plant-file", metavar="FILE",
                   help="the rig it plays: a lab's rig file (.json or .toml of RigParameters names, SI) over isorig's "
                        "default rig; its supply, jack and command ranges are the ones ARM and COMMAND are checked "
                        "against")
    p.add_argument("--plant-set", action="append", default=[], metavar="NAME=VALUE",
                   help="change one parameter of the rig it plays (after --plant-file), e.g. piston_area_m2=0.02 "
                        "(repeatable)")
    p.add_argument("--foreign-rig", metavar="SEED", type=int, default=None,
                   help="play rig SEED of the foreign family (foreign_rigs: written from the physics, not from "
                        "isorig's model: valve lands, pump and accumulator, LuGre friction, its own specimen, a "
                        "load cell, late and noisy sensors; docs/commissioning.md, 'Foreign rigs') instead of "
                        "isorig's model; --isolator, --plant-file and --plant-set do not apply")
    from .rig_key import add_link_flags

    add_link_flags(p)
    g = p.add_argument_group("fault injection (times count from the ARM of the test)")
    g.add_argument("--packet-loss-pct", type=float, default=0.0, help="drop this share of datagrams, both ways")
    g.add_argument("--latency-ms", type=float, default=0.0, help="delay every measurement by this much")
    g.add_argument("--jitter-ms", type=float, default=0.0, help="... plus or minus up to this much (uniform)")
    g.add_argument("--drop-link-after-s", type=float, help="cut the link for good after this time")
    g.add_argument("--outage-every-s", type=float, metavar="S",
                   help="the link goes silent both ways for --outage-ms every S s (the first after S s): what a host "
                        "stalled that long looks like, repeatably")
    g.add_argument("--outage-ms", type=float,
                   help="how long each outage lasts (default 10 ms; with --outage-every-s)")
    g.add_argument("--overrun-ms", type=float, default=0.0, metavar="MS",
                   help="the rig itself stalls this long once, 30 ms after the ARM, in every other test (the first, "
                        "third ...): a rig's own overrun (docs/rig-protocol.md 1.6), repeatably")
    g.add_argument("--restart-after-s", type=float,
                   help="restart after this time: session and host forgotten, valve closed, silent until a new ARM")
    g.add_argument("--sensor-fault", choices=("stuck", "nan", "out-of-range"),
                   help="the position sensor sticks, reads NaN or reads out of range (silently)")
    g.add_argument("--sensor-fault-after-s", type=float, default=0.0, help="when the sensor fault begins")
    g.add_argument("--supply-loss-after-s", type=float, help="the pump stops: supply pressure decays from this time")
    g.add_argument("--supply-rise-s", type=float, metavar="S",
                   help="a pump that takes time: after ARM the supply pressure goes from the previous setting (0 at "
                        "the first ARM) towards the asked one with time constant S s, instead of at once "
                        "(docs/rig-protocol.md, 3.7)")
    d = p.add_argument_group("protocol defects (only for testing isorig check-rig: a rig that does not conform)")
    d.add_argument("--defect", action="append", default=[], choices=tuple(DEFECTS), metavar="NAME",
                   help="break one rule of docs/rig-protocol.md on purpose (repeatable): "
                        + "; ".join(f"{name}: {what}" for name, what in DEFECTS.items()))
    a = p.add_argument_group("the lab network as an attacker sees it (only for the link-attack tests)")
    a.add_argument("--tap-port", type=int, metavar="PORT",
                   help="send a copy of every datagram the rig receives or sends to 127.0.0.1:PORT, and open a "
                        "loopback port (printed) through which a forged datagram reaches the rig as if from its "
                        "host, or the host from the rig")
    p.set_defaults(func=run)


def plant(args):
    """(the rig parameters, their name, where they came from) from --plant-file and --plant-set."""
    from sim.rig import DEFAULT_RIG
    from sim.rigfile import load_rig_file, with_assignments

    described = load_rig_file(args.plant_file) if args.plant_file else None
    rig = described.parameters if described else DEFAULT_RIG
    try:
        rig = with_assignments(rig, args.plant_set, "--plant-set")
    except ValueError as exc:
        message = str(exc) if str(exc).startswith("--plant-set") else f"--plant-set: {exc}"
        raise UsageError(f"isorig rig-emulator: {message}") from None
    name = described.name if described else "isorig default rig"
    sources = ([described.source] if described else []) + [f"--plant-set {a}" for a in args.plant_set]
    return rig, name, ", ".join(sources) or "sim.rig defaults"


def run(args) -> int:
    from pathlib import Path

    from sim.emulator.auth import resolve_security
    from sim.emulator.server import GIL_SWITCH_INTERVAL_S, EmulatorConfig, Faults, RigEmulator
    from sim.isolator import load_isolator
    from sim.realtime import raise_priority

    try:
        security = resolve_security(args.host, args.rig_key_file, args.rig_protocol)
    except ValueError as exc:
        raise UsageError(f"isorig rig-emulator: {exc}") from None
    if args.outage_ms is not None and args.outage_every_s is None:
        raise UsageError("isorig rig-emulator: --outage-ms needs --outage-every-s (how often the link goes silent)")
    faults = Faults(args.packet_loss_pct, args.latency_ms, args.jitter_ms, args.drop_link_after_s,
                    args.restart_after_s, args.sensor_fault, args.sensor_fault_after_s, args.supply_loss_after_s,
                    args.supply_rise_s, args.outage_every_s,
                    Faults.outage_ms if args.outage_ms is None else args.outage_ms, args.overrun_ms)
    if args.status_file:  # said now: a status writer that failed in its thread left a rig running, unwatched
        folder = Path(args.status_file).resolve().parent
        if not folder.is_dir() or not os.access(folder, os.W_OK):
            raise UsageError(f"isorig rig-emulator: --status-file {args.status_file}: its folder {folder} does not "
                             "exist or cannot be written")
    rig, plant_name, plant_source = plant(args)
    foreign = None
    if args.foreign_rig is not None:
        from foreign_rigs import draw_rig

        if args.plant_file or args.plant_set:
            raise UsageError("isorig rig-emulator: --foreign-rig plays a rig of its own; leave out --plant-file and "
                             "--plant-set")
        try:
            foreign = draw_rig(args.foreign_rig)
        except ValueError as exc:
            raise UsageError(f"isorig rig-emulator: --foreign-rig: {exc}") from None
        plant_name, plant_source = foreign.name, f"foreign_rigs.draw_rig({args.foreign_rig})"
    config = EmulatorConfig(load_isolator(args.isolator), args.port, args.host, rig=rig, period_s=args.period_s,
                            watchdog_s=args.watchdog_ms / 1e3, seed=args.seed, faults=faults,
                            status_file=Path(args.status_file) if args.status_file else None,
                            plant_name=plant_name, plant_source=plant_source, defects=tuple(dict.fromkeys(args.defect)),
                            security=security, tap_port=args.tap_port, foreign_rig=foreign)
    try:
        emulator = RigEmulator(config)
    except ValueError as exc:  # a value out of its range (period, watchdog, tap port, ...): said, no traceback
        raise UsageError(f"isorig rig-emulator: {exc}") from None
    except OSError as exc:
        raise UsageError(f"isorig rig-emulator: cannot listen on {args.host}:{args.port}: {exc.strerror}") from None
    priority = raise_priority(20)  # above the worker's: the rig is the real-time target
    sys.setswitchinterval(GIL_SWITCH_INTERVAL_S)  # the tick loop takes the GIL back from the status writer at once
    stop = lambda *_: emulator.stop()  # noqa: E731
    signal.signal(signal.SIGTERM, stop)
    signal.signal(signal.SIGINT, stop)
    changed = config.plant()["changed"]
    plant_text = config.plant_name + (f" ({', '.join(f'{k}={v:g}' for k, v in changed.items())})" if changed else "")
    defects = f", DEFECTS {', '.join(config.defects)} (for testing check-rig)" if config.defects else ""
    if faults.supply_rise_s is not None:
        defects += f", pump rising to each ARM's supply with time constant {faults.supply_rise_s:g} s"
    if faults.overrun_ms:
        defects += f", OVERRUNS of {faults.overrun_ms:g} ms {faults.overrun_after_s * 1e3:g} ms after every other ARM"
    if faults.outage_every_s is not None:
        defects += f", OUTAGES of {faults.outage_ms:g} ms every {faults.outage_every_s:g} s while armed"
    if emulator.forge_port is not None:
        defects += (f", TAPPED to 127.0.0.1:{config.tap_port}, forging port {emulator.forge_port} (for the "
                    "link-attack tests)")
    link = (f"protocol 2, authenticated with {security.key_file}" if security.authenticated else
            f"protocol 1, NOT AUTHENTICATED ({security.why})")
    specimen = "its own specimen" if foreign is not None else f"isolator {config.isolator.name}"
    print(f"isorig rig-emulator: udp://{args.host}:{emulator.port}, {link}, {specimen}, plant "
          f"{plant_text}, period {config.period_s:g} s, watchdog {config.watchdog_s * 1e3:g} ms, priority "
          f"{priority}{defects}", file=sys.stderr, flush=True)
    # what exists now (the modules numpy, numba and the plant loaded: ~56 000 objects) is never scanned again: a
    # full collection over it took 9-12 ms, and came every few seconds as the ticks made garbage, so the rig's own
    # ticks slipped by as much (its longest tick lateness 9.7-27 ms in 10 tests of 60 s). The ticks' garbage is
    # still collected, over the young objects alone
    gc.freeze()
    try:
        emulator.serve()
    finally:
        emulator.close()
    counters = emulator.status()["counters"]
    print(f"isorig rig-emulator: stopped after {counters['ticks']} periods, {counters['arms']} test(s) armed",
          file=sys.stderr)
    return 0


