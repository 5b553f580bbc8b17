"""`isorig identify`: step-test fits of eq. (7) (Tables III/IV), Bouc-Wen fits of eq. (4) from records, and the
commissioning of a rig (`identify rig`, isorig/commands/identify_rig.py)."""

from __future__ import annotations

import json
import re
import time
from pathlib import Path

from isorig.cli import UsageError


def register(sub) -> None:
    from sim.isolator import PRESETS

    p = sub.add_parser("identify", help="identify eq. (7) from step tests or eq. (4) from a force-displacement record")
    isub = p.add_subparsers(dest="identify_command", required=True, parser_class=type(p))

    s = isub.add_parser("steps", help="fit eq. (7)'s a_p, a_s to step tests (the paper's Tables III/IV)")
    s.add_argument("--isolator", default="IUT_a",
                   help=f"preset ({', '.join(PRESETS)}) or an isolator .json file (default IUT_a)")
    s.add_argument("--supply-bar", type=float, nargs="+", default=[20.0, 30.0, 40.0],
                   help="supply pressures in bar (default 20 30 40)")
    s.add_argument("--step-v", type=float, nargs="+", default=[2.0, 4.0, 6.0],
                   help="step voltages in V (default 2 4 6)")
    s.add_argument("--duration-s", type=float, default=None, help="length of each simulated step test (default 10)")
    s.add_argument("--vertical-load-n", type=float, default=None,
                   help="vertical load on the specimen in N (friction mu N + F_c of eq. 1), 0 to the jack's capacity "
                        "(850 kN); default: the load fitted to the isolator's paper table for IUT_a and IUT_b "
                        "(sim.identify_steps.PAPER_TABLE_VERTICAL_LOAD_N), else the isolator's design load, else "
                        "the rig's")
    s.add_argument("--rig-file", default=None, metavar="FILE",
                   help="the lab's rig: a .json or .toml file of RigParameters names (SI) over the defaults; the "
                        "step tests are simulated on it (docs/drivers.md)")
    s.add_argument("--rig-set", nargs="+", default=[], metavar="NAME=VALUE",
                   help="override rig parameters (SI, names as in sim/rig.py RigParameters; after --rig-file), "
                        "e.g. piston_area_m2=0.01246")
    s.add_argument("--csv", default=None,
                   help="fit one measured step instead (columns time_s, voltage_v, displacement_m)")
    s.add_argument("--json", action="store_true", help="print JSON instead of a table")
    s.set_defaults(func=run_steps)

    b = isub.add_parser("bouc-wen", help="fit eq. (4) (rho_bw, sigma_bw, n, kd, kw) to a force-displacement record")
    b.add_argument("file", help="CSV with columns time_s, displacement_m, force_n (e.g. isorig simulate's "
                                "timeseries.csv; other columns are ignored)")
    b.add_argument("--json", action="store_true", help="print one JSON object")
    b.add_argument("--save-isolator", default=None, metavar="OUT.json",
                   help="save the identified isolator for `isorig simulate --isolator OUT.json`")
    b.add_argument("--name", default=None, help="name of the saved isolator (default: from the file name)")
    b.set_defaults(func=run_bouc_wen)

    from . import identify_rig

    identify_rig.register(isub, type(p))


# ---------------------------------------------------------------------------------------------------
# steps
# ---------------------------------------------------------------------------------------------------

