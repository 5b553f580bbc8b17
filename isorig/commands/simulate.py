"""`isorig simulate`: one closed-loop test -> timeseries.csv + summary.json.

On the simulated rig (default) the test runs in the compiled engine as fast as it can, judged by the service's
detectors with the rig's default limits and acted on as the service does (sim.detectors: the same rows, status
and reason as the service's worker; ``--no-limit-detectors`` leaves the limits out, for studies beyond them); with
``--rig udp://HOST:PORT`` the same test runs in real time through the UDP driver, with the service's loop,
detectors and stop paths (backend.worker.run_here), and the summary adds the link's figures. The summary says
the final status and its reason; the exit code is 0 only for a completed test whose table followed.
"""

from __future__ import annotations

import json
import time
from pathlib import Path

from isorig.cli import Progress, UsageError, output_folder, whole_number


def register(sub) -> None:
    from sim.controllers import CONTROLLER_NAMES, DEFAULT_CONTROLLER
    from sim.isolator import PRESETS

    p = sub.add_parser("simulate", help="run one closed-loop test on the simulated rig, or on a UDP rig in real time")
    p.add_argument("--isolator", default="IUT_a",
                   help=f"preset ({', '.join(PRESETS)}) or path to an isolator .json file")
    p.add_argument("--supply-bar", type=float, default=100.0, help="supply pressure in bar (default 100)")
    p.add_argument("--vertical-load-n", type=float, default=None,
                   help="vertical load on the specimen in N, 0 to the jack's 850 kN (default: the isolator's "
                        "design load, else 1.25e5 N as in the paper)")
    p.add_argument("--amplitude-m", type=float, default=0.02, help="sine amplitude in m (default 0.02)")
    p.add_argument("--frequency-hz", type=float, default=1.0, help="sine frequency in Hz (default 1)")
    p.add_argument("--cycles", type=whole_number, default=30, help="number of cycles (default 30)")
    p.add_argument("--taper-cycles", type=whole_number, default=1, help="ramp-in/out cycles (default 1)")
    p.add_argument("--offset-m", type=float, default=0.0, help="mean displacement in m (default 0)")
    p.add_argument("--controller", choices=CONTROLLER_NAMES, default=DEFAULT_CONTROLLER,
                   help=f"controller (default {DEFAULT_CONTROLLER})")
    p.add_argument("--controller-option", action="append", default=[], metavar="NAME=VALUE", type=option_pair,
                   help="override a controller default, e.g. dimensionless_as=true or gamma=5e4 (repeatable)")
    g = p.add_argument_group("earthquake tests: a time history instead of the sine (docs/earthquake.md)")
    g.add_argument("--history", metavar="FILE", help="a displacement history: CSV with time_s, displacement_m")
    g.add_argument("--ground-motion", metavar="FILE|NAME",
                   help="a ground acceleration record (CSV time_s, acceleration_m_per_s2, or PEER .AT2) or a "
                        "synthetic preset (near_field_short, far_field_long, soft_site); the isolator's "
                        "displacement demand under it (a rigid mass, the vertical load / g, on the isolator) "
                        "is the target")
    g.add_argument("--ground-motion-units", choices=("m/s2", "g", "cm/s2"),
                   help="units of a CSV ground motion (default: from its header, else m/s2)")
    g.add_argument("--scale", type=float, default=1.0, help="scale factor of the history or ground motion")
    g.add_argument("--taper-s", type=float, default=1.0, help="raised-cosine taper at each end in s (default 1)")
    p.add_argument("--rig-file", help="the lab's rig: a .json or .toml file of RigParameters names (SI) over the "
                   "defaults; what the controller assumes (docs/drivers.md)")
    p.add_argument("--rig-set", action="append", default=[], metavar="NAME=VALUE",
                   help="change one rig parameter (after --rig-file), e.g. position_latency_s=0.002 (repeatable)")
    p.add_argument("--plant-set", action="append", default=[], metavar="NAME=VALUE",
                   help="change the simulated plant only (the rig as it truly is, unknown to the controller): a "
                        "rig or isolator parameter, e.g. bulk_modulus_pa=5e8 (repeatable)")
    p.add_argument("--plant-change", action="append", default=[], metavar="TIME_S:NAME=VALUE",
                   help="change a rig or isolator parameter of the plant mid-test, e.g. 10:kd_n_per_m=6e5 "
                        "(repeatable)")
    p.add_argument("--out", required=True, help="output directory for timeseries.csv and summary.json")
    add_detector_flag(p)
    add_follow_flag(p)
    p.add_argument("--rig", default="simulated",
                   help="'simulated' (default: the compiled engine, faster than real time) or udp://HOST:PORT "
                        "(a real-time I/O target or `isorig rig-emulator`, in real time)")
    p.add_argument("--link-timeout-s", type=float, default=0.05,
                   help="UDP rig: a link silent this long ends the test failed (default 0.05 s)")
    from .rig_key import add_link_flags

    add_link_flags(p)
    p.set_defaults(func=run)


