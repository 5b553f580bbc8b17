"""Fixed-gain PID position controller with anti-windup: the conventional baseline the paper argues against.

    u = K_p e + K_i integral(e) + K_d d(e)/dt (filtered),  e = r - y

The derivative acts on the measurement (no kick on target steps) through a first-order filter
of time constant ``derivative_filter_s``. Anti-windup by conditional integration: the integral is
frozen while the command is saturated and the error would drive it further into saturation.
Gains were tuned once on IUT_a at 100 bar, 0.5 Hz, 20 mm by scripts/tune_pid.py (best RMS error with a
gain margin of 2) and are never retuned: that is the point of a baseline.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from .base import M_POSITION, M_TARGET, R_AR, R_AS, R_AY, R_MODEL, Controller, Option, check_options

KIND = 2
KP, KI, KD, TF, ULIM = range(5)
S_INTEGRAL, S_DFILT, S_YPREV, S_STARTED = range(4)

OPTIONS = {  # tuned once by scripts/tune_pid.py
    "kp_v_per_m": Option(1400.0, 0.0, 1e7, "V/m", meaning="proportional gain"),
    "ki_v_per_m_s": Option(80000.0, 0.0, 1e9, "V/(m s)", meaning="integral gain"),
    "kd_v_s_per_m": Option(0.0, 0.0, 1e5, "V s/m", meaning="derivative gain (on the measurement)"),
    "derivative_filter_s": Option(0.005, 1e-4, 1.0, "s", meaning="time constant of the derivative's filter"),
    "command_limit_v": Option(10.0, 0.1, 20.0, "V", meaning="saturation used by the anti-windup"),
}
TUNED_DEFAULTS = {name: spec.default for name, spec in OPTIONS.items()}
ADAPTED = ()  # a fixed-gain controller adapts nothing


def make_pid(rig=None, **options) -> Controller:
    o = check_options("pid", OPTIONS, options)
    params = np.array([o["kp_v_per_m"], o["ki_v_per_m_s"], o["kd_v_s_per_m"], o["derivative_filter_s"],
                       o["command_limit_v"]])
    return Controller("pid", KIND, params, np.zeros(4), o)


@njit(cache=True, error_model="numpy", inline="always")
def pid_step(p, s, meas, dt, report):
    y = meas[M_POSITION]
    e = meas[M_TARGET] - y
    if s[S_STARTED] < 0.5:
        s[S_YPREV] = y
        s[S_STARTED] = 1.0
    # filtered derivative of -y
    alpha = dt / (p[TF] + dt)
    s[S_DFILT] += alpha * (-(y - s[S_YPREV]) / dt - s[S_DFILT])
    s[S_YPREV] = y
    u = p[KP] * e + p[KI] * s[S_INTEGRAL] + p[KD] * s[S_DFILT]
    saturated_up = u > p[ULIM] and e > 0.0
    saturated_down = u < -p[ULIM] and e < 0.0
    if not (saturated_up or saturated_down):
        s[S_INTEGRAL] += e * dt
    report[R_MODEL] = np.nan
    report[R_AR] = np.nan
    report[R_AY] = np.nan
    report[R_AS] = np.nan
    return u