def run_steps(args) -> int:
    if args.csv:
        if args.rig_file is not None:
            raise UsageError("isorig identify steps: --rig-file sets the rig of the simulated step tests; a measured "
                             "step (--csv) is fitted as recorded")
        return _fit_csv(args)
    from sim.identify_steps import (
        STEP_DURATION_S,
        compare_with_paper,
        default_step_vertical_load_n,
        paper_a_s_floor,
        step_grid,
        targets_check,
        warm_up,
    )
    from sim.isolator import load_isolator
    from sim.rig import BAR_PA, DEFAULT_RIG

    iso = load_isolator(args.isolator)
    described = None
    if args.rig_file is not None:
        from sim.rigfile import load_rig_file

        described = load_rig_file(args.rig_file)  # a RigError (exit 2, one line) if it is not a rig
    rig = rig_with_overrides(described.parameters if described is not None else DEFAULT_RIG, args.rig_set)
    for bar in args.supply_bar:
        if not (rig.min_supply_pa <= bar * BAR_PA <= rig.max_supply_pa):
            raise UsageError(f"isorig identify steps: --supply-bar {bar:g} is outside the rig's range "
                             f"[{rig.min_supply_pa / BAR_PA:g}, {rig.max_supply_pa / BAR_PA:g}] bar")
    for v in args.step_v:
        if not (0.0 < abs(v) <= rig.command_limit_v):
            raise UsageError(f"isorig identify steps: --step-v {v:g} must be non-zero and within "
                             f"+-{rig.command_limit_v:g} V")
    duration = STEP_DURATION_S if args.duration_s is None else args.duration_s
    if not (1.0 <= duration <= 120.0):
        raise UsageError(f"isorig identify steps: --duration-s {duration:g} must be within [1, 120] s")
    load_n = checked_vertical_load_n(args.vertical_load_n, rig)
    if load_n is None:
        load_n = default_step_vertical_load_n(iso, rig)
    warm_up()
    t0 = time.perf_counter()
    rows = compare_with_paper(step_grid(rig, iso, args.supply_bar, args.step_v, duration, vertical_load_n=load_n),
                              iso.name)
    elapsed = time.perf_counter() - t0
    if args.json:
        keys = ("supply_bar", "step_v", "vertical_load_n", "a_p_per_s", "a_s_m", "residual_m")
        print(json.dumps([{k: r[k] for k in keys} for r in rows]))
        return 0
    paper = any("paper_a_s_m" in r for r in rows)
    print(f"eq. (7) identified on the fifth-order model, {iso.name}, step tests of {duration:g} s sampled at "
          f"500 Hz" + (" (paper: Table III)" if iso.name == "IUT_a" else " (paper: Table IV)" if paper else ""))
    if described is not None:
        changed = ", ".join(f"{k} = {v:g}" for k, v in described.changed().items()) or "the defaults"
        print(f"rig: {described.name} ({described.source}): {changed}")
    loaded = rig.with_changes(vertical_load_n=load_n)
    print(f"vertical load {load_n / 1e3:g} kN"
          + (" (fitted to the paper's table)" if args.vertical_load_n is None and paper else "")
          + f": friction mu N + F_c = {loaded.friction_coefficient:g} x {load_n:g} N + {loaded.coulomb_force_n:g} N "
            f"= {loaded.friction_force_n:.5g} N (eq. 1)")
    head = "test        a_p 1/s" + ("  paper  ratio" if paper else "") + "   a_s mm" + \
           ("  paper   error" if paper else "") + "  residual mm  fit s"
    print(head)
    for r in rows:
        line = f"Ps{r['supply_bar']:g}u{r['step_v']:g}".ljust(10) + f"{r['a_p_per_s']:9.3f}"
        if paper:
            line += (f"  {r['paper_a_p_per_s']:5.2f}  x{r['a_p_ratio']:4.2f}" if "paper_a_p_per_s" in r
                     else "      -      -")
        line += f"  {r['a_s_m'] * 1e3:7.2f}"
        if paper:
            line += (f"  {r['paper_a_s_m'] * 1e3:5.1f}  {100 * r['a_s_rel_error']:+5.1f} %" if "paper_a_s_m" in r
                     else "      -        -")
        line += f"  {r['residual_m'] * 1e3:11.3f}  {r['fit_time_s']:5.2f}"
        print(line)
    if paper:
        c = targets_check({iso.name: rows})
        rising = {True: "yes", False: "no", None: "not checked (one supply pressure)"}[c["a_s_rises_with_supply"]]
        print(f"worst |a_s error| {100 * c['worst_a_s_rel_error']:.1f} % (target 30 %); worst a_p factor "
              f"{c['worst_a_p_factor']:.2f} (target 2); a_s rises with supply pressure at every step voltage: "
              f"{rising}")
        floor = paper_a_s_floor([(r["supply_bar"], r["step_v"]) for r in rows if "paper_a_s_m" in r])
        print(f"with one friction for both isolators, any rig under the paper's model leaves some a_s of these cells "
              f"at least {100 * floor:.1f} % off Tables III-IV (both rest under the same force); one vertical load "
              "per table lifts that bound (docs/identification.md)")
    print(f"{len(rows)} identifications in {elapsed:.2f} s ({elapsed / max(len(rows), 1):.2f} s each, "
          "simulation included)")
    return 0


