"""Step-test identification of the first-order model, eq. (7), as in section III of the paper.

A step test: the rig at rest, a constant valve command u (V) from t = 0, the table displacement sampled
at 500 Hz. Eq. (7), dy/dt = -a_p y + a_p y u / (k atanh(y / a_s)), is fitted to the record by non-linear
least squares (``scipy.optimize.least_squares``) over log(a_p), log(a_s), from a closed-form start and a
few spread starts; the best fit is kept and its RMS residual reported.

``step_grid`` runs the paper's grid of step tests (20, 30, 40 bar x 2, 4, 6 V) on the fifth-order model,
eqs. (2)-(4), open loop, and identifies each; ``PAPER_TABLES`` holds Tables III and IV to compare with.

A step test runs under a vertical load N on the specimen, which sets the guide friction mu N + F_c of eq. (1)
(``vertical_load_n``; default the rig's). The paper does not state the load of its step tests:
``PAPER_TABLE_VERTICAL_LOAD_N`` holds the load fitted to each table (scripts/calibrate.py,
docs/identification.md), and ``default_step_vertical_load_n`` picks it for IUT_a and IUT_b.
"""

from __future__ import annotations

import time
from dataclasses import asdict, dataclass

import numpy as np
from numba import njit
from scipy.optimize import least_squares

from .identify import IdentificationError, as_record, read_record_csv
from .isolator import Isolator
from .models import K_VOLT, first_order_response
from .rig import BAR_PA, N_STATES, X_Y, RigParameters, pack_plant, rk4_steps, valve_command

SAMPLE_HZ = 500.0  # the paper's sampling rate for the step tests
STEP_DURATION_S = 10.0  # record length: eq. (7) with a_p ~ 0.5 1/s settles within ~3 s even at u = 2 V
PLANT_STEP_S = 2.0e-4  # RK4 step of the fifth-order model (the engine's plant step)
STEP_CSV_COLUMNS = ("time_s", "voltage_v", "displacement_m")
MIN_STEP_SAMPLES = 20
REFINED_STARTS = 2  # least-squares runs from the best-ranked initial guesses

# Tables III (IUT_a) and IV (IUT_b): (supply bar, step V) -> (a_p 1/s, a_s m).
PAPER_TABLES: dict[str, dict[tuple[float, float], tuple[float, float]]] = {
    "IUT_a": {
        (20.0, 2.0): (0.49, 0.010), (20.0, 4.0): (0.55, 0.011), (20.0, 6.0): (0.57, 0.011),
        (30.0, 2.0): (0.49, 0.021), (30.0, 4.0): (0.54, 0.022), (30.0, 6.0): (0.56, 0.022),
        (40.0, 2.0): (0.51, 0.030), (40.0, 4.0): (0.56, 0.031), (40.0, 6.0): (0.58, 0.031),
    },
    "IUT_b": {
        (20.0, 2.0): (0.60, 0.016), (20.0, 4.0): (0.71, 0.014), (20.0, 6.0): (0.72, 0.015),
        (30.0, 2.0): (0.61, 0.028), (30.0, 4.0): (0.72, 0.027), (30.0, 6.0): (0.71, 0.028),
        (40.0, 2.0): (0.58, 0.043), (40.0, 4.0): (0.69, 0.042), (40.0, 6.0): (0.70, 0.042),
    },
}
PAPER_SUPPLY_BAR = (20.0, 30.0, 40.0)
PAPER_STEP_V = (2.0, 4.0, 6.0)
# The vertical load N (N) of each table's step tests: not stated in the paper, fitted by scripts/calibrate.py
# (one load per table, one rig for both isolators, within the jack's 0..850 kN) together with the rig's
# friction mu N + F_c of eq. (1). Only mu N + F_c enters a step test, so these loads hold with the rig's
# friction_coefficient and coulomb_force_n of that calibration (docs/identification.md).
PAPER_TABLE_VERTICAL_LOAD_N: dict[str, float] = {"IUT_a": 0.0, "IUT_b": 8.095e5}


@dataclass
class StepFit:
    """Eq. (7) fitted to one step record."""

    a_p_per_s: float
    a_s_m: float
    residual_m: float  # RMS of (model - record)
    step_v: float
    final_displacement_m: float
    starts: int
    evaluations: int
    time_s: float

    def to_dict(self) -> dict:
        return asdict(self)


