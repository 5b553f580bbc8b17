"""The flow balance, eq. (3) second line, with the valve of eq. (3) third line and eq. (2):

    A_p y' + C P_L' = K_q DZ(v_e) R(s P_s - sgn(v_e) P_L),  C = V_0 / (2 beta)
    v_e'' = -w_v^2 v_e - 2 xi_v w_v v_e' + w_v^2 v_c,     v_c = u + v_e0 (u >= 0), k_en u + v_e0 (u < 0)

with R the orifice law of sim.rig (sqrt, linear below the declared regularisation drop) and s the supply share of
a single-rod actuator (1 towards +y, the declared A_B / A_A towards -y; sim.rig's docstring); k_ep is 1 (it is
K_q's share), so K_q is the flow gain of a positive command and k_en K_q that of a negative one. It is linear
in (K_q, C) once the dead zone, the null offset v_e0, the valve's w_v and xi_v, the position latency L, k_en and
the valve's play are fixed: those seven are found by non-linear least squares over the linear solution (variable
projection), started from a grid over the dead zone, and then by alternating: the seven at C held (a plain sum of
squares), then (K_q, C) at them, until they settle. The variable projection's cost is the bias-compensated one
(``_projected_residual``), and minimised over the seven it is ill-posed: the noise's share it takes out grows with
C, so a longer run lowers it without end (foreign rig 121: 7.0 where the fit stopped, 0.12 after 400 evaluations)
and where it stops depends on the run. At C held the noise's share does not move with the seven, and the alternation
settles in 2-4 rounds at the same point from starts 0.5 ms either side (rig 121's latency 0.567, 0.566 and 0.574 ms
against a true 0.560; where the variable projection alone had stopped at 0.113, 0.043 and 0.551).

The dead zone is a signed lap (``land_flow``): negative, the valve is underlapped, both its lands open round null
(sim.rig.load_flow); the play is a backlash between the command and the spool (``after_play``). On foreign rigs
0-599 these two took the flow balance's median R^2 from 0.986 to 0.996 and 0.983 to 0.997. ``part_disagreement``
fits the valve law on each experiment of the record alone: what the model leaves out shows as their disagreement.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numba import njit
from scipy import optimize, signal

from ..rig import past_play
from .signals import Signals, explained, lowpass

MAX_EVALUATIONS = 40  # per start of the non-linear fit (it converges in 10-30 on a rich record)
TOLERANCE = 1e-5  # relative change of the cost and of the parameters at which it has converged
DEAD_ZONE_GRID_STEP_V = 0.1
UNDERLAP_GRID_STEPS = 3  # the grid also tries underlaps of 1-3 steps (foreign rigs: 0.05-0.3 V)
ALTERNATIONS = 4  # at most: theta at C held, then (K_q, C) at that theta (``fit_flow``)
ALTERNATION_SETTLED = 0.01  # the largest move of theta, in SCALE units, at which the alternation has settled

#: bounds of the non-linear parameters: dead zone V (negative: an underlap), null offset V, valve Hz, valve
#: damping, latency ms, k_en, the valve's play V
LOWER = np.array([-1.0, -1.0, 5.0, 0.1, 0.0, 0.3, 0.0])
UPPER = np.array([5.0, 1.0, 400.0, 3.0, 20.0, 3.0, 0.5])
SCALE = np.array([0.1, 0.01, 10.0, 0.1, 0.1, 0.01, 0.01])


def orifice(dp: np.ndarray, dp_reg: float) -> np.ndarray:
    """R(dp) of sim.rig.regularised_sqrt, vectorised."""
    if dp_reg <= 0.0:
        return np.sqrt(np.maximum(dp, 0.0))
    return np.where(dp >= dp_reg, np.sqrt(np.maximum(dp, dp_reg)), dp / math.sqrt(dp_reg))


def land_flow(v_e: np.ndarray, p_load: np.ndarray, p_supply: np.ndarray, lap_v: float, dp_reg: float,
              area_ratio_b: float = 1.0) -> np.ndarray:
    """Q_L / K_q of a valve whose lands are lapped by ``lap_v`` (sim.rig.load_flow, vectorised): the land towards
    +y opens past v_e = lap_v, the one towards -y past v_e = -lap_v; an overlap (lap_v > 0) is the dead zone DZ,
    an underlap (lap_v < 0) opens both round null (twice the small-signal gain, a leak with P_L)."""
    towards_plus = np.maximum(v_e - lap_v, 0.0) * orifice(p_supply - p_load, dp_reg)
    towards_minus = np.maximum(-v_e - lap_v, 0.0) * orifice(area_ratio_b * p_supply + p_load, dp_reg)
    return towards_plus - towards_minus


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


@njit(cache=True)
def _after_play(u: np.ndarray, play_v: float) -> np.ndarray:
    """The command past a valve's play (backlash) of ``play_v`` full width over a record (sim.rig.past_play, as
    the plant's command_after_play applies it; at rest on 0 V before it)."""
    out = np.empty_like(u)
    held = 0.0
    for k in range(u.size):
        held = past_play(u[k], held, 0.5 * play_v)
        out[k] = held
    return out