def checked_vertical_load_n(load_n: float | None, rig) -> float | None:
    """--vertical-load-n in N, within [0, the jack's capacity rig.max_vertical_load_n]; UsageError otherwise."""
    import math

    if load_n is None:
        return None
    if not math.isfinite(load_n) or not 0.0 <= load_n <= rig.max_vertical_load_n:
        raise UsageError(f"isorig identify steps: --vertical-load-n {load_n:g} is outside the jack's range "
                         f"[0, {rig.max_vertical_load_n:g}] N")
    return float(load_n)


def rig_with_overrides(rig, pairs: list[str]):
    """The rig with NAME=VALUE overrides; UsageError naming the bad pair and the allowed names."""
    from dataclasses import fields

    allowed = {f.name for f in fields(rig)}
    changes = {}
    for pair in pairs:
        name, sep, text = pair.partition("=")
        if not sep or name not in allowed:
            raise UsageError(f"isorig identify steps: --rig-set {pair!r} must be NAME=VALUE with NAME one of "
                             f"{', '.join(sorted(allowed))}")
        try:
            value = float(text)
        except ValueError:
            raise UsageError(f"isorig identify steps: --rig-set {pair!r}: {text!r} is not a number") from None
        if not value > 0.0 or value == float("inf"):
            raise UsageError(f"isorig identify steps: --rig-set {pair!r}: the value must be a positive number")
        changes[name] = value
    if not changes:
        return rig
    from sim.rig import RigError

    changed = rig.with_changes(**changes)
    try:
        changed.check()  # ranges and combinations, as a rig file is checked
    except RigError as exc:
        raise UsageError(f"isorig identify steps: --rig-set: {exc}") from None
    return changed


def _fit_csv(args) -> int:
    import numpy as np

    from sim.identify_steps import fit_first_order, read_step_csv
    from sim.models import first_order_response

    rec = read_step_csv(args.csv)
    first_order_response(np.arange(2.0), np.ones(2), 1.0, 1.0)  # load the compiled model before timing the fit
    fit = fit_first_order(rec.time_s, rec.voltage_v, rec.displacement_m)
    if args.json:
        print(json.dumps({"step_v": fit.step_v, "a_p_per_s": fit.a_p_per_s, "a_s_m": fit.a_s_m,
                          "residual_m": fit.residual_m, "time_s": fit.time_s}))
        return 0
    print(f"{args.csv}: step of {fit.step_v:g} V, final displacement {fit.final_displacement_m * 1e3:.3f} mm")
    print(f"a_p = {fit.a_p_per_s:.4g} 1/s   a_s = {fit.a_s_m * 1e3:.4g} mm   "
          f"RMS residual {fit.residual_m * 1e3:.4f} mm")
    print(f"identified in {fit.time_s:.2f} s ({fit.starts} starts ranked, {fit.evaluations} model evaluations)")
    return 0


# ---------------------------------------------------------------------------------------------------
# bouc-wen
# ---------------------------------------------------------------------------------------------------

