"""The rig's parameters from a commissioning record: equation-error fits of the two physical lines of eq. (3).

What a rig measures each period: the valve command u it was sent (zero-order hold over the period), the
position reading y_L (the table's position ``L`` late), the load pressure P_L, the specimen's force F and the
supply pressure P_s. Low-passed alike (zero phase, ``CORNER_HZ``), so that derivatives can be taken, they obey:

    force balance, eq. (3) first line:   A_p P_L - F = m y'' + F_f sgn(y') + sigma y'          (sliding only)
    flow balance, eq. (3) second line:   A_p y' + C P_L' = K_q DZ(v_e) R(P_s - sgn(v_e) P_L),  C = V_0 / (2 beta)
    valve, eq. (3) third line, eq. (2):  v_e'' = -w_v^2 v_e - 2 xi_v w_v v_e' + w_v^2 v_c,
                                         v_c = u + v_e0 (u >= 0), k_en u + v_e0 (u < 0)

with R the orifice law of sim.rig (sqrt, linear below the declared regularisation drop); k_ep is 1 (it is
K_q's share), so K_q is the flow gain of a positive command and k_en K_q that of a negative one. The piston
area A_p, the oil volume V_0 and the regularisation drop are the declared ones (a catalogue value, and two
that only enter as C or at the force limit); everything else is fitted:

1. the flow balance is linear in (K_q, C) once the dead zone, the null offset v_e0, the valve's w_v and xi_v,
   the position latency L and k_en are fixed: those six are found by non-linear least squares over the linear
   solution (variable projection), started from a grid over the dead zone;
2. the force balance is linear in (m, F_c, sigma, sigma_1 delta) at that latency, with the guides' friction a
   Dahl law (pre-sliding: a table that a dither moves by tens of um is held by its bearings' bristles, a spring
   of F_c / delta with a damper, not by F_f sgn(y')), its pre-sliding distance delta on a grid:

       A_p P_L - F = m y'' + F_c z + sigma_1 delta z' + sigma y',   z' = y' (1 - z sgn(y')) / delta,  |z| <= 1

   fitted with every coefficient >= 0 (a negative mass or friction is not a rig) over the whole record; or the
   Coulomb law of eq. (1), A_p P_L - F = m y'' + F_f sgn(y') + sigma y', over the samples where the table
   slides (a table that sticks rigidly is held by whatever the static friction takes), whichever explains
   more (``ForceFit.presliding_m`` is 0 for Coulomb's).

Uncertainties are delete-a-group jackknife estimates: the record is cut into ``CHUNK_S`` stretches dealt
round to ``BLOCKS`` groups (each group has some of every phase of the excitation), the fit is made again
without each group, and the spread of those fits is the uncertainty. It includes what the model does not
explain, not only noise. Nothing here knows the rig it runs on.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy import optimize, signal

from ..measurement import STATUS_COMMAND_MISSED, measured_rows
from ..rig import RigParameters
from ..samples import Samples

CORNER_HZ = 150.0  # the zero-phase low-pass before derivatives: above the oil column and most valves' bandwidth
NOISE_BAND_HZ = 350.0  # a reading's content above this is its sensor's noise (the rig moves far below it)
EDGE_S = 0.05  # the filter's start and end transients are not fitted
#: the pre-sliding distances the Dahl friction law is tried at, m (a factor sqrt 2 apart); 0: Coulomb's law
PRESLIDING_GRID_M = tuple(5e-6 * 2 ** (k / 2) for k in range(13))
SLIDING_M_PER_S = 1e-3  # Coulomb's law is fitted where |y'| is above this ...
STICK_MARGIN_S = 0.003  # ... and has been for this long either side (a rigidly sticking table is not in it)
BLOCKS = 5
ANOMALY_MARGIN_S = 0.015  # left out either side of a lost measurement or a late command
MAX_ANOMALY_SHARE = 0.1  # more than this share of lost or late periods: the record is not fitted
MAX_EVALUATIONS = 40  # per start of the non-linear fit (it converges in 10-30 on a rich record)
TOLERANCE = 1e-5  # relative change of the cost and of the parameters at which it has converged
CHUNK_S = 0.2
DEAD_ZONE_GRID_STEP_V = 0.1
#: bounds of the non-linear parameters: dead zone V, null offset V, valve Hz, valve damping, latency ms, k_en
LOWER = np.array([0.0, -1.0, 5.0, 0.1, 0.0, 0.3])
UPPER = np.array([5.0, 1.0, 400.0, 3.0, 20.0, 3.0])
SCALE = np.array([0.1, 0.01, 10.0, 0.1, 0.1, 0.01])


class FitError(ValueError):
    """A record that cannot be fitted (too short, no motion, non-finite readings): says what is missing."""


@dataclass
class Signals:
    """A commissioning record as the fits use it: raw channels, their low-passed copies and derivatives."""

    dt_s: float
    u: np.ndarray
    y: np.ndarray
    p_load: np.ndarray
    force: np.ndarray
    p_supply: np.ndarray
    valid: np.ndarray  # samples the fits may use
    y_f: np.ndarray = field(init=False)
    v_f: np.ndarray = field(init=False)
    a_f: np.ndarray = field(init=False)
    p_load_f: np.ndarray = field(init=False)
    p_load_rate_f: np.ndarray = field(init=False)
    force_f: np.ndarray = field(init=False)
    #: each reading's white noise, one sigma (m, Pa, N), and what it leaves in the low-passed derivatives
    noise: dict = field(init=False)

    def __post_init__(self):
        self.y_f = lowpass(self.y, self.dt_s)
        self.v_f = derivative(self.y_f, self.dt_s)
        self.a_f = derivative(self.v_f, self.dt_s)
        self.p_load_f = lowpass(self.p_load, self.dt_s)
        self.p_load_rate_f = derivative(self.p_load_f, self.dt_s)
        self.force_f = lowpass(self.force, self.dt_s)
        gains = noise_gains(self.dt_s)
        y, p, f = (noise_std(x, self.dt_s, self.valid) for x in (self.y, self.p_load, self.force))
        self.noise = {"position_m": y, "load_pressure_pa": p, "force_n": f,
                      "velocity_m_per_s": y * gains[1], "acceleration_m_per_s2": y * gains[2],
                      "load_pressure_f_pa": p * gains[0], "load_pressure_rate_pa_per_s": p * gains[1],
                      "force_f_n": f * gains[0]}

    def __len__(self) -> int:
        return self.u.size

    def at_latency(self, x: np.ndarray, latency_s: float) -> np.ndarray:
        """x(t + L): what a reading ``L`` late showed, moved back to when it happened (cubic Lagrange
        interpolation between the periods: a linear one would low-pass it, and the accelerations with it)."""
        return shifted(x, latency_s / self.dt_s)


def shifted(x: np.ndarray, periods: float) -> np.ndarray:
    """x[k + periods] for a fractional number of periods >= 0 (cubic Lagrange; the last values held)."""
    whole = int(math.floor(periods))
    f = periods - whole
    n = x.size
    padded = np.concatenate([x[:1], x, np.full(whole + 3, x[-1])])  # padded[i + 1] = x[i]
    i = np.arange(n) + whole + 1
    xm1, x0, x1, x2 = padded[i - 1], padded[i], padded[i + 1], padded[i + 2]
    return (-f * (f - 1) * (f - 2) / 6 * xm1 + (f + 1) * (f - 1) * (f - 2) / 2 * x0
            - (f + 1) * f * (f - 2) / 2 * x1 + (f + 1) * f * (f - 1) / 6 * x2)


def lowpass(x: np.ndarray, dt_s: float, corner_hz: float = CORNER_HZ) -> np.ndarray:
    """Zero-phase 4th-order Butterworth low-pass (forwards and backwards)."""
    sos = signal.butter(4, min(corner_hz, 0.45 / dt_s), fs=1.0 / dt_s, output="sos")
    return signal.sosfiltfilt(sos, x)


def derivative(x: np.ndarray, dt_s: float) -> np.ndarray:
    """dx/dt by the fourth-order central difference (flat to 0.5 % up to a tenth of the sampling rate: the
    second-order one, np.gradient, is 3 % low at 50 Hz at 1 kHz, which biased the mass by as much)."""
    d = np.gradient(x, dt_s)
    d[2:-2] = (x[:-4] - 8.0 * x[1:-3] + 8.0 * x[3:-1] - x[4:]) / (12.0 * dt_s)
    return d


def noise_std(x: np.ndarray, dt_s: float, where: np.ndarray | None = None) -> float:
    """A reading's white-noise sigma, from its content above ``NOISE_BAND_HZ`` (zero-phase high-pass; scaled by
    the share of white noise's variance that passes it). The rig's motion, oil column and valve lie far below that
    band; a sensor's noise and quantisation spread over the whole of it. ``where``: the samples to judge it on
    (the high-pass runs over the whole record, so that a gap between them is not read as noise)."""
    if 2.0 * NOISE_BAND_HZ * dt_s >= 0.9 or x.size < 200:
        return 0.0
    sos = signal.butter(4, NOISE_BAND_HZ, "high", fs=1.0 / dt_s, output="sos")
    passed = signal.sosfiltfilt(sos, x)
    use = np.ones(x.size, dtype=bool) if where is None else where.copy()
    use[:50] = use[-50:] = False
    if np.count_nonzero(use) < 100:
        return 0.0
    return float(math.sqrt(np.mean(passed[use] ** 2) / _white_share_above(dt_s)))


def _impulse(dt_s: float, n: int = 401) -> np.ndarray:
    x = np.zeros(n)
    x[n // 2] = 1.0
    return x


def _white_share_above(dt_s: float) -> float:
    sos = signal.butter(4, NOISE_BAND_HZ, "high", fs=1.0 / dt_s, output="sos")
    return float(np.sum(signal.sosfiltfilt(sos, _impulse(dt_s)) ** 2))


def noise_gains(dt_s: float) -> tuple[float, float, float]:
    """How much of a unit white noise's sigma the fits' low-pass leaves in a reading, its derivative (1/s) and
    its second derivative (1/s^2): the square root of the summed squares of their impulse responses."""
    h = lowpass(_impulse(dt_s), dt_s)
    h1 = derivative(h, dt_s)
    h2 = derivative(h1, dt_s)
    return tuple(float(math.sqrt(np.sum(g ** 2))) for g in (h, h1, h2))


def signals_from_samples(samples: Samples, dt_s: float) -> Signals:
    """The channels a real rig measures, from a record (``voltage_v`` is the command the host sent).

    A link is not perfect: a period whose measurement was lost holds the previous reading (FLAG_LOST), and a
    command that missed its period left the previous one applied for it (COMMAND_MISSED in the next
    measurement, docs/rig-protocol.md). The readings held over lost periods are interpolated, the command is
    the one the rig applied, and the fits leave out ``ANOMALY_MARGIN_S`` either side of either (the low-pass
    spreads them), as they leave out the filter's transients at both ends."""
    n = len(samples)
    if n * dt_s < 2.0:
        raise FitError(f"a commissioning record of {n * dt_s:.2f} s is too short to fit (at least 2 s)")
    columns = {name: np.array(samples[name], dtype=float) for name in
               ("voltage_v", "measured_displacement_m", "load_pressure_pa", "force_n", "supply_pressure_pa")}
    for name, x in columns.items():
        if not np.all(np.isfinite(x)):
            raise FitError(f"the record's {name} has non-finite values: the fit needs every reading")
    flags = np.nan_to_num(np.asarray(samples["flags"], dtype=float)).astype(np.int64)
    lost = ~measured_rows(flags)
    missed = np.zeros(n, dtype=bool)
    missed[:-1] = (flags[1:] & STATUS_COMMAND_MISSED) != 0  # the measurement after a missed period says so
    if np.count_nonzero(lost | missed) > MAX_ANOMALY_SHARE * n:
        raise FitError(f"{np.count_nonzero(lost)} measurements lost and {np.count_nonzero(missed)} commands late "
                       f"in {n} periods (more than {100 * MAX_ANOMALY_SHARE:g} %): the link is not good enough to "
                       "fit (see the link figures; a host that is loaded misses its periods)")
    u = columns["voltage_v"]
    for k in np.flatnonzero(missed):
        if k > 0:
            u[k] = u[k - 1]  # the rig held the command before (consecutive misses in order)
    if lost.any() and not lost.all():
        t = np.arange(n)
        for name in ("measured_displacement_m", "load_pressure_pa", "force_n", "supply_pressure_pa"):
            x = columns[name]
            x[lost] = np.interp(t[lost], t[~lost], x[~lost])
    margin = int(round(ANOMALY_MARGIN_S / dt_s))
    near = np.convolve((lost | missed).astype(float), np.ones(2 * margin + 1), "same") > 0
    valid = ~near
    edge = int(round(EDGE_S / dt_s))
    valid[:edge] = False
    valid[n - edge:] = False
    return Signals(dt_s, u, columns["measured_displacement_m"], columns["load_pressure_pa"], columns["force_n"],
                   columns["supply_pressure_pa"], valid)


