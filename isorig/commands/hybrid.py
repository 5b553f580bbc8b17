"""`isorig hybrid`: real-time hybrid simulation of a base-isolated building (docs/earthquake.md).

The building above the isolator is integrated in the computer, one control period at a time; the isolator
is the specimen on the rig. On the simulated rig (default) this is a virtual RTHS, run as fast as it goes
through the service's own loop, detectors and stop paths (backend.worker.run_here on the simulated rig, with
the rig's default limits: the verdict the service gives the test; ``--no-limit-detectors``: the bare loop of
sim.hybrid.run_virtual, with the stability monitor only). The full-numerical reference (the same building
with the isolator's Bouc-Wen model) is computed offline and compared: J4 and J5. Writes timeseries.csv (the
record's columns and the building's channels) and summary.json (J1-J5, the stability monitor, the
reference's peaks, the status and its reason).
"""

from __future__ import annotations

import json
import time

from isorig.cli import UsageError, output_folder


def register(sub) -> None:
    from sim.controllers import CONTROLLER_NAMES, DEFAULT_CONTROLLER
    from sim.isolator import PRESETS

    p = sub.add_parser("hybrid", help="real-time hybrid simulation: a building in the computer on the isolator "
                                      "on the rig, under a ground motion")
    p.add_argument("--structure", required=True, metavar="FILE",
                   help="the building above the isolator: JSON with base_mass_kg, masses_kg, stiffness_n_per_m, "
                        "damping_ratio")
    p.add_argument("--ground-motion", required=True, metavar="FILE|NAME",
                   help="ground acceleration: CSV time_s, acceleration_m_per_s2, a PEER .AT2 file, or a synthetic "
                        "preset (near_field_short, far_field_long, soft_site)")
    p.add_argument("--ground-motion-units", choices=("m/s2", "g", "cm/s2"),
                   help="units of a CSV ground motion (default: from its header, else m/s2)")
    p.add_argument("--scale", type=float, default=1.0, help="scale factor of the ground motion (default 1)")
    p.add_argument("--isolator", default="IUT_a",
                   help=f"the specimen: a preset ({', '.join(PRESETS)}) or an isolator .json file")
    p.add_argument("--supply-bar", type=float, default=100.0, help="supply pressure in bar (default 100)")
    p.add_argument("--vertical-load-n", type=float, default=None,
                   help="vertical load on the specimen, N (default: the building's weight on the isolator)")
    p.add_argument("--controller", choices=CONTROLLER_NAMES, default=DEFAULT_CONTROLLER)
    p.add_argument("--rig", default="simulated",
                   help="'simulated' (default: virtual RTHS, as fast as it runs) or udp://HOST:PORT (a real-time "
                        "I/O target or `isorig rig-emulator`, in real time)")
    p.add_argument("--out", required=True, help="output directory for timeseries.csv and summary.json")
    from .simulate import add_follow_flag

    add_follow_flag(p)
    p.add_argument("--no-limit-detectors", action="store_true",
                   help="simulated rig: run the bare hybrid loop, past the rig's default limits and the sensor and "
                        "follow detectors that the service applies to every test and this command applies by "
                        "default (the stability monitor stays)")
    from .rig_key import add_link_flags

    add_link_flags(p)
    p.set_defaults(func=run)


def _on_rig(args, building, ag, scenario):
    """The hybrid test in real time on a rig through its driver (backend.worker.run_here)."""
    from backend.drivers import rig_kind

    from .rig_run import check_start_position, rig_job, run_job
    from .simulate import limits_with_follow

    try:
        rig_kind(args.rig)
    except ValueError as exc:
        raise UsageError(f"isorig hybrid: --rig: {exc}") from None
    from .rig_key import link_options, link_security

    security = link_security("hybrid", args.rig, args)
    check_start_position("hybrid", args.rig, security=link_options(security, args))
    # the scenario's history (the reference's base displacement) puts the servo in its history mode, as in
    # the virtual RTHS; the targets themselves come from the building, period by period
    job = rig_job(args.rig, scenario, security=link_options(security, args),
                  hybrid={"building": building.to_dict(), "ground_acc_m_per_s2": ag})
    job["limits"] = limits_with_follow(scenario.rig, args.follow).to_dict()
    print(f"running {ag.size / 1000:g} s of hybrid simulation in real time on {args.rig} (Ctrl-C aborts)"
          + ("" if security.authenticated else f"; rig link NOT AUTHENTICATED (protocol 1: {security.why})"))
    run, sent, status, reason, _wall_s = run_job(job)
    return run.hybrid, sent.samples(), (None if status == "completed" else f"{status}: {reason}")


def _check_vertical_load(args, building) -> None:
    """The vertical load within the jack's range, before anything is computed: without --vertical-load-n it is
    the building's weight, and a building heavier than the jack is refused saying so (UsageError: exit 2)."""
    from sim.earthquake import too_heavy_for_the_jack
    from sim.profiles import check_vertical_load
    from sim.rig import DEFAULT_RIG
    from sim.structure import G_M_PER_S2

    if args.vertical_load_n is not None:
        check_vertical_load(args.vertical_load_n, DEFAULT_RIG)  # ProfileError names the field and its range
        return
    why = too_heavy_for_the_jack(building.total_mass_kg * G_M_PER_S2, DEFAULT_RIG.max_vertical_load_n)
    if why is not None:
        raise UsageError(f"isorig hybrid: {why}")


