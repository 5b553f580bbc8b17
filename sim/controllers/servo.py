"""Learning servo controller: flow-linearised velocity feed-forward, position feedback, an estimate of the
valve's true flow gain and harmonic learning of the periodic error. Design and stability argument:
docs/controller.md.

    v   = r' + tau_v r'' + K_p (r - y) + dv                    velocity demand, m/s
    dv  = c_0 + V_env Re sum_k c_k exp(j k theta)              learned periodic feed-forward
    u_l = A_n (v / g) / (K_qn sqrt(P_s - sgn(v) P_L))          inverse of the valve flow law, eq. (3)
    u   = u_l + DZ ramp(u_l / delta)                           dead-zone inverse (ramp over +-delta)

g is the ratio of the true to the nominal flow gain (K_q A_n / (K_qn A_p)) and DZ the valve's dead zone, both
estimated by least squares of the measured table velocity on what the nominal valve gives for the command
sent tau_l earlier: y' = g (x - DZ w), x = u K_qn sqrt(dp) / A_n, w = sgn(u) K_qn sqrt(dp) / A_n (exponential
forgetting, a prior at the nominal values, projection); it keeps the loop gain at K_p whatever the valve and
the nominal values.

theta and V_env (the phase and the velocity amplitude of the sine target) come from the target rate r' and
its differences, so the controller needs no profile information: for r = A sin(w t), w^2 = -r''' r' / r'^2
at every instant. The complex coefficients c_k (harmonic k = 1..H of the target frequency, dimensionless:
relative to the target's peak velocity) learn the periodic error:

    c_k += gamma_k dt / (pi A_eff) (r - y) exp(-j k theta) (K_p + j k w) exp(j k w tau_l)
    gamma_k = gamma min(1, K_p / (k w))

that is, the error's k-th Fourier coefficient divided by a nominal model of the closed loop from dv to y
(1 / (s + K_p) with a pure delay tau_l for the valve), so each harmonic's error shrinks by about
(1 - gamma_k) per cycle. The learning runs only on a steady sine (not in a taper, not at a block change;
a new frequency clears it), is frozen while the command saturates (the error then says nothing about the
feed-forward) and each |c_k| is projected onto a bound. Only the measured position, the load pressure, the
supply pressure setting and nominal rig values (A_p, K_q, dead zone, command limit) are used; never the
isolator's parameters.

Report: model_m = r (the feed-forward removes the reference lag: the reference model is the target itself);
ar_hat = g, the estimated ratio of the true to the nominal flow gain; ay_hat = the estimated dead zone in V;
as_hat = the target frequency the learning is locked to, in Hz (0 before the first steady cycle).
"""

from __future__ import annotations

import numpy as np
from numba import njit

from .base import (
    M_LOAD_PRESSURE,
    M_POSITION,
    M_SUPPLY_PRESSURE,
    M_TARGET,
    M_TARGET_RATE,
    R_AR,
    R_AS,
    R_AY,
    R_MODEL,
    Adapted,
    Controller,
    Option,
    check_options,
)

KIND = 3
MAX_HARMONICS = 24

# Parameter indices.
(P_AREA, P_KQ, P_DZ, P_ULIM, P_KP, P_TAU_V, P_TAU_L, P_GAMMA, P_NH, P_FMAX, P_DZ_RAMP, P_DP_MIN,
 P_TW, P_AFLOOR, P_C1MAX, P_CKMAX, P_C0MAX, P_DZ_FRAC, P_GW, P_GMIN, P_GMAX, P_GVMIN, P_STEADY,
 P_PL_SHARE, P_DZ_ADAPT, P_DZ_LO, P_DZ_HI) = range(27)
P_JERK_LEAD, P_INTEGRAL = 27, 28
N_PARAMS = 29
DELAY_LINE = 32  # samples of the regressor history kept for the valve estimate

# State indices; the delay line and the harmonic coefficients (real, imaginary) follow.
(S_STARTED, S_RD1, S_RD2, S_NUM, S_DEN, S_OMEGA_LEARNED, S_C0, S_SAT, S_VENV, S_YPREV, S_GXY, S_GXX,
 S_GAIN, S_HEAD, S_STEADY_S, S_GXW, S_GWW, S_GWY, S_DZ_HAT, S_NEW_FREQ_S) = range(20)