def orifice(dp: np.ndarray, dp_reg: float) -> np.ndarray:
    """R(dp) of sim.rig.regularised_sqrt, vectorised."""
    if dp_reg <= 0.0:
        return np.sqrt(np.maximum(dp, 0.0))
    return np.where(dp >= dp_reg, np.sqrt(np.maximum(dp, dp_reg)), dp / math.sqrt(dp_reg))


def valve_filter(w: float, damping: float, dt_s: float) -> tuple[np.ndarray, np.ndarray]:
    """The exact zero-order-hold discretisation of v_e'' = -w^2 v_e - 2 xi w v_e' + w^2 v_c, as the numerator and
    denominator of a digital filter from v_c to v_e (e^{A T} in closed form from its eigenvalues)."""
    a = np.array([[0.0, 1.0], [-w * w, -2.0 * damping * w]])
    root = np.sqrt(complex(damping * damping - 1.0)) * w
    l1, l2 = -damping * w + root, -damping * w - root
    if abs(l1 - l2) < 1e-9 * w:  # critically damped: separate the two eigenvalues a little
        l1, l2 = l1 * (1 + 1e-7), l2 * (1 - 1e-7)
    e1, e2 = np.exp(l1 * dt_s), np.exp(l2 * dt_s)
    alpha1 = ((e1 - e2) / (l1 - l2)).real
    alpha0 = ((l1 * e2 - l2 * e1) / (l1 - l2)).real
    ad = alpha0 * np.eye(2) + alpha1 * a
    bd = np.linalg.solve(a, (ad - np.eye(2)) @ np.array([0.0, w * w]))
    num = np.array([0.0, bd[0], ad[0, 1] * bd[1] - ad[1, 1] * bd[0]])
    den = np.array([1.0, -np.trace(ad), np.linalg.det(ad)])
    return num, den