def after_play(u: np.ndarray, play_v: float) -> np.ndarray:
    """``_after_play`` of the record's commands (u itself without play)."""
    return _after_play(np.ascontiguousarray(u, dtype=float), play_v) if play_v > 0.0 else u


def valve_voltage(u: np.ndarray, dt_s: float, natural_hz: float, damping: float, null_v: float,
                  negative_gain: float = 1.0, play_v: float = 0.0) -> np.ndarray:
    """v_e at the start of each period for the command u held over it: the second-order valve of eq. (3)
    driven by v_c of eq. (2) (k_ep = 1, k_en = ``negative_gain``) past the valve's play, discretised exactly for
    a zero-order hold."""
    num, den = valve_filter(2.0 * math.pi * natural_hz, damping, dt_s)
    if play_v > 0.0:
        u = after_play(u, play_v)
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
    play_v: float = 0.0

    @property
    def theta(self) -> np.ndarray:
        """The seven non-linear parameters in ``fit_flow``'s order and units (a ``start`` for another fit)."""
        return np.array([self.dead_zone_v, self.null_offset_v, self.valve_hz, self.valve_damping,
                         self.latency_s * 1e3, self.negative_gain, self.play_v])


def _flow_columns(sig: Signals, mask: np.ndarray, area: float, dp_reg: float, theta: np.ndarray,
                  area_ratio_b: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """The regressors of (K_q, C) and the regressand A_p y' for the non-linear parameters theta."""
    dz, null_v, valve_hz, damping, latency_ms, negative_gain, play_v = theta
    v_e = valve_voltage(sig.u, sig.dt_s, valve_hz, damping, null_v, negative_gain, play_v)
    x = np.column_stack([lowpass(land_flow(v_e, sig.p_load, sig.p_supply, dz, dp_reg, area_ratio_b), sig.dt_s,
                                       sig.flow_corner_hz), -sig.p_load_rate_flow])[mask]
    return x, area * sig.at_latency(sig.v_flow, latency_ms * 1e-3)[mask]


def _flow_regression(sig: Signals, mask: np.ndarray, area: float, dp_reg: float, theta: np.ndarray,
                     area_ratio_b: float = 1.0):
    """(K_q, C), the residual (m3/s) and the regressand for the non-linear parameters theta."""
    x, target = _flow_columns(sig, mask, area, dp_reg, theta, area_ratio_b)
    # normal equations (2 unknowns), with the P_L' noise's own share taken out of its column's sum of squares:
    # a regressor with noise in it pulls its coefficient, C, towards zero by var(signal) / var(signal + noise)
    # (bias-compensated least squares; the noise from the reading's content above NOISE_BAND_HZ)
    normal = x.T @ x
    normal[1, 1] -= x.shape[0] * sig.noise["load_pressure_rate_flow_pa_per_s"] ** 2
    coef = np.linalg.lstsq(normal, x.T @ target, rcond=None)[0]
    return coef, target - x @ coef, target


def _projected_residual(sig: Signals, mask: np.ndarray, area: float, dp_reg: float, theta: np.ndarray,
                        area_ratio_b: float, scale: float) -> np.ndarray:
    """The residual the non-linear fit minimises: ``_flow_regression``'s, shrunk so that its sum of squares is
    the bias-compensated cost sum(r^2) - N (C sigma)^2, sigma the P_L' column's noise. The plain sum of squares
    holds the noise's share C^2 N sigma^2, which falls with C: minimising it pulls the non-linear parameters
    towards those that shrink C. On overlapped foreign rigs with pressure transducers' noise that put the latency
    0.3-0.5 ms late (rigs 84, 147, 204, 230; right without the noise). The compensated cost is the one whose
    minimiser in (K_q, C) is ``_flow_regression``'s, so the variable projection stays consistent. Over the
    non-linear parameters it is ill-posed (the module docstring): ``fit_flow`` uses it for the first steps from its
    grid only, and settles them with ``_residual_at_compliance``."""
    coef, res, _ = _flow_regression(sig, mask, area, dp_reg, theta, area_ratio_b)
    res = res * scale
    plain = float(res @ res)
    noise = res.size * (coef[1] * sig.noise["load_pressure_rate_flow_pa_per_s"] * scale) ** 2
    return res * math.sqrt(max(plain - noise, 1e-6 * plain) / max(plain, 1e-300))


def _residual_at_compliance(sig: Signals, mask: np.ndarray, area: float, dp_reg: float, theta: np.ndarray,
                            area_ratio_b: float, scale: float, compliance: float) -> np.ndarray:
    """The flow balance's residual with C held at ``compliance`` and K_q its least-squares value: a plain sum of
    squares whose noise share, C^2 N sigma^2, no longer moves with theta (``fit_flow``'s alternation)."""
    x, target = _flow_columns(sig, mask, area, dp_reg, theta, area_ratio_b)
    rest = target - compliance * x[:, 1]
    gain = float(x[:, 0] @ rest) / max(float(x[:, 0] @ x[:, 0]), 1e-300)
    return (rest - gain * x[:, 0]) * scale


def fit_flow(sig: Signals, area: float, dp_reg: float, mask: np.ndarray | None = None,
             start: np.ndarray | None = None, latency_guess_s: float = 0.0, area_ratio_b: float = 1.0) -> FlowFit:
    """The flow balance (eq. 3, second line) with the valve (eq. 3, third line; eq. 2): see the module
    (``area_ratio_b``: the declared A_B / A_A)."""
    mask = sig.valid if mask is None else mask
    scale = 1.0 / max(np.std(area * sig.v_flow[mask]), 1e-12)

    def residual(theta):
        return _projected_residual(sig, mask, area, dp_reg, theta, area_ratio_b, scale)

    if start is None:
        overlaps = np.arange(0.0, min(UPPER[0], np.max(np.abs(sig.u)) + DEAD_ZONE_GRID_STEP_V), DEAD_ZONE_GRID_STEP_V)
        grid = np.concatenate((-DEAD_ZONE_GRID_STEP_V * np.arange(UNDERLAP_GRID_STEPS, 0, -1), overlaps))
        costs = [float(np.sum(residual(np.array([dz, 0.0, 80.0, 0.7, latency_guess_s * 1e3, 1.0, 0.0])) ** 2))
                 for dz in grid]
        best_dz = grid[int(np.argmin(costs))]
        starts = [np.array([best_dz, 0.0, hz, 0.7, latency_guess_s * 1e3, 1.0, 0.0]) for hz in (50.0, 120.0)]
        best = None
        for theta0 in starts:
            sol = optimize.least_squares(residual, np.clip(theta0, LOWER, UPPER), bounds=(LOWER, UPPER),
                                         x_scale=SCALE, diff_step=1e-3, max_nfev=MAX_EVALUATIONS, ftol=TOLERANCE,
                                         xtol=TOLERANCE)
            if best is None or sol.cost < best.cost:
                best = sol
        theta = best.x
    else:
        theta = np.clip(np.asarray(start, dtype=float), LOWER, UPPER)
    for _ in range(ALTERNATIONS):
        compliance = _flow_regression(sig, mask, area, dp_reg, theta, area_ratio_b)[0][1]
        sol = optimize.least_squares(
            lambda t, c=compliance: _residual_at_compliance(sig, mask, area, dp_reg, t, area_ratio_b, scale, c),
            theta, bounds=(LOWER, UPPER), x_scale=SCALE, diff_step=1e-3, max_nfev=MAX_EVALUATIONS, ftol=TOLERANCE,
            xtol=TOLERANCE)
        moved = float(np.max(np.abs(sol.x - theta) / SCALE))
        theta = sol.x
        if moved < ALTERNATION_SETTLED:
            break
    coef, res, target = _flow_regression(sig, mask, area, dp_reg, theta, area_ratio_b)
    target_noise = (area * sig.noise["velocity_flow_m_per_s"]) ** 2
    r2 = explained(res, target, target_noise + (coef[1] * sig.noise["load_pressure_rate_flow_pa_per_s"]) ** 2,
                   target_noise)
    dz, null_v, valve_hz, damping, latency_ms, negative_gain, play_v = theta
    return FlowFit(float(dz), float(null_v), float(valve_hz), float(damping), float(latency_ms * 1e-3),
                   float(negative_gain), float(coef[0]), float(coef[1]), r2, float(play_v))


#: the valve law's values whose model error shows as a disagreement between the parts of the record
VALVE_LAW_NAMES = ("dead_zone_v", "driver_offset_v", "driver_gain_negative", "flow_gain_m3_per_s_v_sqrt_pa")


def part_disagreement(sig: Signals, area: float, dp_reg: float, flow: FlowFit,
                      parts: list[np.ndarray], area_ratio_b: float = 1.0) -> dict[str, float]:
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
        scale = 1.0 / max(np.std(area * sig.v_flow[mask]), 1e-12)

        def theta(x, fixed=fixed):
            return np.array([x[0], x[1], *fixed, x[2], flow.play_v])

        def residual(x, mask=mask, scale=scale):
            return _projected_residual(sig, mask, area, dp_reg, theta(x), area_ratio_b, scale)

        start = np.clip([flow.dead_zone_v, flow.null_offset_v, flow.negative_gain], LOWER[free], UPPER[free])
        sol = optimize.least_squares(residual, start, bounds=(LOWER[free], UPPER[free]), x_scale=SCALE[free],
                                     diff_step=1e-3, max_nfev=MAX_EVALUATIONS, ftol=TOLERANCE, xtol=TOLERANCE)
        coef = _flow_regression(sig, mask, area, dp_reg, theta(sol.x), area_ratio_b)[0]
        laws.append(dict(zip(VALVE_LAW_NAMES, (sol.x[0], sol.x[1], sol.x[2], coef[0]), strict=True)))
    if len(laws) < 2:
        return {}
    return {name: float(abs(laws[0][name] - laws[1][name]) / math.sqrt(2.0)) for name in VALVE_LAW_NAMES}