def add_detector_flag(p) -> None:
    """--no-limit-detectors: the opt-out of the service's limits on the simulated rig."""
    p.add_argument("--no-limit-detectors", action="store_true",
                   help="simulated rig: run past the rig's default limits (stroke, force, the velocity the pump "
                        "can feed, load pressure, tracking error) and the sensor detectors, which the service "
                        "applies to every test and which this command applies by default; the run then gets a "
                        "verdict the service would not give it (the follow detector stays)")


FOLLOW_CHOICES = {"stop": "controlled_stop", "indicate": "indicate"}  # --follow -> limits.actions.follow


def add_follow_flag(p) -> None:
    """--follow stop|indicate: the action of the detector of a table that does not follow (sim.follow)."""
    p.add_argument("--follow", choices=tuple(FOLLOW_CHOICES), default="stop",
                   help="when the table does not follow its target (an oscillation, or tracking the learning does "
                        "not bring within 1 %% of the amplitude): stop the test (default: a controlled stop, the "
                        "valve closed at once on an oscillation) or indicate (an event, the test runs to its end "
                        "and the tracking verdict says how well it followed; e.g. the paper's --controller mrac)")


def limits_with_follow(rig, follow: str):
    """The rig's default limits with the follow detector's action of ``--follow`` (sim.safety.SafetyLimits)."""
    from sim.safety import make_limits

    return make_limits(rig, {"actions": {"follow": FOLLOW_CHOICES[follow]}})


def print_follow_indications(summary: dict) -> None:
    """The follow detector's indications of a run set to indicate (``--follow indicate``)."""
    seen = [i for i in summary.get("limit_indications", []) if i["detector"] == "not_following"]
    for i in seen:
        print(f"follow detector (set to indicate): {i['message']}")


def history_target(args, scenario):
    """The time history of --history or --ground-motion, prepared for the rig (sim.history)."""
    from sim.ground_motion import GROUND_MOTIONS, synthetic_ground_motion
    from sim.history import isolation_displacement, prepare_history, read_displacement_csv, read_ground_motion

    if args.history and args.ground_motion:
        raise UsageError("isorig simulate: give --history or --ground-motion, not both")
    if args.history:
        t, d = read_displacement_csv(args.history)
        return prepare_history(t, d, scale=args.scale, taper_in_s=args.taper_s, taper_out_s=args.taper_s,
                               source=str(args.history))
    if args.ground_motion in GROUND_MOTIONS:
        t, acc, _info = synthetic_ground_motion(args.ground_motion)
    else:
        t, acc = read_ground_motion(args.ground_motion, args.ground_motion_units)
    mass_kg = scenario.effective_vertical_load_n / 9.80665
    if mass_kg <= 0:
        raise UsageError("isorig simulate: a ground motion needs a vertical load above 0 N (the mass it carries)")
    d = isolation_displacement(t, args.scale * acc, scenario.isolator, mass_kg)
    return prepare_history(t, d, taper_in_s=args.taper_s, taper_out_s=args.taper_s,
                           source=f"{args.ground_motion} x {args.scale:g} through {scenario.isolator.name} under "
                                  f"{mass_kg:.0f} kg")


