"""Bouc-Wen identification: fit (rho_BW, sigma_BW, n, k_d, k_w) of eq. (4) to a force-displacement record.

    F_BW = k_d d + k_w w,   dw/dt = rho_BW d' { 1 + |w|^n sigma_BW [ 1 - sgn(d' w) - 1/sigma_BW ] }    (4)

The force is linear in (k_d, k_w) once w(t) is known, and w(t) depends only on (rho_BW, sigma_BW, n). So the
fit is separable (variable projection): an outer non-linear least squares over log(rho, sigma, n) whose inner
step solves for (k_d, k_w) by linear least squares. A grid of starts (rho D in 1..30, sigma, n) is ranked first
and the best two are refined; the Jacobian of the full five-parameter residual at the optimum tells how well each
parameter is determined (flat directions, correlations).

The record is assumed to start at rest in the isolator's virgin state (w = 0), as `isorig simulate` records do.
"""

from __future__ import annotations

import time
from dataclasses import asdict, dataclass, field

import numpy as np
from scipy.optimize import least_squares, nnls

from .identify import IdentificationError, as_record, read_record_csv
from .isolator import LIMITS, Isolator, isolator_from_dict, simulate_loop

LOOP_CSV_COLUMNS = ("time_s", "displacement_m", "force_n")
MIN_LOOP_SAMPLES = 50
MAX_FIT_SAMPLES = 20000  # longer records are decimated for the fit (the metrics use every sample)
NONUNIFORM_TOL = 0.01  # relative spread of the sampling interval above which the record is resampled
FLAT_SINGULAR_RATIO = 1e-3  # a direction is flat when its singular value is below this x the largest
STRONG_CORRELATION = 0.98
REFINED_STARTS = 2  # least-squares runs from the best-ranked starts of the grid
JAC_STEP = 1e-4  # central-difference step in log-parameters
NAMES = ("rho_bw_per_m", "sigma_bw", "n", "kd_n_per_m", "kw_n")


@dataclass
class BoucWenFit:
    """The identified isolator, the fit quality and how well each parameter is determined."""

    isolator: Isolator
    nrms_error: float  # RMS(force error) / RMS(measured force)
    rms_error_n: float
    fitted_force_n: np.ndarray = field(repr=False)
    relative_std: dict  # approximate 1-sigma relative uncertainty of each parameter (from the Jacobian)
    singular_values: list  # of the Jacobian in log-parameters, normalised to the largest
    flat_directions: list  # human-readable combinations along which the fit barely changes
    correlations: list  # parameter pairs with |correlation| >= STRONG_CORRELATION
    measured_metrics: list = field(default_factory=list)  # per-cycle loop metrics of the record
    fitted_metrics: list = field(default_factory=list)  # ... of the fitted force on the same displacement
    evaluations: int = 0
    time_s: float = 0.0

    @property
    def is_flat(self) -> bool:
        return bool(self.flat_directions or self.correlations)

    def to_dict(self) -> dict:
        out = {k: v for k, v in asdict(self).items() if k not in ("fitted_force_n", "isolator")}
        out["parameters"] = {k: getattr(self.isolator, k) for k in NAMES}
        out["is_flat"] = self.is_flat
        return out


@dataclass
class LoopRecord:
    time_s: np.ndarray
    displacement_m: np.ndarray
    force_n: np.ndarray


def read_loop_csv(path) -> LoopRecord:
    """A force-displacement record (columns time_s, displacement_m, force_n; others, e.g. of
    `isorig simulate`'s timeseries.csv, are ignored)."""
    cols = read_record_csv(path, LOOP_CSV_COLUMNS, MIN_LOOP_SAMPLES)
    return LoopRecord(cols["time_s"], cols["displacement_m"], cols["force_n"])


def warm_up() -> None:
    """Load (or compile: numba caches them on disk) the fit's kernels, on a tiny record."""
    from .isolator import PRESETS

    d = np.zeros(3)
    _linear_part(d, _w_history(d, 1e-3, 100.0, 0.5, 1.0), simulate_loop(PRESETS["IUT_a"], d, 1e-3))