def valve_voltage(u: np.ndarray, dt_s: float, natural_hz: float, damping: float, null_v: float,
                  negative_gain: float = 1.0) -> np.ndarray:
    """v_e at the start of each period for the command u held over it: the second-order valve of eq. (3)
    driven by v_c of eq. (2) (k_ep = 1, k_en = ``negative_gain``), discretised exactly for a zero-order hold."""
    num, den = valve_filter(2.0 * math.pi * natural_hz, damping, dt_s)
    return signal.lfilter(num, den, np.where(u < 0.0, negative_gain * u, u) + null_v)


@dataclass
class FlowFit:
    dead_zone_v: float
    null_offset_v: float
    valve_hz: float
    valve_damping: float
    latency_s: float
    negative_gain: float
    flow_gain: float
    compliance_m3_per_pa: float
    r2: float


@dataclass
class ForceFit:
    mass_kg: float
    friction_n: float
    viscous_n_s_per_m: float
    presliding_m: float
    bristle_damping_n_s_per_m: float
    r2: float
    samples: int


def _flow_regression(sig: Signals, mask: np.ndarray, area: float, dp_reg: float, theta: np.ndarray):
    """(K_q, C), the residual (m3/s) and the regressand for the non-linear parameters theta."""
    dz, null_v, valve_hz, damping, latency_ms, negative_gain = theta
    v_e = valve_voltage(sig.u, sig.dt_s, valve_hz, damping, null_v, negative_gain)
    r = orifice(sig.p_supply - np.sign(v_e) * sig.p_load, dp_reg)
    opening = np.maximum(v_e - dz, 0.0) + np.minimum(v_e + dz, 0.0)
    x = np.column_stack([lowpass(opening * r, sig.dt_s), -sig.p_load_rate_f])[mask]
    target = area * sig.at_latency(sig.v_f, latency_ms * 1e-3)[mask]
    # normal equations (2 unknowns), with the P_L' noise's own share taken out of its column's sum of squares:
    # a regressor with noise in it pulls its coefficient, C, towards zero by var(signal) / var(signal + noise)
    # (bias-compensated least squares; the noise from the reading's content above NOISE_BAND_HZ)
    normal = x.T @ x
    normal[1, 1] -= x.shape[0] * sig.noise["load_pressure_rate_pa_per_s"] ** 2
    coef = np.linalg.lstsq(normal, x.T @ target, rcond=None)[0]
    return coef, target - x @ coef, target


