"""The force balance, eq. (3) first line, with the guides' friction law fitted, not assumed.

Linear in (m, F_c, sigma, sigma_1 delta) at a latency, with the guides' friction a Dahl law (pre-sliding: a table
that a dither moves by tens of um is held by its bearings' bristles, a spring of F_c / delta with a damper, not
by F_f sgn(y')), its pre-sliding distance delta on a grid:

    A_p P_L - F = m y'' + F_c z + sigma_1 delta z' + sigma y',   z' = y' (1 - z sgn(y')) / delta,  |z| <= 1

fitted with every coefficient >= 0 (a negative mass or friction is not a rig) over the whole record; or the
Coulomb law of eq. (1), A_p P_L - F = m y'' + F_f sgn(y') + sigma y', over the samples where the table slides (a
table that sticks rigidly is held by whatever the static friction takes), whichever explains more
(``ForceFit.presliding_m`` is 0 for Coulomb's).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy import optimize

from .signals import FitError, Signals, derivative, explained, lowpass

#: the pre-sliding distances the Dahl friction law is tried at, m (a factor sqrt 2 apart); 0: Coulomb's law
PRESLIDING_GRID_M = tuple(5e-6 * 2 ** (k / 2) for k in range(13))
SLIDING_M_PER_S = 1e-3  # Coulomb's law is fitted where |y'| is above this ...
STICK_MARGIN_S = 0.003  # ... and has been for this long either side (a rigidly sticking table is not in it)


@dataclass
class ForceFit:
    mass_kg: float
    friction_n: float
    viscous_n_s_per_m: float
    presliding_m: float
    bristle_damping_n_s_per_m: float
    r2: float
    samples: int


def dahl_state(y: np.ndarray, presliding_m: float) -> np.ndarray:
    """z of the Dahl law z' = y' (1 - z sgn(y')) / delta for the displacement y (|z| <= 1; F_c z is the friction).
    Rate-independent, so solved exactly per step of y: z -> s - (s - z) exp(-|dy| / delta), s = sgn(dy)."""
    z = np.empty_like(y)
    state, last = 0.0, float(y[0])
    for k, yk in enumerate(y.tolist()):
        step = yk - last
        last = yk
        if step > 0.0:
            state = 1.0 - (1.0 - state) * math.exp(-step / presliding_m)
        elif step < 0.0:
            state = -1.0 + (1.0 + state) * math.exp(step / presliding_m)
        z[k] = state
    return z


def _friction_columns(sig: Signals, presliding_m: float) -> tuple[np.ndarray, np.ndarray]:
    """(z, z') of the Dahl law on the low-passed position, kept with the record (they do not depend on the mask)."""
    cache = sig.__dict__.setdefault("_dahl", {})
    if presliding_m not in cache:
        z = dahl_state(sig.y_f, presliding_m)
        cache[presliding_m] = (z, derivative(lowpass(z, sig.dt_s), sig.dt_s))
    return cache[presliding_m]


def sliding_mask(sig: Signals, latency_s: float) -> np.ndarray:
    """Samples where the table has been sliding (|y'| > SLIDING_M_PER_S) for STICK_MARGIN_S either side."""
    v = sig.at_latency(sig.v_f, latency_s)
    stuck = np.abs(v) <= SLIDING_M_PER_S
    width = 2 * int(round(STICK_MARGIN_S / sig.dt_s)) + 1
    near_stuck = np.convolve(stuck.astype(float), np.ones(width), "same") > 0
    return sig.valid & ~near_stuck


def _force_law(sig: Signals, area: float, latency_s: float, use: np.ndarray, delta: float) -> ForceFit | None:
    """The force balance with one friction law (delta > 0: Dahl's at that pre-sliding distance; 0: Coulomb's,
    where the table slides), every coefficient >= 0; None when too little of the record is left."""
    if delta == 0.0:
        use = use & sliding_mask(sig, latency_s)
    if np.count_nonzero(use) < 200:
        return None
    v = sig.at_latency(sig.v_f, latency_s)[use]
    a = sig.at_latency(sig.a_f, latency_s)[use]
    target = (area * sig.p_load_f - sig.force_f)[use]
    if delta == 0.0:
        x = np.column_stack([a, lowpass(np.sign(sig.at_latency(sig.v_f, latency_s)), sig.dt_s)[use], v])
    else:
        z, z_rate = (sig.at_latency(c, latency_s)[use] for c in _friction_columns(sig, delta))
        x = np.column_stack([a, z, v, z_rate])
    # min |x c - target| over c >= 0 on x's QR factors: the same minimiser (|x c - t|^2 = |r c - q't|^2 + const),
    # a 4-row problem for BVLS instead of one of the record's length (27 -> ~2 ms a law)
    q, r = np.linalg.qr(x)
    coef = optimize.lsq_linear(r, q.T @ target, bounds=(0.0, np.inf), method="bvls").x
    res = target - x @ coef
    noise = sig.noise
    target_noise = (area * noise["load_pressure_f_pa"]) ** 2 + noise["force_f_n"] ** 2
    r2 = explained(res, target, target_noise + (coef[0] * noise["acceleration_m_per_s2"]) ** 2, target_noise)
    damping = float(coef[3] / delta) if delta > 0.0 else 0.0
    return ForceFit(float(coef[0]), float(coef[1]), float(coef[2]), float(delta), damping, r2, int(target.size))


def fit_force(sig: Signals, area: float, latency_s: float, mask: np.ndarray | None = None,
              presliding_m: float | None = None) -> ForceFit:
    """The force balance (eq. 3, first line; module docstring): Coulomb's law and Dahl's at each pre-sliding
    distance of the grid (or the one law given: 0 is Coulomb's), the one that explains most kept."""
    use = sig.valid if mask is None else sig.valid & mask
    if np.ptp(sig.y_f[use]) < 1e-5:
        raise FitError("the table moved less than 0.01 mm: the force balance cannot be fitted")
    laws = (0.0, *PRESLIDING_GRID_M) if presliding_m is None else (presliding_m,)
    fits = [f for f in (_force_law(sig, area, latency_s, use, delta) for delta in laws) if f is not None]
    if not fits:
        raise FitError("the table slid for less than 0.2 s in the record: the force balance cannot be fitted")
    return max(fits, key=lambda f: f.r2)


def latency_from_force(sig: Signals, area: float, max_latency_s: float = 0.01) -> float:
    """The position latency that fits the force balance best: a scan at 0.25 ms, refined at 0.05 ms about its
    best, at the pre-sliding distance fitted unshifted. The flow balance's latency is fitted with the valve's
    lag beside it; this one, from the mechanics alone, is the first guess of that fit and its cross-check."""
    delta = fit_force(sig, area, 0.0).presliding_m

    def best_of(latencies):
        fits = [(fit_force(sig, area, float(latency), presliding_m=delta).r2, float(latency)) for latency in latencies]
        return max(fits)[1]

    coarse = best_of(np.arange(0.0, max_latency_s + 1e-12, 2.5e-4))
    return best_of(np.arange(max(0.0, coarse - 2.5e-4), coarse + 2.5e-4 + 1e-12, 5e-5))