@dataclass
class StepRecord:
    """A sampled step test: time (s), valve command (V), table displacement (m)."""

    time_s: np.ndarray
    voltage_v: np.ndarray
    displacement_m: np.ndarray


# ---------------------------------------------------------------------------------------------------
# Simulated step tests on the fifth-order model
# ---------------------------------------------------------------------------------------------------

@njit(cache=True)
def _open_loop(plant, v_c, n_samples, substeps, h):
    """Fifth-order model from rest with the valve command v_c held; y at each sample."""
    x = np.zeros(N_STATES)
    y = np.empty(n_samples)
    for i in range(n_samples):
        y[i] = x[X_Y]
        rk4_steps(x, v_c, plant, h, substeps)
    return y


def rig_under_load(rig: RigParameters, vertical_load_n: float | None = None) -> RigParameters:
    """The rig with the vertical load N (N) on the specimen, so that its guide friction mu N + F_c (eq. 1) follows;
    None keeps the rig's own load. ValueError outside the jack's range [0, rig.max_vertical_load_n]."""
    if vertical_load_n is None:
        return rig
    load_n = float(vertical_load_n)
    if not 0.0 <= load_n <= rig.max_vertical_load_n:
        raise ValueError(f"vertical load {load_n:g} N is outside the jack's range [0, {rig.max_vertical_load_n:g}] N")
    return rig if load_n == rig.vertical_load_n else rig.with_changes(vertical_load_n=load_n)


def default_step_vertical_load_n(isolator: Isolator, rig: RigParameters) -> float:
    """The vertical load (N) a step test of ``isolator`` runs under unless told: the load fitted to its paper
    table (IUT_a: Table III, IUT_b: Table IV), else the isolator's design load, else the rig's."""
    if isolator.name in PAPER_TABLE_VERTICAL_LOAD_N:
        return PAPER_TABLE_VERTICAL_LOAD_N[isolator.name]
    if isolator.design_vertical_load_n is not None:
        return isolator.design_vertical_load_n
    return rig.vertical_load_n


def simulate_step(rig: RigParameters, isolator: Isolator, supply_bar: float, step_v: float,
                  duration_s: float = STEP_DURATION_S, sample_hz: float = SAMPLE_HZ,
                  vertical_load_n: float | None = None) -> StepRecord:
    """Open-loop step test of the fifth-order model, eqs. (2)-(4): u = step_v from t = 0, sampled at sample_hz,
    under the vertical load ``vertical_load_n`` (N; friction mu N + F_c of eq. 1; None: the rig's)."""
    plant = pack_plant(rig_under_load(rig, vertical_load_n), isolator, supply_bar * BAR_PA)
    substeps = max(1, int(round(1.0 / (sample_hz * PLANT_STEP_S))))
    h = 1.0 / (sample_hz * substeps)
    n = int(round(duration_s * sample_hz)) + 1
    u = float(np.clip(step_v, -rig.command_limit_v, rig.command_limit_v))
    y = _open_loop(plant, valve_command(u, plant), n, substeps, h)
    t = np.arange(n) / sample_hz
    return StepRecord(t, np.full(n, u), y)


# ---------------------------------------------------------------------------------------------------
# Fitting eq. (7)
# ---------------------------------------------------------------------------------------------------

