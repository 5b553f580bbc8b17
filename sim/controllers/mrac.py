"""The paper's model reference adaptive controller: control law eq. (9), adaptation laws eqs. (18)-(20),
reference model eq. (8).

    u = (a_r r + a_y y) k atanh(y / a_s) / y                        (9)
    a_s' = -gamma_as e atanh(y)        (literal, y in metres)        (18)
    a_y' = -gamma e y                                                (19)
    a_r' = -gamma e r                                                (20)
    e = y - y_m

Numerical safety: atanh(y/a_s)/y is evaluated as atanh_over_x(y/a_s)/a_s, so y = 0 is its limit
1/a_s; |y/a_s| is clipped to ``x_clip`` < 1 so |y| >= a_s_hat gives a large finite gain that the
command saturation then limits; a_s_hat is kept at or above ``as_min_m`` so eq. (9) stays defined.

Eq. (18) as printed takes atanh(y) with y in metres, which makes a_s_hat move very slowly. The
option ``dimensionless_as=True`` uses atanh(y / a_s_hat) instead: the same sign structure, but a
regressor of order one whatever the unit of y (document both; literal is the default).
"""

from __future__ import annotations

import numpy as np
from numba import njit

from ..models import K_VOLT, atanh_over_x, reference_model_step
from .base import (
    M_POSITION,
    M_TARGET,
    R_AR,
    R_AS,
    R_AY,
    R_MODEL,
    Adapted,
    Controller,
    Option,
    check_options,
)

KIND = 1
# Parameter indices.
A_M, B_M, GAMMA, GAMMA_AS, DIMENSIONLESS, AS_MIN, X_CLIP = range(7)
# State indices.
S_YM, S_AR, S_AY, S_AS = range(4)

OPTIONS = {  # section V of the paper for the defaults
    "a_m_per_s": Option(50.0, 1e-3, 1e4, "1/s", meaning="reference model pole a_m, eq. (8)"),
    "b_m_per_s": Option(50.0, 1e-3, 1e4, "1/s", meaning="reference model gain b_m, eq. (8)"),
    "gamma": Option(1.0e5, 0.0, 1e12, "-", meaning="adaptation gain of a_y_hat and a_r_hat, eqs. (19)-(20)"),
    "gamma_as": Option(2.0, 0.0, 1e6, "-", meaning="adaptation gain of a_s_hat, eq. (18)"),
    "as0_m": Option(0.04, 1e-4, 1.0, "m", meaning="a_s_hat(0)"),
    "ar0": Option(0.0, -1e6, 1e6, "-", meaning="a_r_hat(0)"),
    "ay0": Option(0.0, -1e6, 1e6, "-", meaning="a_y_hat(0)"),
    "dimensionless_as": Option(False, kind="bool", meaning="eq. (18) with atanh(y / a_s_hat) instead of atanh(y)"),
    "as_min_m": Option(1.0e-3, 1e-6, 1.0, "m", meaning="floor of a_s_hat"),
    "x_clip": Option(0.999, 0.5, 0.999999, "-", meaning="y / a_s_hat is clipped to +-this in eq. (9)"),
}
PAPER_DEFAULTS = {name: spec.default for name, spec in OPTIONS.items()}
ADAPTED = (
    Adapted("model_m", "reference model y_m", "m", "output of the reference model, eq. (8)"),
    Adapted("ar_hat", "a_r_hat", "-", "adapted gain on the target r, eq. (20)"),
    Adapted("ay_hat", "a_y_hat", "-", "adapted gain on the position y, eq. (19)"),
    Adapted("as_hat", "a_s_hat", "m", "adapted steady-state displacement parameter, eq. (18)"),
)


def make_mrac(rig=None, **options) -> Controller:
    """The paper's MRAC with section V defaults; any default can be overridden by keyword."""
    o = check_options("mrac", OPTIONS, options)
    params = np.array([
        o["a_m_per_s"], o["b_m_per_s"], o["gamma"], o["gamma_as"],
        1.0 if o["dimensionless_as"] else 0.0, o["as_min_m"], o["x_clip"],
    ])
    state = np.array([0.0, o["ar0"], o["ay0"], o["as0_m"]])
    return Controller("mrac", KIND, params, state, o)


@njit(cache=True, error_model="numpy", inline="always")
def mrac_step(p, s, meas, dt, report):
    """One control period of eqs. (8), (9), (18)-(20); Euler update of the adapted parameters."""
    y = meas[M_POSITION]
    r = meas[M_TARGET]
    y_m = s[S_YM]
    a_r = s[S_AR]
    a_y = s[S_AY]
    a_s = max(s[S_AS], p[AS_MIN])
    x = y / a_s
    if x > p[X_CLIP]:
        x = p[X_CLIP]
    elif x < -p[X_CLIP]:
        x = -p[X_CLIP]
    u = (a_r * r + a_y * y) * K_VOLT * atanh_over_x(x) / a_s  # eq. (9)

    report[R_MODEL] = y_m
    report[R_AR] = a_r
    report[R_AY] = a_y
    report[R_AS] = a_s

    e = y - y_m
    if p[DIMENSIONLESS] > 0.5:
        regressor_as = np.arctanh(x)
    else:
        regressor_as = np.arctanh(min(max(y, -0.999999), 0.999999))  # eq. (18) literal, y in m
    s[S_AS] = max(a_s - p[GAMMA_AS] * e * regressor_as * dt, p[AS_MIN])  # eq. (18)
    s[S_AY] = a_y - p[GAMMA] * e * y * dt  # eq. (19)
    s[S_AR] = a_r - p[GAMMA] * e * r * dt  # eq. (20)
    s[S_YM] = reference_model_step(y_m, r, p[A_M], p[B_M], dt)  # eq. (8)
    return u