def rig_arguments(args):
    """(the rig the controller assumes, plant-only changes, timed plant changes) from the rig flags."""
    from sim.engine import ISOLATOR_PARAMETERS
    from sim.rig import DEFAULT_RIG
    from sim.rigfile import RIG_FIELDS, load_rig_file, parse_assignment, with_assignments

    rig = load_rig_file(args.rig_file).parameters if args.rig_file else DEFAULT_RIG
    rig = with_assignments(rig, args.rig_set, "--rig-set")
    allowed = RIG_FIELDS + ISOLATOR_PARAMETERS
    plant = dict(parse_assignment(a, allowed, "rig or isolator parameter") for a in args.plant_set)
    timed = []
    for text in args.plant_change:
        when, sep, assignment = text.partition(":")
        try:
            t_s = float(when)
        except ValueError:
            t_s = None
        if not sep or t_s is None:
            raise UsageError(f"isorig simulate: --plant-change {text!r} is not TIME_S:NAME=VALUE "
                             "(e.g. 10:kd_n_per_m=6e5)")
        timed.append((t_s, *parse_assignment(assignment, allowed, "rig or isolator parameter")))
    return rig, plant, timed


def option_pair(text: str) -> tuple[str, float | bool]:
    """NAME=VALUE with a number or true/false."""
    import argparse

    name, sep, raw = text.partition("=")
    if not sep or not name:
        raise argparse.ArgumentTypeError(f"{text!r} is not NAME=VALUE")
    if raw.lower() in ("true", "false"):
        return name, raw.lower() == "true"
    try:
        return name, float(raw)
    except ValueError:
        raise argparse.ArgumentTypeError(f"value of {name!r} must be a number or true/false, not {raw!r}") from None


def run(args) -> int:
    from sim.engine import Scenario, Simulation
    from sim.records import write_csv

    rig, plant_changes, timed_changes = rig_arguments(args)
    scenario = Scenario.sine(args.isolator, args.supply_bar, args.amplitude_m, args.frequency_hz, args.cycles,
                             controller=args.controller, taper_cycles=args.taper_cycles, offset_m=args.offset_m,
                             controller_options=dict(args.controller_option), vertical_load_n=args.vertical_load_n,
                             rig=rig, plant_changes=plant_changes, timed_changes=timed_changes)
    if args.rig_file:  # a commissioned rig file: the follow monitor and the verdict use how it was measured
        from sim.rigfile import load_rig_file

        scenario.rig_commissioning = load_rig_file(args.rig_file).commissioning
    if args.history or args.ground_motion:
        import dataclasses

        scenario = dataclasses.replace(scenario, profile=[], history=history_target(args, scenario))
    if args.rig != "simulated" and args.no_limit_detectors:
        raise UsageError("isorig simulate: --no-limit-detectors applies to the simulated rig only: a test on a rig "
                         "always runs with its limits")
    scenario.validate()
    limits = None if args.no_limit_detectors else limits_with_follow(scenario.rig, args.follow)
    check_start(scenario, limits)
    out = output_folder(args.out, "isorig simulate")
    if args.rig != "simulated":
        return run_on_rig(args, scenario, out)
    progress = Progress(f"simulating {scenario.duration_s:g} s")
    t0 = time.perf_counter()
    result = Simulation(scenario, validate=False).run(progress=progress, follow=True, limits=limits,
                                                      follow_action=FOLLOW_CHOICES[args.follow])
    progress.close()
    elapsed = time.perf_counter() - t0
    write_csv(out / "timeseries.csv", result.samples, controller=scenario.controller)
    summary = result.summary()
    summary["wall_time_s"] = elapsed
    summary["limit_detectors"] = limits is not None
    (out / "summary.json").write_text(json.dumps(summary, indent=2))
    if "criteria" in summary:
        c = summary["criteria"]
        print(f"wrote {out / 'timeseries.csv'} ({len(result.samples)} samples) and {out / 'summary.json'}")
        print(f"J1 delay {c['j1_delay_ms']:.3f} ms, J3 peak error {c['j3_peak_percent']:.2f} %  (sim.hybrid_metrics; "
              "J2 is the tracking error below)")
        return outcome(result, summary)
    print(f"wrote {out / 'timeseries.csv'} ({len(result.samples)} samples) and {out / 'summary.json'}")
    print(raw_figures(summary) + f"; saturated samples {100 * summary['saturated_share']:.2f} %")
    return outcome(result, summary)


