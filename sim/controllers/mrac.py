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
    Controller,
)

KIND = 1
# Parameter indices.
A_M, B_M, GAMMA, GAMMA_AS, DIMENSIONLESS, AS_MIN, X_CLIP = range(7)
# State indices.
S_YM, S_AR, S_AY, S_AS = range(4)

PAPER_DEFAULTS = {
    "a_m_per_s": 50.0,  # section V
    "b_m_per_s": 50.0,
    "gamma": 1.0e5,
    "gamma_as": 2.0,
    "as0_m": 0.04,
    "ar0": 0.0,
    "ay0": 0.0,
    "dimensionless_as": False,
    "as_min_m": 1.0e-3,
    "x_clip": 0.999,
}


def make_mrac(**options) -> Controller:
    """The paper's MRAC with section V defaults; any default can be overridden by keyword."""
    unknown = set(options) - set(PAPER_DEFAULTS)
    if unknown:
        raise ValueError(f"unknown mrac option(s) {sorted(unknown)}; allowed: {sorted(PAPER_DEFAULTS)}")
    o = {**PAPER_DEFAULTS, **options}
    params = np.array([
        o["a_m_per_s"], o["b_m_per_s"], o["gamma"], o["gamma_as"],
        1.0 if o["dimensionless_as"] else 0.0, o["as_min_m"], o["x_clip"],
    ])
    state = np.array([0.0, o["ar0"], o["ay0"], o["as0_m"]])
    return Controller("mrac", KIND, params, state, o)


@njit(cache=True)
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