S_LINE_X = 20
S_LINE_W = S_LINE_X + DELAY_LINE
S_C = S_LINE_W + DELAY_LINE
N_STATE = S_C + 2 * MAX_HARMONICS


def _nominal_rig(rig=None) -> dict:
    """The nominal values the servo takes from the rig the lab describes (default: sim.rig.DEFAULT_RIG)."""
    from ..rig import DEFAULT_RIG

    rig = rig or DEFAULT_RIG
    return {
        "piston_area_m2": rig.piston_area_m2,
        "flow_gain_m3_per_s_v_sqrt_pa": rig.flow_gain_m3_per_s_v_sqrt_pa,
        "dead_zone_v": rig.dead_zone_v,
        "command_limit_v": rig.command_limit_v,
    }


OPTIONS = {
    # nominal rig values (the rig's, never the isolator's); taken from sim.rig.DEFAULT_RIG when not given
    "piston_area_m2": Option(None, 1e-4, 1.0, "m2", meaning="nominal piston area A_p"),
    "flow_gain_m3_per_s_v_sqrt_pa": Option(None, 1e-10, 1e-4, "m3/(s V sqrt(Pa))", meaning="nominal valve flow gain"),
    "dead_zone_v": Option(None, 0.0, 5.0, "V", meaning="nominal valve dead zone (half width)"),
    "command_limit_v": Option(None, 0.1, 20.0, "V", meaning="valve command saturation"),
    # fixed design constants, the same on every isolator (docs/controller.md)
    "kp_per_s": Option(30.0, 1e-3, 500.0, "1/s", meaning="position loop gain: velocity demand per metre of error"),
    "velocity_lead_s": Option(0.006, 0.0, 0.1, "s", meaning="feed-forward lead for the valve lag (r' + tau r'')"),
    "learning_lag_s": Option(0.007, 0.0, 0.05, "s", meaning="delay of the nominal loop model the learning inverts"),
    "learning_gain": Option(0.8, 0.0, 1.5, "-", meaning="share of each harmonic's error removed per cycle"),
    "harmonics": Option(15, 0, MAX_HARMONICS, "-", "int", "harmonics of the target frequency learned"),
    "learning_max_hz": Option(12.0, 1e-3, 100.0, "Hz", meaning="harmonics above this frequency are not learned"),
    "dead_zone_ramp_v": Option(0.05, 1e-4, 2.0, "V", meaning="the dead-zone inverse ramps in over +-this"),
    "dead_zone_share": Option(1.0, 0.0, 2.0, "-", meaning="share of the dead zone that is compensated"),
    "min_pressure_drop_share": Option(0.05, 1e-3, 1.0, "-", meaning="floor of P_s - sgn(v) P_L, share of P_s"),
    "frequency_window_s": Option(0.1, 1e-3, 10.0, "s", meaning="forgetting time of the target-frequency estimate"),
    "amplitude_floor_m": Option(1.0e-3, 1e-6, 0.1, "m", meaning="learning normalises by max(envelope, this)"),
    "c1_max": Option(1.5, 0.0, 10.0, "-", meaning="projection bound of |c_1| (relative velocity)"),
    "ck_max": Option(0.5, 0.0, 10.0, "-", meaning="projection bound of |c_k|, k >= 2"),
    "c0_max_m_per_s": Option(0.02, 0.0, 1.0, "m/s", meaning="projection bound of the learned constant velocity"),
    "gain_window_s": Option(0.3, 1e-3, 100.0, "s", meaning="forgetting time of the flow-gain estimate"),
    "gain_min": Option(0.25, 1e-3, 1.0, "-", meaning="lower projection of the flow-gain ratio"),
    "gain_max": Option(6.0, 1.0, 100.0, "-", meaning="upper projection of the flow-gain ratio"),
    "gain_min_velocity_m_per_s": Option(0.005, 1e-6, 1.0, "m/s",
                                        meaning="the gain estimate moves only with this much RMS nominal velocity"),
    "steady_envelope_rate": Option(0.05, 1e-4, 1.0, "-", meaning="learning runs while the envelope is this steady"),
    "load_pressure_share": Option(1.0, 0.0, 1.0, "-", meaning="1: the valve inverse uses the measured P_L"),
    "dead_zone_adaptive": Option(1.0, 0.0, 1.0, "-", meaning="1: the dead zone is estimated with the flow gain"),
    "dead_zone_min_share": Option(0.5, 0.0, 1.0, "-", meaning="lower projection of the dead zone, share of nominal"),
    "dead_zone_max_share": Option(1.5, 1.0, 5.0, "-", meaning="upper projection of the dead zone, share of nominal"),
    # arbitrary (non-periodic) commands: the second-order lag of the valve and the oil column, fed forward
    "jerk_lead_s2": Option(0.0, 0.0, 1e-3, "s2", meaning="feed-forward of the target jerk (0: off, as on "
                           "sines, where the learning does it; time histories turn it on)"),
    "integral_per_s": Option(0.0, 0.0, 100.0, "1/s", meaning="integral action on the position error (0: off, as "
                             "on sines, where the learned constant does it; time histories turn it on)"),
}
DEFAULTS = {name: spec.default for name, spec in OPTIONS.items()}
#: what a time history (no repeating cycle to learn) runs with: no harmonic learning; an integral on the position
#: error takes over the learned constant (the valve's null offset, the friction's asymmetry)
HISTORY_MODE = {"learning_gain": 0.0, "integral_per_s": 1.0}
ADAPTED = (
    Adapted("model_m", "target r", "m", "the reference is the target itself: the feed-forward removes its lag"),
    Adapted("ar_hat", "flow gain ratio g", "-", "the valve's true flow gain over the nominal one (estimated)"),
    Adapted("ay_hat", "dead zone", "V", "the valve's dead zone (estimated)"),
    Adapted("as_hat", "learned frequency", "Hz", "the target frequency the learning is locked to (0: none)"),
)


