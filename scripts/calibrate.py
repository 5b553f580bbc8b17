"""Calibrate the unknown rig parameters and the step tests' vertical loads against the paper's Tables III and IV.

One rig for both isolators; one vertical load per table. For a candidate, the paper's 18 step tests (IUT_a and
IUT_b x 20/30/40 bar x 2/4/6 V) are simulated on the fifth-order model, each table under its own vertical load
N (friction mu N + F_c of eq. 1), and eq. (7) is fitted to each (sim.identify_steps). The objective is the worst
cell against the issue's targets, e_as = max |a_s / a_s_paper - 1| / 0.3 and e_ap = max |log(a_p / a_p_paper)|
/ log 2 (both below 1: targets met): max(e_as, e_ap) + 0.25 (e_as + e_ap), plus penalties for records that
have not settled and for an a_s that does not rise with P_s. Nelder-Mead (the objective is a maximum, not
smooth) adjusts:

    piston_area_m2            A_p (log): static balance A_p P_s = F_BW(y_s) + mu N + F_c -> slope of a_s over P_s
    flow_gain_...             K_q (log): speed of the response -> a_p
    dead_zone_v               DZ width (log): rise of a_p with the step voltage
    orifice_regularisation_pa sqrt(dp) made linear below this drop (log): how a_p changes with P_s
    vertical load IUT_a, IUT_b N of Table III and of Table IV, within the jack's [0, 850 kN] (linear, clipped):
                              the friction mu N + F_c of each table -> the intercept of its a_s over P_s

Only mu N + F_c enters a step test, so of (mu, F_c, N_a, N_b) the tests fix two combinations: mu and F_c are
held (FIXED) and the two loads fitted. Deterministic (fixed start and simplex, no random numbers); runs in one
process (one core). Prints each evaluation, the run time, the parameters, the loads, the tables and the targets
check; with --write-docs it saves the step-response figures and prints a markdown table.

Run: .venv/bin/python scripts/calibrate.py [--quick | --defaults | --static-scan] [--max-evals N] [--write-docs]
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np
from scipy.optimize import minimize

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from sim.identify_steps import (  # noqa: E402
    PAPER_STEP_V,
    PAPER_SUPPLY_BAR,
    PAPER_TABLE_VERTICAL_LOAD_N,
    PAPER_TABLES,
    compare_with_paper,
    identify_step,
    targets_check,
    warm_up,
)
from sim.isolator import PRESETS  # noqa: E402
from sim.models import K_VOLT  # noqa: E402
from sim.rig import DEFAULT_RIG, RigParameters  # noqa: E402

FREE = ("piston_area_m2", "flow_gain_m3_per_s_v_sqrt_pa", "dead_zone_v", "orifice_regularisation_pa")
LOWER = np.log([0.005, 1e-8, 0.05, 1e4])
UPPER = np.log([0.03, 1e-5, 1.9, 1e7])
# Held during the fit (the step tests see only mu N + F_c): mu of the rig notes and sim/rig.py, and the rig
# notes' seal friction F_c (the previous one-load calibration had raised F_c to 4550 N to stand in for the
# friction a heavier load gives IUT_b).
FIXED = {"friction_coefficient": 0.015, "coulomb_force_n": 1500.0}
# Fixed starting point: the best point of exploratory runs of the same objective (frictions per table free).
START = {"piston_area_m2": 0.01324, "flow_gain_m3_per_s_v_sqrt_pa": 2.696e-7, "dead_zone_v": 0.8848,
         "orifice_regularisation_pa": 2.157e6}
START_LOAD_N = {"IUT_a": 0.0, "IUT_b": 7.78e5}
# The result of this script (run of 2026-11-24 from START, 124 evaluations, 465 s on one core of the shared
# machine), rounded; the fitted loads are sim.identify_steps.PAPER_TABLE_VERTICAL_LOAD_N (0 and 809.5 kN).
CALIBRATED = {"piston_area_m2": 0.01334, "flow_gain_m3_per_s_v_sqrt_pa": 2.764e-7, "dead_zone_v": 0.8621,
              "orifice_regularisation_pa": 2.234e6, **FIXED}
SIMPLEX_STEP = 0.08  # initial simplex: each log parameter +8 %, each load +5 % of the jack's capacity
SIMPLEX_LOAD_STEP = 0.05
SETTLE_TOL = 0.01  # a record has settled if it moves less than 1 % of its final value over its last 3 s


def calibrated_rig(base: RigParameters = DEFAULT_RIG) -> RigParameters:
    """The rig this script proposes (CALIBRATED on top of ``base``)."""
    return base.with_changes(**CALIBRATED)


def unpack(theta: np.ndarray, base: RigParameters) -> tuple[RigParameters, dict[str, float]]:
    """The rig (FREE from theta[:4] in log space, FIXED) and the loads (theta[4:], fractions of the jack's
    capacity, clipped to [0, 1])."""
    rig = base.with_changes(**FIXED, **{name: float(np.exp(np.clip(v, lo, hi)))
                                        for name, v, lo, hi in zip(FREE, theta[:4], LOWER, UPPER, strict=True)})
    loads = {iso: float(np.clip(f, 0.0, 1.0)) * rig.max_vertical_load_n
             for iso, f in zip(PAPER_TABLES, theta[4:], strict=True)}
    return rig, loads


def grid(rig: RigParameters, loads_n: dict[str, float], refined: int = 1) -> dict[str, list[dict]]:
    """The 18 step tests, each table under its own vertical load, compared with Tables III-IV (one process)."""
    out = {}
    for iso in PAPER_TABLES:
        rows = [identify_step(rig, PRESETS[iso], p, v, refined_starts=refined, vertical_load_n=loads_n[iso])
                for p in PAPER_SUPPLY_BAR for v in PAPER_STEP_V]
        out[iso] = compare_with_paper(rows, iso)
    return out


def objective(compared: dict[str, list[dict]]) -> tuple[float, float, float, float]:
    """(cost, e_as, e_ap, drift): e_as = worst |a_s error| / 0.3, e_ap = worst |log a_p ratio| / log 2 (targets:
    both below 1); cost = max(e_as, e_ap) + 0.25 (e_as + e_ap) + penalties for unsettled records (drift over the
    last 3 s above 1 % of the final value) and for an a_s that does not rise with P_s."""
    cells = [r for rows in compared.values() for r in rows]
    e_as = max(abs(r["a_s_m"] / r["paper_a_s_m"] - 1.0) for r in cells) / 0.3
    e_ap = max(abs(np.log(r["a_p_per_s"] / r["paper_a_p_per_s"])) for r in cells) / np.log(2.0)
    drift = max(r["tail_drift_m"] / max(abs(r["final_displacement_m"]), 1e-6) for r in cells)
    penalty = 10.0 * max(0.0, drift - SETTLE_TOL) + (0.0 if targets_check(compared)["a_s_rises_with_supply"] else 5.0)
    return max(e_as, e_ap) + 0.25 * (e_as + e_ap) + penalty, e_as, e_ap, drift


def fit(max_evals: int, base: RigParameters = DEFAULT_RIG) -> tuple[RigParameters, dict[str, float]]:
    """Nelder-Mead over FREE and the two loads from START; prints every evaluation."""
    theta0 = np.concatenate([np.log([START[name] for name in FREE]),
                             [START_LOAD_N[iso] / base.max_vertical_load_n for iso in PAPER_TABLES]])
    steps = np.array([SIMPLEX_STEP] * len(FREE) + [SIMPLEX_LOAD_STEP] * len(PAPER_TABLES))
    simplex = np.vstack([theta0] + [theta0 + steps[i] * np.eye(theta0.size)[i] for i in range(theta0.size)])
    # a start at the upper load bound would put a simplex vertex beyond it (clipped, so flat): step down there
    simplex[1:, 4:] = np.where(simplex[1:, 4:] > 1.0, 2.0 * theta0[4:] - simplex[1:, 4:], simplex[1:, 4:])
    history: list[float] = []
    t0 = time.perf_counter()

    def fun(theta):
        rig, loads = unpack(theta, base)
        cost, e_as, e_ap, drift = objective(grid(rig, loads))
        history.append(cost)
        print(f"  eval {len(history):3d} ({time.perf_counter() - t0:5.0f} s): cost {cost:.4f} "
              f"(a_s {0.3 * e_as:.1%}, a_p x{2.0 ** e_ap:.3f}, drift {drift:.4f})  "
              + "  ".join(f"{n.split('_')[0]}={getattr(rig, n):.4g}" for n in FREE)
              + "  " + "  ".join(f"N_{iso[-1]}={n / 1e3:.1f} kN" for iso, n in loads.items()), flush=True)
        return cost

    sol = minimize(fun, theta0, method="Nelder-Mead",
                   options={"initial_simplex": simplex, "maxfev": max_evals, "xatol": 0.002, "fatol": 0.001})
    print(f"Nelder-Mead: {sol.message} ({sol.nfev} evaluations, best cost {min(history):.4f})")
    return unpack(sol.x, base)


def static_scan() -> None:
    """The bounds the static force balance sets on a_s (sim.rest_balance). First, with no rig at all: per cell,
    the smallest a_s error that lets one rest force serve both isolators (no rig under the paper's model does
    better while both isolators are tested under the same friction). Then the best one rig, A_p P_s - friction,
    can do with one friction, and with one friction per isolator (its own vertical load); the static balance of
    the calibrated rig under the fitted loads; and, for comparison, a series compliance K_s (y = d + F / K_s; not
    in the model)."""
    from sim.rest_balance import (
        best_rest_balance,
        common_rest_force_bound,
        loading_branch,
        rest_a_s_errors,
        rest_a_s_m,
    )

    a_s_tables = {iso: {cell: a_s for cell, (_, a_s) in table.items()} for iso, table in PAPER_TABLES.items()}
    branch = {iso: loading_branch(PRESETS[iso]) for iso in PAPER_TABLES}
    bound = common_rest_force_bound(a_s_tables, branch)
    print("any rig, one friction for both isolators: smallest worst |a_s error| with one rest force, per cell")
    for (bar, volt), e in bound.items():
        print(f"  Ps{bar:.0f}u{volt:.0f}  {100 * e:5.1f} %")
    print(f"  worst cell {100 * max(bound.values()):.1f} % (target 30 %)")
    # A previous test's history: each isolator first taken to its own excursion and back before the step.
    priors_m = np.linspace(-0.05, 0.05, 11)
    histories = {iso: {p: loading_branch(PRESETS[iso], points=4001, prior_excursion_m=p) for p in priors_m}
                 for iso in PAPER_TABLES}
    worst_cell, pa, pb = min((max(common_rest_force_bound(a_s_tables, {"IUT_a": histories["IUT_a"][pa],
                                                                        "IUT_b": histories["IUT_b"][pb]}).values()),
                              pa, pb) for pa in priors_m for pb in priors_m)
    print(f"  with a history (each isolator first taken to -50..+50 mm and back, 10 mm steps): best worst cell "
          f"{100 * worst_cell:.1f} % (IUT_a {1e3 * pa:+.0f} mm, IUT_b {1e3 * pb:+.0f} mm)")

    rig = calibrated_rig()
    jack = (rig.coulomb_force_n, rig.with_changes(vertical_load_n=rig.max_vertical_load_n).friction_force_n)
    for label, per_isolator, bounds in (("one friction", False, (0.0, np.inf)),
                                        ("one friction per isolator", True, (0.0, np.inf)),
                                        (f"one friction per isolator, loads within the jack (F_c = "
                                         f"{rig.coulomb_force_n:g} N, mu = {rig.friction_coefficient:g})", True, jack)):
        worst, area, friction = best_rest_balance(a_s_tables, branch, per_isolator, friction_range_n=bounds)
        loads = {iso: (f - rig.coulomb_force_n) / rig.friction_coefficient for iso, f in friction.items()}
        what = ", ".join(f"{iso} {f:.4g} N" for iso, f in friction.items()) if per_isolator else \
            f"{friction['IUT_a']:.4g} N"
        print(f"static balance, {label}: worst |a_s error| {100 * worst:.1f} % at A_p = {area:.4g} m2, "
              f"friction mu N + F_c = {what}"
              + (" (vertical loads: " + ", ".join(f"{iso} {n / 1e3:.0f} kN" for iso, n in loads.items()) + ")"
                 if bounds is jack else ""))
    friction = {iso: rig.with_changes(vertical_load_n=n).friction_force_n for iso, n in
                PAPER_TABLE_VERTICAL_LOAD_N.items()}
    errors = rest_a_s_errors(a_s_tables, branch, rig.piston_area_m2, friction)
    print(f"static balance of the calibrated rig under the fitted loads (A_p = {rig.piston_area_m2:.4g} m2, "
          + ", ".join(f"{iso} {PAPER_TABLE_VERTICAL_LOAD_N[iso] / 1e3:.0f} kN -> {f:.4g} N" for iso, f in
                      friction.items())
          + f"): worst |a_s error| {100 * max(abs(e) for e in errors.values()):.1f} %")

    def worst_series(theta) -> float:
        area, friction, k_s = np.exp(theta)
        out = 0.0
        for iso, table in PAPER_TABLES.items():
            for (bar, volt), (_, a_s) in table.items():
                push = area * bar * 1e5 - friction
                if push <= 0.0 or push >= branch[iso][1][-1]:
                    return 10.0
                identified = rest_a_s_m(branch[iso], push, volt) + push / k_s / np.tanh(volt / K_VOLT)
                out = max(out, abs(identified / a_s - 1.0))
        return out

    best = None
    for shift in (0.0, 0.3, -0.3):
        sol = minimize(worst_series, np.log([0.008, 5000.0, 1.0e6]) + shift, method="Nelder-Mead",
                       options={"xatol": 1e-4, "fatol": 1e-6, "maxfev": 800})
        if best is None or sol.fun < best.fun:
            best = sol
    p = np.exp(best.x)
    print(f"static balance + series compliance, one friction: worst |a_s error| {100 * best.fun:.1f} % at "
          f"A_p = {p[0]:.4g} m2, friction {p[1]:.4g} N, K_s = {p[2]:.3g} N/m (not in the model)")


def print_tables(compared: dict[str, list[dict]]) -> None:
    for iso, rows in compared.items():
        print(f"\n{iso}: test        a_p 1/s (paper)  ratio    a_s mm (paper)   error   residual mm")
        for r in rows:
            print(f"  Ps{r['supply_bar']:.0f}u{r['step_v']:.0f}      {r['a_p_per_s']:6.3f} ({r['paper_a_p_per_s']:.2f})"
                  f"  x{r['a_p_ratio']:4.2f}   {r['a_s_m'] * 1e3:6.2f} ({r['paper_a_s_m'] * 1e3:4.1f})"
                  f"  {100 * r['a_s_rel_error']:+6.1f} %   {r['residual_m'] * 1e3:.3f}")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true",
                    help="evaluate CALIBRATED under the fitted loads only (no optimisation)")
    ap.add_argument("--defaults", action="store_true",
                    help="evaluate sim/rig.py's defaults under the fitted loads only (no optimisation)")
    ap.add_argument("--static-scan", action="store_true",
                    help="only the bounds of the static force balance on a_s (seconds), then exit")
    ap.add_argument("--max-evals", type=int, default=150, help="Nelder-Mead evaluation budget (default 150)")
    ap.add_argument("--write-docs", action="store_true",
                    help="write docs/figures/identification_steps_*.png and print the table as markdown")
    args = ap.parse_args()
    t0 = time.perf_counter()
    if args.static_scan:
        static_scan()
        print(f"run time {time.perf_counter() - t0:.1f} s")
        return 0
    warm_up()
    if args.defaults:
        rig, loads = DEFAULT_RIG, dict(PAPER_TABLE_VERTICAL_LOAD_N)
    elif args.quick:
        rig, loads = calibrated_rig(), dict(PAPER_TABLE_VERTICAL_LOAD_N)
    else:
        rig, loads = fit(args.max_evals)
    compared = grid(rig, loads, refined=2)
    print("\nrig parameters evaluated:")
    for name in FREE + tuple(FIXED):
        print(f"  {name} = {getattr(rig, name):.6g}")
    for iso, load in loads.items():
        print(f"  vertical load of {iso}'s table: {load:.6g} N (friction mu N + F_c = "
              f"{rig.with_changes(vertical_load_n=load).friction_force_n:.5g} N)")
    print_tables(compared)
    check = targets_check(compared)
    print(f"\nworst |a_s error| {100 * check['worst_a_s_rel_error']:.1f} % (target 30 %), "
          f"worst a_p factor {check['worst_a_p_factor']:.3f} (target 2), "
          f"a_s rises with P_s at every step voltage: {check['a_s_rises_with_supply']}; "
          f"targets {'met' if check['passes'] else 'NOT met'}")
    if args.write_docs:
        write_docs(rig, loads, compared)
    print(f"run time {time.perf_counter() - t0:.1f} s")
    return 0


def write_docs(rig: RigParameters, loads_n: dict[str, float], compared: dict[str, list[dict]]) -> None:
    import matplotlib

    from sim.identify_steps import simulate_step
    from sim.models import first_order_response

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    docs = ROOT / "docs"
    print("\nmarkdown table for docs/identification.md:\n")
    print("| isolator | test | a_p 1/s | paper | ratio | a_s mm | paper | error | residual mm |")
    print("|---|---|---|---|---|---|---|---|---|")
    for iso, rows in compared.items():
        for r in rows:
            print(f"| {iso} | Ps{r['supply_bar']:.0f}u{r['step_v']:.0f} | {r['a_p_per_s']:.3f} | "
                  f"{r['paper_a_p_per_s']:.2f} | {r['a_p_ratio']:.2f} | {r['a_s_m'] * 1e3:.2f} | "
                  f"{r['paper_a_s_m'] * 1e3:.1f} | {100 * r['a_s_rel_error']:+.1f} % | {r['residual_m'] * 1e3:.3f} |")
    print()
    from matplotlib.lines import Line2D

    for iso, rows in compared.items():
        fig, axes = plt.subplots(1, 3, figsize=(13, 4.2), sharey=True)
        for ax, bar in zip(axes, PAPER_SUPPLY_BAR, strict=True):
            for r, colour in zip([r for r in rows if r["supply_bar"] == bar], ("C0", "C1", "C2"), strict=True):
                rec = simulate_step(rig, PRESETS[iso], bar, r["step_v"], vertical_load_n=loads_n[iso])
                ax.plot(rec.time_s, rec.displacement_m * 1e3, colour, lw=2.4, alpha=0.5)
                fo = first_order_response(rec.time_s, rec.voltage_v, r["a_p_per_s"], r["a_s_m"])
                ax.plot(rec.time_s, fo * 1e3, colour, ls="--", lw=1.2)
                paper = first_order_response(rec.time_s, rec.voltage_v, r["paper_a_p_per_s"], r["paper_a_s_m"])
                ax.plot(rec.time_s, paper * 1e3, colour, ls=":", lw=1.2)
            ax.set_title(f"{iso}, P_s = {bar:.0f} bar, N = {loads_n[iso] / 1e3:.0f} kN")
            ax.set_xlabel("time (s)")
            ax.grid(alpha=0.3)
        handles = [Line2D([], [], color="k", lw=2.4, alpha=0.5, label="fifth-order model"),
                   Line2D([], [], color="k", ls="--", lw=1.2, label="eq. (7) fitted to it"),
                   Line2D([], [], color="k", ls=":", lw=1.2, label="eq. (7) with the paper's a_p, a_s")]
        handles += [Line2D([], [], color=c, lw=2, label=f"step {v:g} V") for c, v in zip(("C0", "C1", "C2"),
                                                                                       PAPER_STEP_V, strict=True)]
        axes[2].legend(handles=handles, fontsize=7, loc="lower right")
        axes[0].set_ylabel("table displacement (mm)")
        fig.suptitle(f"{iso}: step tests on the fifth-order model (rig of scripts/calibrate.py), the eq. (7) "
                     "fitted to them, and eq. (7) with the paper's Table " + ("III" if iso == "IUT_a" else "IV"),
                     fontsize=10)
        fig.tight_layout()
        path = docs / "figures" / f"identification_steps_{iso}.png"
        path.parent.mkdir(parents=True, exist_ok=True)
        fig.savefig(path, dpi=110)
        plt.close(fig)
        print(f"wrote {path}")


if __name__ == "__main__":
    sys.exit(main())