def explained(residual: np.ndarray, target: np.ndarray, residual_noise_var: float, target_noise_var: float) -> float:
    """R^2 of a balance judged against what its readings' noise leaves to explain: the share of the target's
    variance beyond its noise that the fit explains, counting the residual's expected noise as explained."""
    unexplained = max(float(np.var(residual)) - residual_noise_var, 0.0)
    return 1.0 - unexplained / max(float(np.var(target)) - target_noise_var, 1e-300)


def fit_flow(sig: Signals, area: float, dp_reg: float, mask: np.ndarray | None = None,
             start: np.ndarray | None = None, latency_guess_s: float = 0.0) -> FlowFit:
    """The flow balance (eq. 3, second line) with the valve (eq. 3, third line; eq. 2): see the module."""
    mask = sig.valid if mask is None else mask
    scale = 1.0 / max(np.std(area * sig.v_f[mask]), 1e-12)

    def residual(theta):
        return _flow_regression(sig, mask, area, dp_reg, theta)[1] * scale

    if start is None:
        grid = np.arange(0.0, min(UPPER[0], np.max(np.abs(sig.u)) + DEAD_ZONE_GRID_STEP_V), DEAD_ZONE_GRID_STEP_V)
        costs = [float(np.sum(residual(np.array([dz, 0.0, 80.0, 0.7, latency_guess_s * 1e3, 1.0])) ** 2))
                 for dz in grid]
        best_dz = grid[int(np.argmin(costs))]
        starts = [np.array([best_dz, 0.0, hz, 0.7, latency_guess_s * 1e3, 1.0]) for hz in (50.0, 120.0)]
    else:
        starts = [np.asarray(start, dtype=float)]
    best = None
    for theta0 in starts:
        sol = optimize.least_squares(residual, np.clip(theta0, LOWER, UPPER), bounds=(LOWER, UPPER), x_scale=SCALE,
                                     diff_step=1e-3, max_nfev=MAX_EVALUATIONS, ftol=TOLERANCE, xtol=TOLERANCE)
        if best is None or sol.cost < best.cost:
            best = sol
    coef, res, target = _flow_regression(sig, mask, area, dp_reg, best.x)
    target_noise = (area * sig.noise["velocity_m_per_s"]) ** 2
    r2 = explained(res, target, target_noise + (coef[1] * sig.noise["load_pressure_rate_pa_per_s"]) ** 2, target_noise)
    dz, null_v, valve_hz, damping, latency_ms, negative_gain = best.x
    return FlowFit(float(dz), float(null_v), float(valve_hz), float(damping), float(latency_ms * 1e-3),
                   float(negative_gain), float(coef[0]), float(coef[1]), r2)


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