def make_servo(rig=None, **options) -> Controller:
    """The learning servo controller; nominal rig values from ``rig`` (what the lab's rig file says; default
    sim.rig.DEFAULT_RIG) unless given as options."""
    o = check_options("servo", OPTIONS, options)
    for key, value in _nominal_rig(rig).items():
        if o[key] is None:
            o[key] = value
    params = np.zeros(N_PARAMS)
    params[P_AREA] = o["piston_area_m2"]
    params[P_KQ] = o["flow_gain_m3_per_s_v_sqrt_pa"]
    params[P_DZ] = o["dead_zone_v"]
    params[P_ULIM] = o["command_limit_v"]
    params[P_KP] = o["kp_per_s"]
    params[P_TAU_V] = o["velocity_lead_s"]
    params[P_TAU_L] = o["learning_lag_s"]
    params[P_GAMMA] = o["learning_gain"]
    params[P_NH] = o["harmonics"]
    params[P_FMAX] = o["learning_max_hz"]
    params[P_DZ_RAMP] = o["dead_zone_ramp_v"]
    params[P_DP_MIN] = o["min_pressure_drop_share"]
    params[P_TW] = o["frequency_window_s"]
    params[P_AFLOOR] = o["amplitude_floor_m"]
    params[P_C1MAX] = o["c1_max"]
    params[P_CKMAX] = o["ck_max"]
    params[P_C0MAX] = o["c0_max_m_per_s"]
    params[P_DZ_FRAC] = o["dead_zone_share"]
    params[P_GW] = o["gain_window_s"]
    params[P_GMIN] = o["gain_min"]
    params[P_GMAX] = o["gain_max"]
    params[P_GVMIN] = o["gain_min_velocity_m_per_s"]
    params[P_STEADY] = o["steady_envelope_rate"]
    params[P_PL_SHARE] = o["load_pressure_share"]
    params[P_DZ_ADAPT] = o["dead_zone_adaptive"]
    params[P_DZ_LO] = o["dead_zone_min_share"] * o["dead_zone_v"]
    params[P_DZ_HI] = o["dead_zone_max_share"] * o["dead_zone_v"]
    params[P_JERK_LEAD] = o["jerk_lead_s2"]
    params[P_INTEGRAL] = o["integral_per_s"]
    state = np.zeros(N_STATE)
    state[S_GAIN] = 1.0
    state[S_DZ_HAT] = o["dead_zone_v"]
    # prior of the valve estimate: two pseudo-samples consistent with the nominal valve (g = 1, DZ = DZ_n),
    # a moving one (x = a, w = 0, velocity a) and one at the dead-zone edge (x = a, w = a / DZ_n, velocity 0);
    # it fades with the forgetting time, so the first samples cannot throw the estimate to its bounds
    a = o["gain_min_velocity_m_per_s"]
    b = a / max(o["dead_zone_v"], 1e-3)
    state[S_GXX] = a * a + (o["dead_zone_v"] * b) ** 2
    state[S_GXW] = o["dead_zone_v"] * b * b
    state[S_GWW] = b * b
    state[S_GXY] = a * a
    state[S_GWY] = 0.0
    return Controller("servo", KIND, params, state, o)


