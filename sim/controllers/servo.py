"""Learning servo controller: flow-linearised velocity feed-forward, position feedback and harmonic
learning of the periodic error. Design and stability argument: docs/controller.md.

    v   = r' + tau_v r'' + K_p (r - y) + dv                    velocity demand, m/s
    dv  = c_0 + V_env Re sum_k c_k exp(j k theta)              learned periodic feed-forward
    Q   = A_n v                                                flow demand, m3/s
    u_l = Q / (K_qn sqrt(P_s - sgn(v) P_L))                    inverse of the valve flow law, eq. (3)
    u   = u_l + DZ_n ramp(u_l / delta)                         dead-zone inverse (smoothed)

theta and V_env (the phase and the velocity amplitude of the sine target) come from the target rate r'
and its differences, so the controller needs no profile information: for r = A sin(w t),
w^2 = -r''' r' / r'^2 exactly at every instant. The complex coefficients c_k (harmonic k = 1..H of the
target frequency, dimensionless: relative to the target's peak velocity) learn the periodic error:

    c_k += gamma dt / (pi A_eff) (r - y) exp(-j k theta) (K_p + j k w) exp(j k w tau_l)

that is, the error's k-th Fourier coefficient divided by a nominal model of the closed loop from dv to y
(1 / (s + K_p) with a pure delay for the valve), so each harmonic's error shrinks by about (1 - gamma)
per cycle. The update is frozen while the command saturates (the error then says nothing about the
feed-forward) and each |c_k| is projected onto a bound. Only the measured position, the load pressure,
the supply pressure setting and nominal rig values (A_p, K_q, dead zone, command limit) are used.

Report: model_m = r (the feed-forward removes the reference lag, so the reference model is the target
itself); ar_hat = learned velocity gain on the first harmonic (1 + Re c_1: > 1 means the nominal flow
gain is too high); ay_hat = learned phase lead of the first harmonic in degrees; as_hat = estimated
target frequency in Hz.
"""

from __future__ import annotations

import math

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
    Controller,
)

KIND = 3
MAX_HARMONICS = 24

# Parameter indices.
(P_AREA, P_KQ, P_DZ, P_ULIM, P_KP, P_TAU_V, P_TAU_L, P_GAMMA, P_NH, P_FMAX, P_DZ_RAMP, P_DP_MIN,
 P_TW, P_AFLOOR, P_C1MAX, P_CKMAX, P_C0MAX, P_DZ_FRAC, P_GW, P_GMIN, P_GMAX, P_GVMIN, P_STEADY,
 P_PL_SHARE) = range(24)
N_PARAMS = 24
DELAY_LINE = 32  # samples of the nominal-velocity history kept for the flow-gain estimate

# State indices; the delay line and the harmonic coefficients (real, imaginary) follow.
(S_STARTED, S_RD1, S_RD2, S_NUM, S_DEN, S_OMEGA_LEARNED, S_C0, S_SAT, S_VENV, S_YPREV, S_GXY, S_GXX,
 S_GAIN, S_HEAD, S_STEADY_S) = range(15)
S_LINE = 15
S_C = S_LINE + DELAY_LINE
N_STATE = S_C + 2 * MAX_HARMONICS


def _nominal_rig() -> dict:
    from ..rig import DEFAULT_RIG

    return {
        "piston_area_m2": DEFAULT_RIG.piston_area_m2,
        "flow_gain_m3_per_s_v_sqrt_pa": DEFAULT_RIG.flow_gain_m3_per_s_v_sqrt_pa,
        "dead_zone_v": DEFAULT_RIG.dead_zone_v,
        "command_limit_v": DEFAULT_RIG.command_limit_v,
    }


DEFAULTS = {
    # nominal rig values (the rig's, never the isolator's); taken from sim.rig.DEFAULT_RIG when not given
    "piston_area_m2": None,
    "flow_gain_m3_per_s_v_sqrt_pa": None,
    "dead_zone_v": None,
    "command_limit_v": None,
    # fixed design constants, the same on every isolator (docs/controller.md)
    "kp_per_s": 30.0,  # position loop gain: velocity demand per metre of error
    "velocity_lead_s": 0.006,  # feed-forward lead for the valve lag (r' + tau r'')
    "learning_lag_s": 0.007,  # delay in the nominal loop model the learning inverts (valve + sampling)
    "learning_gain": 0.5,  # share of each harmonic's error removed per cycle
    "harmonics": 15,  # harmonics of the target frequency learned (at most MAX_HARMONICS)
    "learning_max_hz": 12.0,  # harmonics above this frequency are not learned
    "dead_zone_ramp_v": 0.05,  # the dead-zone inverse ramps in over +-this command
    "dead_zone_share": 1.0,  # share of the nominal dead zone that is compensated
    "min_pressure_drop_share": 0.05,  # floor of P_s - sgn(v) P_L in the valve inverse, share of P_s
    "frequency_window_s": 0.1,  # forgetting time of the target-frequency estimate
    "amplitude_floor_m": 1.0e-3,  # learning normalises by max(envelope, this)
    "c1_max": 1.5,  # projection bound of |c_1| (relative velocity)
    "ck_max": 0.5,  # projection bound of |c_k|, k >= 2
    "c0_max_m_per_s": 0.02,  # projection bound of the learned constant velocity
    "gain_window_s": 0.3,  # forgetting time of the flow-gain estimate
    "gain_min": 0.25,  # projection of the flow-gain ratio (true / nominal)
    "gain_max": 4.0,
    "gain_min_velocity_m_per_s": 0.005,  # the gain estimate moves only with this much RMS nominal velocity
    "steady_envelope_rate": 0.02,  # learning runs while |d V_env/dt| / (w V_env) stays below this
    "load_pressure_share": 1.0,  # 1: the valve inverse uses the measured load pressure; 0: only P_s (ablation)
}