def raw_figures(summary: dict) -> str:
    """The raw |y - r| figures, named as such (sim.tracking_figure.RAW_NAME): not the tracking figure."""
    from sim.tracking_figure import RAW_NAME

    last = summary.get("last_two_cycles", {})
    return (f"{RAW_NAME}: RMS {summary.get('rms_y_minus_r_m', float('nan')) * 1e3:.3f} mm over the run"
            + (f", {last['rms_y_minus_r_m'] * 1e3:.3f} mm over its last two cycles" if last else ""))


def check_start(scenario, limits) -> None:
    """Refuse, before anything runs, a sine whose untapered start is expected to trip a limit (sim.profiles.
    start_problem: the service's set-up check refuses it the same way); ``limits`` None (--no-limit-detectors):
    nothing to trip."""
    from sim.profiles import start_problem

    problem = start_problem(scenario, limits, override="--no-limit-detectors to run it past the rig's limits")
    if problem is not None:
        raise UsageError(f"isorig simulate: --taper-cycles {problem.value}: {problem}")


def outcome(result, summary: dict) -> int:
    """Print how the test ended (the service's status and reason) and its tracking verdict; the exit code: 0
    only for a test that ran to its end and whose table followed (within the 1 % the service allows,
    sim.follow)."""
    print_follow_indications(summary)
    print(f"test {result.status}" + (f": {result.reason}" if result.reason else "")
          + ("" if summary.get("limit_detectors", True) else " (without the limit detectors: --no-limit-detectors)"))
    from sim.tracking_figure import tracking_line

    verdict = summary.get("tracking_verdict", {})
    print(tracking_line(verdict))  # the one tracking figure (docs/metrics.md, "The tracking figure")
    return 1 if result.status != "completed" or verdict.get("verdict") == "did_not_follow" else 0


def run_on_rig(args, scenario, out: Path) -> int:
    """The test in real time on the rig ``args.rig`` through its driver; same files as the engine's run."""
    from backend.drivers import rig_kind
    from sim.engine import Result
    from sim.records import write_csv

    from .rig_key import link_options, link_security
    from .rig_run import check_start_position, rig_job, run_job

    try:
        rig_kind(args.rig)
    except ValueError as exc:
        raise UsageError(f"isorig simulate: --rig: {exc}") from None
    if not (0 < args.link_timeout_s <= 5):
        raise UsageError(f"isorig simulate: --link-timeout-s {args.link_timeout_s:g} is outside (0, 5] s")
    security, options = None, None
    if args.rig.startswith("udp://"):
        security = link_security("simulate", args.rig, args)
        options = link_options(security, args)
        check_start_position("simulate", args.rig, security=options)
    job = rig_job(args.rig, scenario, args.link_timeout_s, security=options)
    job["limits"] = limits_with_follow(scenario.rig, args.follow).to_dict()
    print(f"running {scenario.duration_s:g} s in real time on {args.rig} (Ctrl-C aborts)"
          + ("" if security is None or security.authenticated else
             f"; rig link NOT AUTHENTICATED (protocol 1: {security.why})"))
    run, sent, status, reason, wall_s = run_job(job)  # Ctrl-C: abort the test, valve closed, files written
    samples = sent.samples()
    write_csv(out / "timeseries.csv", samples, controller=scenario.controller)
    summary = Result(scenario, samples, diverged=False).summary()  # the worker's detectors stopped it, if at all
    summary.update(rig=args.rig, status=status, reason=reason, wall_time_s=wall_s,
                   lost_periods=run.lost_periods, link=run.driver.link_stats(), pacing=run.pacing(),
                   events=sent.of_kind("event"))
    (out / "summary.json").write_text(json.dumps(summary, indent=2, default=float))
    from sim.tracking_figure import tracking_line

    print(f"wrote {out / 'timeseries.csv'} ({len(samples)} samples) and {out / 'summary.json'}")
    print(f"test {status}" + (f": {reason}" if reason else "") + f"; {run.lost_periods} period(s) lost on the link")
    print(raw_figures(summary))
    print(tracking_line(summary.get("tracking_verdict")))  # the one tracking figure (docs/metrics.md)
    return 0 if status == "completed" else 1