#: the valve law's values whose model error shows as a disagreement between the parts of the record
VALVE_LAW_NAMES = ("dead_zone_v", "driver_offset_v", "driver_gain_negative", "flow_gain_m3_per_s_v_sqrt_pa")


def part_disagreement(sig: Signals, area: float, dp_reg: float, flow: FlowFit,
                      parts: list[np.ndarray]) -> dict[str, float]:
    """What the flow balance's model leaves out, as the valve law fitted on each part of the record alone (the
    valve sweeps, the dither: one experiment each) disagrees: |a - b| / sqrt(2) for each of VALVE_LAW_NAMES,
    the valve's dynamics and the latency held at the whole record's. A rig the model describes gives the same
    valve law from both (within their noise); one it does not (a valve whose lands meter unequally, an actuator
    whose sides differ) gives each experiment its own, and the jackknife, which deals every part to every
    group, cannot see that."""
    fixed = [flow.valve_hz, flow.valve_damping, flow.latency_s * 1e3]
    free = np.array([0, 1, 5])
    laws = []
    for part in parts:
        mask = sig.valid & part
        if np.count_nonzero(mask) < int(1.0 / sig.dt_s):
            continue
        scale = 1.0 / max(np.std(area * sig.v_f[mask]), 1e-12)

        def theta(x, fixed=fixed):
            return np.array([x[0], x[1], *fixed, x[2]])

        def residual(x, mask=mask, scale=scale):
            return _flow_regression(sig, mask, area, dp_reg, theta(x))[1] * scale

        start = np.clip([flow.dead_zone_v, flow.null_offset_v, flow.negative_gain], LOWER[free], UPPER[free])
        sol = optimize.least_squares(residual, start, bounds=(LOWER[free], UPPER[free]), x_scale=SCALE[free],
                                     diff_step=1e-3, max_nfev=MAX_EVALUATIONS, ftol=TOLERANCE, xtol=TOLERANCE)
        coef = _flow_regression(sig, mask, area, dp_reg, theta(sol.x))[0]
        laws.append(dict(zip(VALVE_LAW_NAMES, (sol.x[0], sol.x[1], sol.x[2], coef[0]), strict=True)))
    if len(laws) < 2:
        return {}
    return {name: float(abs(laws[0][name] - laws[1][name]) / math.sqrt(2.0)) for name in VALVE_LAW_NAMES}


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
    coef = optimize.lsq_linear(x, target, bounds=(0.0, np.inf), method="bvls").x
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
    """A first guess of the position latency: the shift that fits the force balance best (a scan, at the
    pre-sliding distance fitted unshifted)."""
    delta = fit_force(sig, area, 0.0).presliding_m
    best = (math.inf, 0.0)
    for latency in np.arange(0.0, max_latency_s + 1e-12, 2.5e-4):
        fit = fit_force(sig, area, float(latency), presliding_m=delta)
        if 1.0 - fit.r2 < best[0]:
            best = (1.0 - fit.r2, float(latency))
    return best[1]