def _uniform(t: np.ndarray, d: np.ndarray, f: np.ndarray) -> tuple[float, np.ndarray, np.ndarray]:
    """The record on a uniform time grid (simulate_loop needs one); resampled linearly if needed."""
    steps = np.diff(t)
    dt = float(np.median(steps))
    if np.max(np.abs(steps - dt)) <= NONUNIFORM_TOL * dt:
        return dt, d, f
    n = int(np.floor((t[-1] - t[0]) / dt)) + 1
    grid = t[0] + dt * np.arange(n)
    return dt, np.interp(grid, t, d), np.interp(grid, t, f)


def _decimate(dt: float, d: np.ndarray, f: np.ndarray) -> tuple[float, np.ndarray, np.ndarray]:
    step = int(np.ceil(d.size / MAX_FIT_SAMPLES))
    if step <= 1:
        return dt, d, f
    return dt * step, d[::step], f[::step]


def _w_history(d: np.ndarray, dt: float, rho: float, sigma: float, n: float) -> np.ndarray:
    """w(t) of eq. (4) for the displacement history (k_d = 0, k_w = 1 makes simulate_loop return w)."""
    return simulate_loop(Isolator("fit", rho, sigma, n, 0.0, 1.0), d, dt)


def _linear_part(d: np.ndarray, w: np.ndarray, f: np.ndarray) -> tuple[float, float]:
    """k_d, k_w >= 0 minimising |k_d d + k_w w - f| (non-negative least squares)."""
    a = np.column_stack([d, w])
    scale = np.maximum(np.linalg.norm(a, axis=0), 1e-30)
    coef, _ = nnls(a / scale, f)
    return float(coef[0] / scale[0]), float(coef[1] / scale[1])


def _bounds_log(names) -> tuple[np.ndarray, np.ndarray]:
    lo = [max(LIMITS[k][0], 1e-3) for k in names]
    hi = [LIMITS[k][1] for k in names]
    return np.log(lo), np.log(hi)


def fit_bouc_wen(time_s, displacement_m, force_n, name: str = "identified",
                 start: dict | None = None) -> BoucWenFit:
    """Identify eq. (4) from a record by separable non-linear least squares (see the module docstring).

    ``start`` (a dict with some of rho_bw_per_m, sigma_bw, n) replaces the grid of starts.
    """
    t0 = time.perf_counter()
    t, d_all, f_all = as_record("loop record", MIN_LOOP_SAMPLES, time_s=time_s, displacement_m=displacement_m,
                                force_n=force_n)
    amplitude = 0.5 * float(np.ptp(d_all))
    if amplitude <= 0.0 or np.ptp(f_all) <= 0.0:
        raise IdentificationError("the record has no motion or no force change: nothing to identify")
    dt_u, d_u, f_u = _uniform(t, d_all, f_all)
    dt, d, f = _decimate(dt_u, d_u, f_u)
    f_scale = float(np.sqrt(np.mean(f ** 2)))
    evaluations = 0

    def projected(theta):
        nonlocal evaluations
        evaluations += 1
        rho, sigma, n = np.exp(theta)
        w = _w_history(d, dt, rho, sigma, n)
        kd, kw = _linear_part(d, w, f)
        return (kd * d + kw * w - f) / f_scale

    lo3, hi3 = _bounds_log(NAMES[:3])
    if start:
        s = {"rho_bw_per_m": 3.0 / amplitude, "sigma_bw": 0.5, "n": 1.0, **start}
        starts = [np.log([s["rho_bw_per_m"], s["sigma_bw"], s["n"]])]
    else:
        starts = [np.log([k / amplitude, sigma, n]) for k in (1.0, 3.0, 10.0, 30.0)
                  for sigma in (0.25, 0.5, 1.0) for n in (1.0, 2.0)]
    starts = [np.clip(x, lo3 + 1e-9, hi3 - 1e-9) for x in starts]
    ranked = sorted(starts, key=lambda x: float(np.sum(projected(x) ** 2)))
    best = None
    for x0 in ranked[:REFINED_STARTS]:
        sol = least_squares(projected, x0, bounds=(lo3, hi3), x_scale=1.0, xtol=1e-9, ftol=1e-12, max_nfev=100)
        if best is None or sol.cost < best.cost:
            best = sol
    rho, sigma, n = np.exp(best.x)
    kd, kw = _linear_part(d, _w_history(d, dt, rho, sigma, n), f)
    params = np.array([rho, sigma, n, kd, kw])

    # The Jacobian of the full five-parameter residual (log-parameters, central differences) at the optimum
    # shows what the record determines.
    def full(theta):
        nonlocal evaluations
        evaluations += 1
        r, s_bw, nn, k_d, k_w = np.exp(theta)
        return (simulate_loop(Isolator("fit", r, s_bw, nn, k_d, k_w), d, dt) - f) / f_scale

    x5 = np.log(np.maximum(params, 1e-12))
    jac = np.empty((d.size, 5))
    for i in range(5):
        step = np.zeros(5)
        step[i] = JAC_STEP
        jac[:, i] = (full(x5 + step) - full(x5 - step)) / (2.0 * JAC_STEP)
    flat, corr, rel_std, sv = _sensitivity(jac, best.fun)

    iso = isolator_from_dict({"name": name, **{k: float(v) for k, v in zip(NAMES, params, strict=True)},
                              "description": "identified from a force-displacement record (isorig identify)"})
    fitted_full = simulate_loop(iso, d_u, dt_u)
    rms = float(np.sqrt(np.mean((fitted_full - f_u) ** 2)))
    t_u = t[0] + dt_u * np.arange(d_u.size)
    measured, fitted = _metrics(t_u, d_u, f_u, fitted_full)
    return BoucWenFit(isolator=iso, nrms_error=rms / float(np.sqrt(np.mean(f_u ** 2))), rms_error_n=rms,
                      fitted_force_n=fitted_full, relative_std=rel_std, singular_values=sv, flat_directions=flat,
                      correlations=corr, measured_metrics=measured, fitted_metrics=fitted,
                      evaluations=evaluations, time_s=time.perf_counter() - t0)