def _warm_loop() -> None:
    import numpy as np

    from sim.isolator import PRESETS, simulate_loop

    simulate_loop(PRESETS["IUT_a"], np.zeros(3), 1e-3)


def run_bouc_wen(args) -> int:
    from sim.identify_bouc_wen import fit_bouc_wen, read_loop_csv, summary_metrics
    from sim.isolator import NAME_PATTERN

    name = args.name or re.sub(r"[^A-Za-z0-9_.\- ]", "_", Path(args.file).stem)[:64] or "identified"
    if args.name is not None and not NAME_PATTERN.match(args.name):
        raise UsageError(f"isorig identify bouc-wen: --name {args.name!r} is invalid: use 1-64 letters, digits, "
                         "spaces, '_', '-' or '.'")
    if name == "timeseries" and args.name is None:
        name = Path(args.file).resolve().parent.name[:64] or name
        name = re.sub(r"[^A-Za-z0-9_.\- ]", "_", name) or "identified"
    rec = read_loop_csv(args.file)
    _warm_loop()  # load the compiled loop model before timing the fit
    fit = fit_bouc_wen(rec.time_s, rec.displacement_m, rec.force_n, name=name)
    measured, fitted = summary_metrics(fit.measured_metrics), summary_metrics(fit.fitted_metrics)
    saved = None
    if args.save_isolator:
        out = Path(args.save_isolator)
        if out.suffix != ".json":
            raise UsageError(f"isorig identify bouc-wen: --save-isolator {out} must end in .json")
        try:
            out.write_text(json.dumps(fit.isolator.to_dict(), indent=2) + "\n")
        except OSError as exc:
            raise UsageError(f"isorig identify bouc-wen: cannot write {out}: {exc.strerror}") from None
        saved = str(out)
    if args.json:
        print(json.dumps({**fit.to_dict(), "measured": measured, "fitted": fitted, "saved_isolator": saved}))
        return 0
    iso = fit.isolator
    print(f"{args.file}: {rec.time_s.size} samples, {measured['cycles']} complete cycle(s)")
    print(f"eq. (4) parameters:  rho_bw {iso.rho_bw_per_m:.4g} 1/m   sigma_bw {iso.sigma_bw:.4g}   n {iso.n:.4g}   "
          f"kd {iso.kd_n_per_m:.4g} N/m   kw {iso.kw_n:.4g} N")
    print("approx. 1-sigma relative uncertainty: " + ", ".join(
        f"{k} {100 * v:.2g} %" for k, v in fit.relative_std.items()))
    print(f"loop error: normalised RMS of force {100 * fit.nrms_error:.2f} % ({fit.rms_error_n:.4g} N)")
    if measured["k_eff_n_per_m"] is not None and fitted["k_eff_n_per_m"] is not None:
        print(f"K_eff measured {measured['k_eff_n_per_m']:.4g} N/m, fitted {fitted['k_eff_n_per_m']:.4g} N/m "
              f"({100 * (fitted['k_eff_n_per_m'] / measured['k_eff_n_per_m'] - 1):+.2f} %); "
              f"EDC measured {measured['edc_j']:.4g} J, fitted {fitted['edc_j']:.4g} J "
              f"({100 * (fitted['edc_j'] / measured['edc_j'] - 1):+.2f} %) (means over complete cycles)")
    else:
        print("K_eff / EDC: the record has no complete cycle")
    if fit.is_flat:
        print("warning: the fit is flat in some direction, so these parameters are not unique for this record:")
        for f in fit.flat_directions:
            print(f"  flat: {f}")
        for c in fit.correlations:
            print(f"  {c['a']} and {c['b']} are correlated ({c['correlation']:+.3f}): they trade off")
    else:
        print("every parameter is determined by this record (no flat direction, no correlation above 0.98)")
    if saved:
        print(f"saved isolator '{iso.name}' to {saved} (use: isorig simulate --isolator {saved})")
    print(f"identified in {fit.time_s:.2f} s ({fit.evaluations} model evaluations)")
    return 0