@njit(cache=True)
def valve_inverse(v, p_load, p_supply, area, kq, dz, dz_ramp, dp_min_share):
    """Command u that makes the nominal valve pass the flow area * v: inverse of eq. (3) with the dead zone."""
    sgn = 1.0 if v >= 0.0 else -1.0
    dp = p_supply - sgn * p_load
    dp_min = dp_min_share * p_supply
    if dp < dp_min:
        dp = dp_min
    u_lin = area * v / (kq * np.sqrt(dp))
    ramp = u_lin / dz_ramp
    if ramp > 1.0:
        ramp = 1.0
    elif ramp < -1.0:
        ramp = -1.0
    return u_lin + dz * ramp


@njit(cache=True)
def servo_step(p, s, meas, dt, report):
    """One control period of the learning servo controller (see the module docstring)."""
    r = meas[M_TARGET]
    rd = meas[M_TARGET_RATE]
    y = meas[M_POSITION]
    if s[S_STARTED] < 0.5:
        s[S_RD1] = rd
        s[S_RD2] = rd
        s[S_YPREV] = y
        for i in range(2 * DELAY_LINE):
            s[S_LINE_X + i] = np.nan
        s[S_STARTED] = 1.0
    rd1 = s[S_RD1]
    rd2 = s[S_RD2]
    # target acceleration at t - dt/2 and jerk at t - dt, from the exact target rate
    rdd = (rd - rd1) / dt
    rddd = (rd - 2.0 * rd1 + rd2) / (dt * dt)
    s[S_RD2] = rd1
    s[S_RD1] = rd
    # target frequency: w^2 = -r''' r' / r'^2 for a sine, averaged with forgetting
    forget = dt / p[P_TW]
    s[S_NUM] += forget * (-rddd * rd1 - s[S_NUM])
    s[S_DEN] += forget * (rd1 * rd1 - s[S_DEN])
    omega_est = 0.0
    if s[S_DEN] > 1e-30 and s[S_NUM] > 0.0:
        omega_est = np.sqrt(s[S_NUM] / s[S_DEN])
    # steady envelope (not in a taper, not at a block change): the learning runs only then
    rd_mid = 0.5 * (rd + rd1)
    # the velocity amplitude seen with the current frequency estimate (constant on a steady sine; with the
    # frequency learned before, a new block's sine would never look steady), steady for a quarter of a period
    v_est = 0.0
    if omega_est > 0.0:
        v_est = np.sqrt(rd_mid * rd_mid + (rdd / omega_est) ** 2)
    if omega_est > 2.0 * np.pi * 1e-3 and v_est > 0.0 and (
            abs(v_est - s[S_VENV]) < p[P_STEADY] * omega_est * v_est * dt):
        s[S_STEADY_S] += dt
    else:
        s[S_STEADY_S] = 0.0
    steady = omega_est > 0.0 and s[S_STEADY_S] > 0.5 * np.pi / omega_est
    s[S_VENV] = v_est
    nh = int(p[P_NH])
    w_l = s[S_OMEGA_LEARNED]
    if steady and w_l > 0.0 and abs(omega_est - w_l) > 0.05 * w_l:
        # a new frequency only once it has been seen on a steady sine for a whole period: the start of a
        # taper-out looks steady for a while, with a frequency estimate bent by the fading envelope
        s[S_NEW_FREQ_S] += dt
        steady = s[S_NEW_FREQ_S] > 2.0 * np.pi / omega_est
        if steady:  # what was learned at the old frequency does not apply
            for i in range(2 * MAX_HARMONICS):
                s[S_C + i] = 0.0
            w_l = 0.0
    else:
        s[S_NEW_FREQ_S] = 0.0
    if steady:
        if w_l <= 0.0:  # lock on
            s[S_OMEGA_LEARNED] = omega_est
        else:  # refine, over a quarter period: a short bend of the estimate (a taper's start) barely moves it
            s[S_OMEGA_LEARNED] = w_l + min(1.0, dt * omega_est / (0.5 * np.pi)) * (omega_est - w_l)
    omega = s[S_OMEGA_LEARNED]
    v_env = 0.0
    if omega > 0.0:
        v_env = np.sqrt(rd_mid * rd_mid + (rdd / omega) ** 2)
        nmax = int(p[P_FMAX] * 2.0 * np.pi / omega)
        if nmax < nh:
            nh = nmax
    # valve estimate: table velocity = g (x - DZ w) with x = the velocity the nominal valve without dead zone
    # gives at the command sent tau_l earlier and w = its velocity per volt times sgn(u); least squares of g
    # and g DZ with forgetting (the dead zone only if dead_zone_adaptive), projected onto their bounds
    head = int(s[S_HEAD])
    lag = int(round(p[P_TAU_L] / dt))
    if lag > DELAY_LINE - 1:
        lag = DELAY_LINE - 1
    if lag < 1:
        lag = 1
    old = (head - lag) % DELAY_LINE
    xd = s[S_LINE_X + old]
    wd = s[S_LINE_W + old]
    vel = (y - s[S_YPREV]) / dt
    s[S_YPREV] = y
    if np.isfinite(xd):
        gf = dt / p[P_GW]
        s[S_GXX] += gf * (xd * xd - s[S_GXX])
        s[S_GXY] += gf * (vel * xd - s[S_GXY])
        s[S_GXW] += gf * (xd * wd - s[S_GXW])
        s[S_GWW] += gf * (wd * wd - s[S_GWW])
        s[S_GWY] += gf * (vel * wd - s[S_GWY])
        if s[S_GXX] > p[P_GVMIN] ** 2:
            sxx, sxw, sww, sxy, swy = s[S_GXX], s[S_GXW], s[S_GWW], s[S_GXY], s[S_GWY]
            det = sxx * sww - sxw * sxw
            # excitation test in the coordinates (x - DZ_n w, w): x alone is nearly collinear with w when the
            # dead zone dominates the command (slow tests); the shear leaves det and the solution unchanged
            dzn = p[P_DZ_LO] + 0.5 * (p[P_DZ_HI] - p[P_DZ_LO])
            szz = sxx - 2.0 * dzn * sxw + dzn * dzn * sww
            if p[P_DZ_ADAPT] > 0.5 and det > 0.02 * szz * sww:
                g_new = (sxy * sww - sxw * swy) / det
                eta = (sxy * sxw - sxx * swy) / det  # g DZ
                if g_new > 0.0:
                    s[S_GAIN] = min(max(g_new, p[P_GMIN]), p[P_GMAX])
                    s[S_DZ_HAT] = min(max(eta / g_new, p[P_DZ_LO]), p[P_DZ_HI])
            else:
                dz = s[S_DZ_HAT]
                szz = sxx - 2.0 * dz * sxw + dz * dz * sww
                if szz > 0.0:
                    s[S_GAIN] = min(max((sxy - dz * swy) / szz, p[P_GMIN]), p[P_GMAX])
    gain = s[S_GAIN]
    # velocity demand: feed-forward with lead (and, for arbitrary commands, the jerk through the second-order
    # lag of the valve and the oil column), position feedback, learned periodic feed-forward
    e = r - y
    kp = p[P_KP]
    v = rd + p[P_TAU_V] * rdd + kp * e + s[S_C0]
    if p[P_JERK_LEAD] > 0.0:
        v += p[P_JERK_LEAD] * rddd
    if p[P_INTEGRAL] > 0.0 and not s[S_SAT] > 0.5:  # the constant velocity a null offset asks, integrated
        c0max = p[P_C0MAX]
        s[S_C0] = min(max(s[S_C0] + p[P_INTEGRAL] * kp * e * dt, -c0max), c0max)
    theta = 0.0
    if omega > 0.0 and nh >= 1:
        theta = np.arctan2(-rdd / omega, rd_mid) + 0.5 * omega * dt
        c1 = np.cos(theta)
        s1 = np.sin(theta)
        ck, sk = c1, s1
        acc = 0.0
        for k in range(nh):
            a = s[S_C + 2 * k]
            b = s[S_C + 2 * k + 1]
            acc += a * ck - b * sk
            ck, sk = ck * c1 - sk * s1, sk * c1 + ck * s1
        v += v_env * acc
    p_load = p[P_PL_SHARE] * meas[M_LOAD_PRESSURE]
    p_supply = meas[M_SUPPLY_PRESSURE]
    u = valve_inverse(v / gain, p_load, p_supply, p[P_AREA], p[P_KQ], p[P_DZ_FRAC] * s[S_DZ_HAT], p[P_DZ_RAMP],
                      p[P_DP_MIN])
    ulim = p[P_ULIM]
    saturated = abs(u) >= ulim
    if u > ulim:
        u = ulim
    elif u < -ulim:
        u = -ulim
    s[S_SAT] = 1.0 if saturated else 0.0
    # regressors of the valve estimate for the command actually applied (NaN inside the dead zone: no flow)
    head = (head + 1) % DELAY_LINE
    xs = np.nan
    ws = np.nan
    if abs(u) > s[S_DZ_HAT]:
        sgn_u = 1.0 if u > 0.0 else -1.0
        dp = p_supply - sgn_u * p_load
        if dp < p[P_DP_MIN] * p_supply:
            dp = p[P_DP_MIN] * p_supply
        per_volt = p[P_KQ] * np.sqrt(dp) / p[P_AREA]
        xs = per_volt * u
        ws = per_volt * sgn_u
    s[S_LINE_X + head] = xs
    s[S_LINE_W + head] = ws
    s[S_HEAD] = head
    # learning update (only on a steady sine and unsaturated), with projection of each coefficient
    if steady and nh >= 1 and not saturated:
        gamma = p[P_GAMMA]
        a_eff = max(v_env / omega, p[P_AFLOOR])
        g = gamma * dt / (np.pi * a_eff)
        # constant term: the error's mean through the loop's DC gain 1/K_p
        c0 = s[S_C0] + gamma * kp * e * omega * dt / (2.0 * np.pi)
        c0max = p[P_C0MAX]
        s[S_C0] = min(max(c0, -c0max), c0max)
        tau = p[P_TAU_L]
        c1 = np.cos(theta)
        s1 = np.sin(theta)
        cl = np.cos(omega * tau)
        sl = np.sin(omega * tau)
        ck, sk = c1, s1
        cd, sd = cl, sl
        for k in range(nh):
            kw = (k + 1) * omega
            # L_k = (K_p + j k w) exp(j k w tau): inverse of the nominal loop from dv to y
            lr = kp * cd - kw * sd
            li = kp * sd + kw * cd
            # z = e exp(-j k theta) L_k
            zr = e * (ck * lr + sk * li)
            zi = e * (ck * li - sk * lr)
            # harmonics above the loop's bandwidth learn more slowly: their model is the least sure
            gk = g * min(1.0, kp / kw)
            a = s[S_C + 2 * k] + gk * zr
            b = s[S_C + 2 * k + 1] + gk * zi
            bound = p[P_C1MAX] if k == 0 else p[P_CKMAX]
            mag = np.sqrt(a * a + b * b)
            if mag > bound:
                a *= bound / mag
                b *= bound / mag
            s[S_C + 2 * k] = a
            s[S_C + 2 * k + 1] = b
            ck, sk = ck * c1 - sk * s1, sk * c1 + ck * s1
            cd, sd = cd * cl - sd * sl, sd * cl + cd * sl
    report[R_MODEL] = r
    report[R_AR] = gain
    report[R_AY] = s[S_DZ_HAT]
    report[R_AS] = omega / (2.0 * np.pi)
    return u