def _sensitivity(jac: np.ndarray, residual: np.ndarray) -> tuple[list, list, dict, list]:
    """Flat directions, strong correlations and approximate relative standard deviations from J (log-params)."""
    _, s, vt = np.linalg.svd(jac, full_matrices=False)
    sv = (s / s[0]).tolist() if s[0] > 0 else [0.0] * len(s)
    flat = []
    for value, vec in zip(sv, vt, strict=True):
        if value < FLAT_SINGULAR_RATIO:
            terms = [f"{c:+.2f} log {NAMES[i]}" for i, c in sorted(enumerate(vec), key=lambda e: -abs(e[1]))
                     if abs(c) >= 0.2]
            flat.append(f"{' '.join(terms)} (relative singular value {value:.1e})")
    dof = max(1, residual.size - jac.shape[1])
    s2 = float(residual @ residual) / dof
    cov = np.linalg.pinv(jac.T @ jac) * s2
    std = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    rel_std = {k: float(np.expm1(v)) for k, v in zip(NAMES, std, strict=True)}
    with np.errstate(invalid="ignore", divide="ignore"):
        corr_m = cov / np.outer(std, std)
    corr = []
    for i in range(len(NAMES)):
        for j in range(i + 1, len(NAMES)):
            c = corr_m[i, j]
            if np.isfinite(c) and abs(c) >= STRONG_CORRELATION:
                corr.append({"a": NAMES[i], "b": NAMES[j], "correlation": float(c)})
    return flat, corr, rel_std, sv


def _metrics(t, d, f_measured, f_fitted) -> tuple[list, list]:
    """Per-cycle loop metrics (sim.metrics) of the measured and the fitted force on the same displacement."""
    from .metrics import cycle_metrics

    try:
        return cycle_metrics(t, d, f_measured), cycle_metrics(t, d, f_fitted)
    except ValueError:
        return [], []


def summary_metrics(cycles: list[dict]) -> dict:
    """Mean K_eff and EDC over the complete cycles (None when the record has none)."""
    keff = [c["k_eff_n_per_m"] for c in cycles if c.get("k_eff_n_per_m") is not None]
    edc = [c["edc_j"] for c in cycles if c.get("edc_j") is not None]
    return {"cycles": len(cycles), "k_eff_n_per_m": float(np.mean(keff)) if keff else None,
            "edc_j": float(np.mean(edc)) if edc else None}