def _simulated(building, ag, scenario, follow: str = "stop"):
    """The hybrid test on the simulated rig through the service's worker (backend.worker.run_here), as fast as
    it runs: its detectors with the rig's default limits (the follow detector's action of ``--follow``), its stop
    paths, its status and reason."""
    from .rig_run import rig_job, run_job
    from .simulate import limits_with_follow

    job = rig_job("simulated", scenario, hybrid={"building": building.to_dict(), "ground_acc_m_per_s2": ag})
    job["limits"] = limits_with_follow(scenario.rig, follow).to_dict()
    job.update(speed=1e6, realtime=False)  # not paced: the simulated rig runs as fast as it goes
    run, sent, status, reason, _wall_s = run_job(job)
    return run.hybrid, sent.samples(), (None if status == "completed" else f"{status}: {reason}"), status


def run(args) -> int:
    import numpy as np

    from sim.controllers import make_controller
    from sim.engine import Scenario
    from sim.follow import advice_for, tracking_verdict
    from sim.ground_motion import GROUND_MOTIONS, synthetic_ground_motion
    from sim.history import read_ground_motion
    from sim.hybrid import (
        HybridSubstructure,
        compare_with_reference,
        ground_at_periods,
        predicted_history,
        reference,
        run_virtual,
    )
    from sim.isolator import load_isolator
    from sim.plant import SimulatedPlant
    from sim.records import samples_to_csv
    from sim.structure import load_structure
    from sim.tracking_figure import tracking_line

    from .simulate import FOLLOW_CHOICES

    building = load_structure(args.structure)
    _check_vertical_load(args, building)
    if args.ground_motion in GROUND_MOTIONS:
        t, acc, _info = synthetic_ground_motion(args.ground_motion)
    else:
        t, acc = read_ground_motion(args.ground_motion, args.ground_motion_units)
    if not (0.0 < args.scale <= 10.0):
        raise UsageError(f"isorig hybrid: --scale {args.scale:g} is outside (0, 10]")
    ag = ground_at_periods(t, args.scale * acc)
    isolator = load_isolator(args.isolator)
    load_n = args.vertical_load_n if args.vertical_load_n is not None else building.total_mass_kg * 9.80665
    ref = reference(building, isolator, ag)
    # the rig's envelope, checked on the reference's base displacement before anything moves
    predicted = predicted_history(ref)  # the base displacement, then the table at rest
    scenario = Scenario(isolator, args.supply_bar * 1e5, [], args.controller, vertical_load_n=load_n,
                        history=predicted)
    scenario.validate()
    if args.no_limit_detectors and args.rig != "simulated":
        raise UsageError("isorig hybrid: --no-limit-detectors applies to the simulated rig only: a test on a rig "
                         "always runs with its limits")
    out = output_folder(args.out, "isorig hybrid")

    t0 = time.perf_counter()
    if args.rig == "simulated" and not args.no_limit_detectors:
        sub, samples, stopped, status = _simulated(building, ag, scenario, args.follow)
    elif args.rig == "simulated":
        sub = HybridSubstructure(building, isolator, ag)
        controller = make_controller(scenario.controller, rig=scenario.rig,
                                     **scenario.effective_controller_options())
        from sim.loop import ClosedLoop

        loop = ClosedLoop([], controller, scenario.rig.command_limit_v, table=sub.target_table())
        plant = SimulatedPlant(scenario.plant_rig, isolator, scenario.supply_pa)
        samples, stopped = run_virtual(sub, loop, plant)
        status = "stopped" if stopped else "completed"
    else:
        sub, samples, stopped = _on_rig(args, building, ag, scenario)
        status = stopped.split(":")[0] if stopped else "completed"
    elapsed = time.perf_counter() - t0
    closed = np.isfinite(samples["target_m"]) & np.isfinite(samples["displacement_m"])
    if stopped and not closed.all():  # ended by a trip or a fault: the criteria over the closed-loop part only
        samples = samples[: int(np.argmin(closed)) if not closed[0] or not closed.all() else len(samples)]
    res = sub.results(samples)
    j45 = compare_with_reference(res, ref)
    text = samples_to_csv(samples).splitlines()
    n = len(samples)
    header = text[0] + "," + ",".join(sub.names)
    rows = [line + "," + ",".join(f"{res[name][i]:.9g}" if i < len(res[name]) else "" for name in sub.names)
            for i, line in enumerate(text[1:n + 1])]
    (out / "timeseries.csv").write_text("\n".join([header, *rows]).replace("nan", "") + "\n")
    summary = {"structure": building.to_dict(), "ground_motion": args.ground_motion, "scale": args.scale,
               "scenario": scenario.describe(), "status": status,
               "limit_detectors": not args.no_limit_detectors, "follow_action": FOLLOW_CHOICES[args.follow],
               "reason": stopped, "criteria": {**res["criteria"], **j45}, "lost_periods": res["lost_periods"],
               "stability": res["stability"],
               "reference_peaks": {k: float(np.max(np.abs(v))) for k, v in ref.items()
                                   if k.endswith(("_m", "_n", "_m_per_s2")) and np.ndim(v) == 1},
               "wall_time_s": elapsed}
    (out / "summary.json").write_text(json.dumps(summary, indent=2, default=float))
    c = summary["criteria"]
    print(f"wrote {out / 'timeseries.csv'} ({n} samples) and {out / 'summary.json'}")
    print(f"{status}" + (f" ({stopped})" if stopped else "")
          + f"; J1 {c['j1_delay_ms']:.3f} ms, J3 {c['j3_peak_percent']:.2f} %; "
          f"against the reference: J4 {c['j4_rms_percent']:.2f} %, J5 {c['j5_peak_percent']:.2f} %"
          + (f"; {res['lost_periods']} periods lost (J2, J3 over the periods measured)" if res["lost_periods"] else ""))
    # the one tracking figure (docs/metrics.md, "The tracking figure"): a history's verdict rests on J2
    print(tracking_line(tracking_verdict([], [], history_criteria=c, advice=advice_for(scenario.controller))))
    return 0 if not stopped else 1
