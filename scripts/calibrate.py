"""Calibrate the unknown rig parameters against the paper's Tables III and IV (one rig, both isolators).

For a candidate rig, the paper's 18 step tests (IUT_a and IUT_b x 20/30/40 bar x 2/4/6 V) are simulated on the
fifth-order model and eq. (7) is fitted to each (sim.identify_steps). The objective is the worst cell against the
issue's targets: max |a_s / a_s_paper - 1| / 0.3 + max |log(a_p / a_p_paper)| / log 2, plus a penalty on
records that have not settled (the paper's step responses settle within a few seconds). Nelder-Mead (the
objective is a maximum, not smooth) adjusts, in log space, the parameters that shape a_s and a_p:

    piston_area_m2            A_p: static balance A_p P_s = F_BW(y_s) + friction -> a_s
    coulomb_force_n           F_c (with mu N): the intercept of a_s over P_s
    flow_gain_...             K_q: speed of the response -> a_p
    dead_zone_v               DZ width: rise of a_p with the step voltage
    orifice_regularisation_pa sqrt(dp) made linear below this drop: how a_p changes with P_s

Deterministic: fixed starting point, no random numbers. Runs on all cores. Prints the run time, the final
parameters and the tables; with --write-docs it saves the step-response figures and prints a markdown table.

Run: .venv/bin/python scripts/calibrate.py [--quick | --defaults | --static-scan] [--write-docs]
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np
from scipy.optimize import minimize

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from sim.identify_steps import (  # noqa: E402
    PAPER_STEP_V,
    PAPER_SUPPLY_BAR,
    PAPER_TABLES,
    compare_with_paper,
    identify_step,
    targets_check,
    warm_up,
)
from sim.isolator import PRESETS  # noqa: E402
from sim.models import K_VOLT  # noqa: E402
from sim.rig import DEFAULT_RIG, RigParameters  # noqa: E402

FREE = ("piston_area_m2", "coulomb_force_n", "flow_gain_m3_per_s_v_sqrt_pa", "dead_zone_v",
        "orifice_regularisation_pa")
LOWER = np.log([0.005, 50.0, 1e-8, 0.05, 1e4])
UPPER = np.log([0.03, 2.0e4, 1e-5, 1.9, 1e7])
# Fixed starting point: where a first, longer run of this script (from the rig-notes set with A_p and F_c at
# the best static-balance compromise, |log| a_s errors) stopped; this run refines it on the target's measure.
START = {"piston_area_m2": 0.01298, "coulomb_force_n": 4200.0, "flow_gain_m3_per_s_v_sqrt_pa": 2.226e-7,
         "dead_zone_v": 0.5635, "orifice_regularisation_pa": 2.346e6}
# The result of this script (run of 2026-11-22, 50 evaluations, 509 s on the shared 2-core machine), rounded.
CALIBRATED = {"piston_area_m2": 0.01246, "coulomb_force_n": 4550.0, "flow_gain_m3_per_s_v_sqrt_pa": 2.054e-7,
              "dead_zone_v": 0.6065, "orifice_regularisation_pa": 2.335e6}
SIMPLEX_STEP = 0.08  # initial simplex: each parameter +8 % (in log space)
SETTLE_TOL = 0.01  # a record has settled if it moves less than 1 % of its final value over its last 3 s


def rig_from(theta: np.ndarray, base: RigParameters = DEFAULT_RIG) -> RigParameters:
    return base.with_changes(**{name: float(v) for name, v in zip(FREE, np.exp(theta), strict=True)})


def _cell(job):
    rig, iso, bar, volt, refined = job
    return identify_step(rig, PRESETS[iso], bar, volt, refined_starts=refined)


def grid(rig: RigParameters, pool, refined: int = 1) -> dict[str, list[dict]]:
    jobs = [(rig, iso, p, v, refined) for iso in PAPER_TABLES for p in PAPER_SUPPLY_BAR for v in PAPER_STEP_V]
    rows = list(pool.map(_cell, jobs))
    n = len(PAPER_SUPPLY_BAR) * len(PAPER_STEP_V)
    return {iso: compare_with_paper(rows[i * n:(i + 1) * n], iso) for i, iso in enumerate(PAPER_TABLES)}


def objective(compared: dict[str, list[dict]]) -> tuple[float, float, float, float]:
    """Worst-cell errors against the targets: max |a_s / a_s_paper - 1| / 0.3 + max |log(a_p ratio)| / log 2,
    plus a penalty for records that have not settled. Below 2 (each term below 1) both targets are met."""
    cells = [r for rows in compared.values() for r in rows]
    e_as = max(abs(r["a_s_m"] / r["paper_a_s_m"] - 1.0) for r in cells) / 0.3
    e_ap = max(abs(np.log(r["a_p_per_s"] / r["paper_a_p_per_s"])) for r in cells) / np.log(2.0)
    drift = max(r["tail_drift_m"] / max(abs(r["final_displacement_m"]), 1e-6) for r in cells)
    penalty = 10.0 * max(0.0, drift - SETTLE_TOL)
    return e_as + e_ap + penalty, e_as, e_ap, drift


def static_scan() -> None:
    """The bounds the static force balance sets on a_s (sim.rest_balance). First, with no rig at all: per cell,
    the smallest a_s error that lets one rest force serve both isolators (no rig under the paper's model does
    better). Then the best one rig, A_p P_s - friction, can do; and, for comparison, the same with a series
    compliance K_s (y = d + F / K_s; not in the model)."""
    from sim.rest_balance import common_rest_force_bound, loading_branch, rest_a_s_m

    a_s_tables = {iso: {cell: a_s for cell, (_, a_s) in table.items()} for iso, table in PAPER_TABLES.items()}
    branch = {iso: loading_branch(PRESETS[iso]) for iso in PAPER_TABLES}
    bound = common_rest_force_bound(a_s_tables, branch)
    print("any rig: smallest worst |a_s error| with one rest force for both isolators, per cell")
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

    def worst(theta, series: bool) -> float:
        area, friction = np.exp(theta[:2])
        k_s = np.exp(theta[2]) if series else np.inf
        out = 0.0
        for iso, table in PAPER_TABLES.items():
            for (bar, volt), (_, a_s) in table.items():
                push = area * bar * 1e5 - friction
                if push <= 0.0 or push >= branch[iso][1][-1]:
                    return 10.0
                identified = rest_a_s_m(branch[iso], push, volt) + push / k_s / np.tanh(volt / K_VOLT)
                out = max(out, abs(identified / a_s - 1.0))
        return out

    for series, x0 in ((False, [0.012, 5000.0]), (True, [0.008, 5000.0, 1.0e6])):
        best = None
        for shift in (0.0, 0.3, -0.3):
            sol = minimize(worst, np.log(x0) + shift, args=(series,), method="Nelder-Mead",
                           options={"xatol": 1e-4, "fatol": 1e-6, "maxfev": 800})
            if best is None or sol.fun < best.fun:
                best = sol
        p = np.exp(best.x)
        extra = f", K_s = {p[2]:.3g} N/m (series compliance, not in the model)" if series else ""
        print(f"static balance{' + series compliance' if series else ''}: worst |a_s error| {100 * best.fun:.1f} % "
              f"at A_p = {p[0]:.4g} m2, friction mu N + F_c = {p[1]:.4g} N{extra}")


def print_tables(compared: dict[str, list[dict]]) -> None:
    for iso, rows in compared.items():
        print(f"\n{iso}: test        a_p 1/s (paper)  ratio    a_s mm (paper)   error   residual mm")
        for r in rows:
            print(f"  Ps{r['supply_bar']:.0f}u{r['step_v']:.0f}      {r['a_p_per_s']:6.3f} ({r['paper_a_p_per_s']:.2f})"
                  f"  x{r['a_p_ratio']:4.2f}   {r['a_s_m'] * 1e3:6.2f} ({r['paper_a_s_m'] * 1e3:4.1f})"
                  f"  {100 * r['a_s_rel_error']:+6.1f} %   {r['residual_m'] * 1e3:.3f}")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="evaluate CALIBRATED only (no optimisation)")
    ap.add_argument("--defaults", action="store_true", help="evaluate sim/rig.py's defaults only (no optimisation)")
    ap.add_argument("--static-scan", action="store_true",
                    help="only the bound of the static force balance on a_s (seconds), then exit")
    ap.add_argument("--max-evals", type=int, default=50, help="Nelder-Mead evaluation budget (default 50)")
    ap.add_argument("--write-docs", action="store_true",
                    help="write docs/figures/identification_steps_*.png and print the table as markdown")
    args = ap.parse_args()
    t0 = time.perf_counter()
    if args.static_scan:
        static_scan()
        print(f"run time {time.perf_counter() - t0:.1f} s")
        return 0
    warm_up()
    with ProcessPoolExecutor(max_workers=os.cpu_count() or 1) as pool:
        if args.defaults:
            theta0 = np.log([getattr(DEFAULT_RIG, name) for name in FREE])
        elif args.quick:
            theta0 = np.log([CALIBRATED[name] for name in FREE])
        else:
            theta0 = np.log([START[name] for name in FREE])
            history = []

            def fun(theta):
                theta = np.clip(theta, LOWER, UPPER)
                cost, e_as, e_ap, drift = objective(grid(rig_from(theta), pool))
                history.append(cost)
                print(f"  eval {len(history):3d}: cost {cost:.4f} (a_s {e_as:.3f}, a_p {e_ap:.3f}, drift {drift:.4f})  "
                      + "  ".join(f"{n.split('_')[0]}={v:.4g}" for n, v in zip(FREE, np.exp(theta), strict=True)),
                      flush=True)
                return cost

            # Nelder-Mead: the objective is a maximum over cells (not smooth); a fixed initial simplex.
            simplex = np.vstack([theta0] + [theta0 + SIMPLEX_STEP * np.eye(len(FREE))[i] for i in range(len(FREE))])
            sol = minimize(fun, theta0, method="Nelder-Mead",
                           options={"initial_simplex": simplex, "maxfev": args.max_evals, "xatol": 0.01,
                                    "fatol": 0.002})
            theta = np.clip(sol.x, LOWER, UPPER)
            print(f"Nelder-Mead: {sol.message} ({sol.nfev} evaluations)")
        if args.quick or args.defaults:
            theta = theta0
        rig = rig_from(theta)
        compared = grid(rig, pool, refined=2)
    print("\nrig parameters evaluated:")
    for name in FREE:
        print(f"  {name} = {getattr(rig, name):.6g}")
    print_tables(compared)
    check = targets_check(compared)
    print(f"\nworst |a_s error| {100 * check['worst_a_s_rel_error']:.1f} % (target 30 %), "
          f"worst a_p factor {check['worst_a_p_factor']:.2f} (target 2), "
          f"a_s rises with P_s at every step voltage: {check['a_s_rises_with_supply']}")
    if args.write_docs:
        write_docs(rig, compared, check)
    print(f"run time {time.perf_counter() - t0:.1f} s")
    return 0


def write_docs(rig: RigParameters, compared: dict[str, list[dict]], check: dict) -> None:
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
                rec = simulate_step(rig, PRESETS[iso], bar, r["step_v"])
                ax.plot(rec.time_s, rec.displacement_m * 1e3, colour, lw=2.4, alpha=0.5)
                fo = first_order_response(rec.time_s, rec.voltage_v, r["a_p_per_s"], r["a_s_m"])
                ax.plot(rec.time_s, fo * 1e3, colour, ls="--", lw=1.2)
                paper = first_order_response(rec.time_s, rec.voltage_v, r["paper_a_p_per_s"], r["paper_a_s_m"])
                ax.plot(rec.time_s, paper * 1e3, colour, ls=":", lw=1.2)
            ax.set_title(f"{iso}, P_s = {bar:.0f} bar")
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