@dataclass
class Estimate:
    """A fitted value with its one-sigma uncertainty (jackknife), unit and meaning."""

    value: float
    std: float
    unit: str
    meaning: str

    @property
    def relative(self) -> float:
        return self.std / abs(self.value) if self.value else math.inf

    def to_dict(self) -> dict:
        return {"value": self.value, "std": self.std, "unit": self.unit, "meaning": self.meaning}


@dataclass
class RigFit:
    """What the fits found: every estimate by name (RigParameters names where one exists), the fits' R^2."""

    estimates: dict[str, Estimate]
    flow_r2: float
    force_r2: float
    force_balance_s: float  # the record's length the force balance was fitted over
    declared: RigParameters
    #: the valve law's disagreement between the record's parts, one sigma by name (part_disagreement)
    disagreement: dict = field(default_factory=dict)

    def value(self, name: str) -> float:
        return self.estimates[name].value

    def to_dict(self) -> dict:
        return {"estimates": {k: e.to_dict() for k, e in self.estimates.items()}, "flow_r2": self.flow_r2,
                "force_r2": self.force_r2, "force_balance_s": self.force_balance_s,
                "disagreement": dict(self.disagreement)}


def _named(flow: FlowFit, force: ForceFit, declared: RigParameters) -> dict[str, float]:
    return {
        "flow_gain_m3_per_s_v_sqrt_pa": flow.flow_gain,
        "driver_gain_negative": flow.negative_gain,
        "dead_zone_v": flow.dead_zone_v,
        "driver_offset_v": flow.null_offset_v,
        "valve_natural_frequency_rad_s": 2.0 * math.pi * flow.valve_hz,
        "valve_damping_ratio": flow.valve_damping,
        "bulk_modulus_pa": declared.half_volume_m3 / (2.0 * flow.compliance_m3_per_pa)
        if flow.compliance_m3_per_pa > 0 else math.nan,
        "position_latency_s": flow.latency_s,
        "mass_kg": force.mass_kg,
        "friction_force_n": force.friction_n,
        "viscous_n_s_per_m": force.viscous_n_s_per_m,
        "presliding_m": force.presliding_m,
        "bristle_damping_n_s_per_m": force.bristle_damping_n_s_per_m,
    }