def _starts(t: np.ndarray, u: np.ndarray, y: np.ndarray) -> tuple[float, float, list[tuple[float, float]]]:
    """Step amplitude, rest position and initial guesses (a_p, a_s): a closed-form one and a few around it.

    a_s ~ |final y| / tanh(|u| / k) (the steady state of eq. 7); a_p from the time to 63 % of the final
    displacement (t63 ~ 1/a_p for a small step, ~ 1/(a_p u/k) for a large one, so both are tried).
    """
    moving = np.flatnonzero(np.abs(u) > 0.0)
    t_step = t[moving[0]] if moving.size else t[0]
    u_step = float(np.median(u[moving])) if moving.size else 0.0
    tail = max(3, y.size // 20)
    y0 = float(np.mean(y[: max(1, moving[0] if moving.size else 1)]))
    y_final = float(np.mean(y[-tail:]))
    rise = abs(y_final - y0)
    if rise <= 0.0 or u_step == 0.0:
        raise IdentificationError("the record shows no step: the voltage or the displacement never changes")
    a_s0 = max(abs(y_final), rise) / np.tanh(abs(u_step) / K_VOLT)
    reached = np.flatnonzero(np.abs(y - y0) >= 0.632 * rise)
    t63 = max(float(t[reached[0]] - t_step) if reached.size else float(t[-1] - t_step), 2.0 * np.median(np.diff(t)))
    a_p_small = 1.0 / t63
    a_p_large = 1.0 / (t63 * max(1.0, abs(u_step) / K_VOLT))
    guesses = [(a_p_small, a_s0), (a_p_large, a_s0), (np.sqrt(a_p_small * a_p_large), 1.05 * a_s0),
               (3.0 * a_p_small, 1.3 * a_s0), (0.3 * a_p_large, a_s0)]
    return u_step, y0, guesses


def fit_first_order(time_s, voltage_v, displacement_m, starts: list[tuple[float, float]] | None = None,
                    refined_starts: int = REFINED_STARTS) -> StepFit:
    """Fit a_p (1/s) and a_s (m) of eq. (7) to one step record by non-linear least squares.

    ``starts`` overrides the automatic initial guesses (a_p, a_s). The record is used as given: u is held
    between samples, y(0) is the first sample.
    """
    t0 = time.perf_counter()
    t, u, y = as_record("step record", MIN_STEP_SAMPLES, time_s=time_s, voltage_v=voltage_v,
                        displacement_m=displacement_m)
    u_step, y_rest, auto = _starts(t, u, y)
    guesses = starts or auto
    y_init = y_rest  # the mean before the step (the first sample if the record starts with the step)
    scale = max(float(np.max(np.abs(y))), 1e-9)

    calls = 0

    def residual(theta):
        nonlocal calls
        calls += 1
        a_p, a_s = np.exp(theta)
        return (first_order_response(t, u, a_p, a_s, y_init) - y) / scale

    # Rank the starts by their cost (one response each), then refine the two best.
    x0s = [np.log([min(max(a_p0, 2e-4), 5e3), min(max(a_s0, 2e-6), 5.0)]) for a_p0, a_s0 in guesses]
    ranked = sorted(x0s, key=lambda x0: float(np.sum(residual(x0) ** 2)))
    best = None
    for x0 in ranked[: max(1, refined_starts)]:
        sol = least_squares(residual, x0, method="trf", bounds=(np.log([1e-4, 1e-6]), np.log([1e4, 10.0])),
                            xtol=1e-8, ftol=1e-10, max_nfev=100)
        if best is None or sol.cost < best.cost:
            best = sol
    a_p, a_s = np.exp(best.x)
    rms = float(np.sqrt(np.mean((best.fun * scale) ** 2)))
    tail = max(3, y.size // 20)
    return StepFit(a_p_per_s=float(a_p), a_s_m=float(a_s), residual_m=rms, step_v=u_step,
                   final_displacement_m=float(np.mean(y[-tail:])), starts=len(guesses), evaluations=calls,
                   time_s=time.perf_counter() - t0)


def read_step_csv(path) -> StepRecord:
    """A measured step test from CSV with columns time_s, voltage_v, displacement_m (others ignored)."""
    cols = read_record_csv(path, STEP_CSV_COLUMNS, MIN_STEP_SAMPLES)
    return StepRecord(cols["time_s"], cols["voltage_v"], cols["displacement_m"])


# ---------------------------------------------------------------------------------------------------
# The paper's grid
# ---------------------------------------------------------------------------------------------------

def identify_step(rig: RigParameters, isolator: Isolator, supply_bar: float, step_v: float,
                  duration_s: float = STEP_DURATION_S, refined_starts: int = REFINED_STARTS,
                  vertical_load_n: float | None = None) -> dict:
    """Simulate one step test on the fifth-order model (eqs. 2-4) and fit eq. (7); one table row.

    ``vertical_load_n`` (N) sets the friction mu N + F_c of eq. (1) (None: the rig's); the row carries the load
    used. ``tail_drift_m`` is how far the table still moves over the last 30 % of the record (settled: ~0).
    """
    loaded = rig_under_load(rig, vertical_load_n)
    rec = simulate_step(loaded, isolator, supply_bar, step_v, duration_s)
    fit = fit_first_order(rec.time_s, rec.voltage_v, rec.displacement_m, refined_starts=refined_starts)
    y = rec.displacement_m
    return {"supply_bar": float(supply_bar), "step_v": float(step_v), "vertical_load_n": loaded.vertical_load_n,
            "a_p_per_s": fit.a_p_per_s, "a_s_m": fit.a_s_m, "residual_m": fit.residual_m,
            "final_displacement_m": fit.final_displacement_m,
            "tail_drift_m": float(abs(y[-1] - y[int(0.7 * (y.size - 1))])), "fit_time_s": fit.time_s}


def _identify_args(args):
    return identify_step(*args)


def step_grid(rig: RigParameters, isolator: Isolator, supply_bar=PAPER_SUPPLY_BAR, step_v=PAPER_STEP_V,
              duration_s: float = STEP_DURATION_S, pool=None, refined_starts: int = REFINED_STARTS,
              vertical_load_n: float | None = None) -> list[dict]:
    """Identify eq. (7) on every (supply, step) pair under one vertical load (N; None: the rig's);
    ``pool`` (an Executor) spreads the work over cores."""
    rig_under_load(rig, vertical_load_n)  # refuse a load outside the jack's range before any work
    jobs = [(rig, isolator, float(p), float(v), duration_s, refined_starts, vertical_load_n)
            for p in supply_bar for v in step_v]
    if pool is None:
        return [identify_step(*j) for j in jobs]
    return list(pool.map(_identify_args, jobs))


def compare_with_paper(rows: list[dict], isolator_name: str) -> list[dict]:
    """Each row with the paper's a_p, a_s (Tables III/IV) and the relative errors, where the paper has the cell."""
    table = PAPER_TABLES.get(isolator_name, {})
    out = []
    for r in rows:
        ref = table.get((r["supply_bar"], r["step_v"]))
        row = dict(r)
        if ref:
            row["paper_a_p_per_s"], row["paper_a_s_m"] = ref
            row["a_p_ratio"] = r["a_p_per_s"] / ref[0]
            row["a_s_rel_error"] = r["a_s_m"] / ref[1] - 1.0
        out.append(row)
    return out


def targets_check(compared: dict[str, list[dict]]) -> dict:
    """The issue's targets over compared grids: every a_s within 30 %, every a_p within a factor 2,
    a_s rising with supply pressure at every step voltage (None when no step voltage has two pressures)."""
    cells = [r for rows in compared.values() for r in rows if "paper_a_s_m" in r]
    worst_as = max((abs(r["a_s_rel_error"]) for r in cells), default=float("nan"))
    worst_ap = max((max(r["a_p_ratio"], 1.0 / r["a_p_ratio"]) for r in cells), default=float("nan"))
    rising = None
    for rows in compared.values():
        for v in {r["step_v"] for r in rows}:
            col = sorted((r["supply_bar"], r["a_s_m"]) for r in rows if r["step_v"] == v)
            if len(col) > 1:
                rising = (rising is not False) and all(b[1] > a[1] for a, b in zip(col, col[1:], strict=False))
    return {"worst_a_s_rel_error": worst_as, "worst_a_p_factor": worst_ap, "a_s_rises_with_supply": rising,
            "passes": bool(cells) and worst_as <= 0.30 and worst_ap <= 2.0 and rising is not False}


def paper_a_s_floor(cells) -> float:
    """The smallest worst a_s error against Tables III-IV that any rig of the paper's model can reach on these
    (supply_bar, step_v) cells (sim.rest_balance; IUT_a and IUT_b from Tables I-II, virgin state); NaN if none."""
    from .isolator import PRESETS
    from .rest_balance import common_rest_force_bound, loading_branch

    cells = set(cells) & set(PAPER_TABLES["IUT_a"])
    if not cells:
        return float("nan")
    tables = {iso: {cell: table[cell][1] for cell in cells} for iso, table in PAPER_TABLES.items()}
    return max(common_rest_force_bound(tables, {iso: loading_branch(PRESETS[iso]) for iso in PAPER_TABLES}).values())


def warm_up() -> None:
    """Compile the step simulation and the eq. (7) response once (numba caches them on disk)."""
    from .isolator import PRESETS

    rec = simulate_step(RigParameters(), PRESETS["IUT_a"], 40.0, 2.0, duration_s=0.1)
    first_order_response(rec.time_s, rec.voltage_v, 0.5, 0.03)