def make_servo(**options) -> Controller:
    """The learning servo controller; nominal rig values default to sim.rig.DEFAULT_RIG."""
    unknown = set(options) - set(DEFAULTS)
    if unknown:
        raise ValueError(f"unknown servo option(s) {sorted(unknown)}; allowed: {sorted(DEFAULTS)}")
    o = {**DEFAULTS, **{k: v for k, v in options.items() if v is not None}}
    for key, value in _nominal_rig().items():
        if o[key] is None:
            o[key] = value
    for key, value in o.items():
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
            raise ValueError(f"servo option {key} = {value!r} must be a finite number")
    for key in ("piston_area_m2", "flow_gain_m3_per_s_v_sqrt_pa", "command_limit_v", "kp_per_s",
                "frequency_window_s", "amplitude_floor_m", "dead_zone_ramp_v", "learning_max_hz"):
        if o[key] <= 0:
            raise ValueError(f"servo option {key} = {o[key]!r} must be > 0")
    if not 0 <= o["harmonics"] <= MAX_HARMONICS or int(o["harmonics"]) != o["harmonics"]:
        raise ValueError(f"servo option harmonics = {o['harmonics']!r} must be a whole number in [0, {MAX_HARMONICS}]")
    if not 0 <= o["learning_gain"] <= 1.5:
        raise ValueError(f"servo option learning_gain = {o['learning_gain']!r} must be in [0, 1.5]")
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
    state = np.zeros(N_STATE)
    state[S_GAIN] = 1.0
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
        for i in range(DELAY_LINE):
            s[S_LINE + i] = np.nan
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
    w_phase = s[S_OMEGA_LEARNED] if s[S_OMEGA_LEARNED] > 0.0 else omega_est
    v_env = 0.0
    if w_phase > 0.0:
        v_env = np.sqrt(rd_mid * rd_mid + (rdd / w_phase) ** 2)
    # steady for at least a quarter of a period
    if omega_est > 2.0 * np.pi * 1e-3 and v_env > 0.0 and (
            abs(v_env - s[S_VENV]) < p[P_STEADY] * omega_est * v_env * dt):
        s[S_STEADY_S] += dt
    else:
        s[S_STEADY_S] = 0.0
    steady = omega_est > 0.0 and s[S_STEADY_S] > 0.5 * np.pi / omega_est
    s[S_VENV] = v_env
    nh = int(p[P_NH])
    if steady:
        w_l = s[S_OMEGA_LEARNED]
        if w_l <= 0.0 or abs(omega_est - w_l) > 0.05 * w_l:
            # a new frequency: what was learned at the old one does not apply
            for i in range(2 * MAX_HARMONICS):
                s[S_C + i] = 0.0
        s[S_OMEGA_LEARNED] = omega_est
    omega = s[S_OMEGA_LEARNED]
    if omega > 0.0:
        nmax = int(p[P_FMAX] * 2.0 * np.pi / omega)
        if nmax < nh:
            nh = nmax
    # flow-gain ratio (true / nominal): least squares of the table velocity on the delayed nominal velocity
    head = int(s[S_HEAD])
    lag = int(round(p[P_TAU_L] / dt))
    if lag > DELAY_LINE - 1:
        lag = DELAY_LINE - 1
    if lag < 1:
        lag = 1
    x = s[S_LINE + (head - lag) % DELAY_LINE]
    vel = (y - s[S_YPREV]) / dt
    s[S_YPREV] = y
    if np.isfinite(x):
        gforget = dt / p[P_GW]
        s[S_GXY] += gforget * (vel * x - s[S_GXY])
        s[S_GXX] += gforget * (x * x - s[S_GXX])
        if s[S_GXX] > p[P_GVMIN] ** 2:
            s[S_GAIN] = min(max(s[S_GXY] / s[S_GXX], p[P_GMIN]), p[P_GMAX])
    gain = s[S_GAIN]
    # velocity demand: feed-forward with lead, position feedback, learned periodic feed-forward
    e = r - y
    kp = p[P_KP]
    v = rd + p[P_TAU_V] * rdd + kp * e + s[S_C0]
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
    u = valve_inverse(v / gain, p[P_PL_SHARE] * meas[M_LOAD_PRESSURE], meas[M_SUPPLY_PRESSURE], p[P_AREA], p[P_KQ],
                      p[P_DZ_FRAC] * p[P_DZ], p[P_DZ_RAMP], p[P_DP_MIN])
    ulim = p[P_ULIM]
    saturated = abs(u) >= ulim
    if u > ulim:
        u = ulim
    elif u < -ulim:
        u = -ulim
    s[S_SAT] = 1.0 if saturated else 0.0
    # the nominal velocity this command asks for (NaN: saturated, says nothing about the gain)
    head = (head + 1) % DELAY_LINE
    s[S_LINE + head] = np.nan if saturated else v / gain
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
            a = s[S_C + 2 * k] + g * zr
            b = s[S_C + 2 * k + 1] + g * zi
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
    report[R_AY] = np.degrees(np.arctan2(s[S_C + 1], 1.0 + s[S_C]))
    report[R_AS] = omega / (2.0 * np.pi)
    return u