UNITS = {"flow_gain_m3_per_s_v_sqrt_pa": ("m3/(s V sqrt(Pa))", "valve flow gain K_q, spool opening positive"),
         "driver_gain_negative": ("V/V", "k_en of eq. (2): a negative command's flow gain is k_en K_q"),
         "dead_zone_v": ("V", "half width of the valve's dead zone DZ"),
         "driver_offset_v": ("V", "valve null offset v_e0 (eq. 2)"),
         "valve_natural_frequency_rad_s": ("rad/s", "valve natural frequency w_v"),
         "valve_damping_ratio": ("-", "valve damping ratio xi_v"),
         "bulk_modulus_pa": ("Pa", "effective bulk modulus beta (the oil column's stiffness, with the declared V_0)"),
         "position_latency_s": ("s", "delay of the position reading"),
         "mass_kg": ("kg", "moving mass m"),
         "friction_force_n": ("N", "Coulomb friction mu N + F_c at the run's vertical load (the Dahl law's level)"),
         "viscous_n_s_per_m": ("N s/m", "viscous friction sigma (the oil column's damping)"),
         "presliding_m": ("m", "the guides' pre-sliding distance delta (Dahl law): F_c / delta is their stiffness"),
         "bristle_damping_n_s_per_m": ("N s/m", "the pre-sliding's damping sigma_1 (Dahl law)")}


def fit_rig(sig: Signals, declared: RigParameters, blocks: int = BLOCKS,
            parts: list[np.ndarray] | None = None) -> RigFit:
    """Every parameter of ``UNITS`` with its jackknife uncertainty over ``blocks`` groups of the record, and the
    valve law's disagreement between ``parts`` of it (boolean masks: the excitation's phases)."""
    if np.ptp(sig.y[sig.valid]) < 1e-5:
        raise FitError("the table moved less than 0.01 mm in the record: nothing to fit")
    area, dp_reg = declared.piston_area_m2, declared.orifice_regularisation_pa
    guess = latency_from_force(sig, area)
    flow = fit_flow(sig, area, dp_reg, latency_guess_s=guess)
    force = fit_force(sig, area, flow.latency_s)
    full = _named(flow, force, declared)
    start = np.array([flow.dead_zone_v, flow.null_offset_v, flow.valve_hz, flow.valve_damping, flow.latency_s * 1e3,
                      flow.negative_gain])
    group = (np.arange(len(sig)) // max(1, int(round(CHUNK_S / sig.dt_s)))) % blocks
    leave_one_out = []
    for b in range(blocks):
        keep = sig.valid & (group != b)
        f = fit_flow(sig, area, dp_reg, keep, start)
        try:
            g = fit_force(sig, area, f.latency_s, keep, presliding_m=force.presliding_m)
        except FitError:
            g = force
        leave_one_out.append(_named(f, g, declared))
    estimates = {}
    for name, value in full.items():
        others = np.array([d[name] for d in leave_one_out])
        std = float(math.sqrt((blocks - 1) / blocks * np.sum((others - others.mean()) ** 2)))
        unit, meaning = UNITS[name]
        estimates[name] = Estimate(float(value), std, unit, meaning)
    disagreement = part_disagreement(sig, area, dp_reg, flow, parts) if parts else {}
    return RigFit(estimates, flow.r2, force.r2, force.samples * sig.dt_s, declared, disagreement)
