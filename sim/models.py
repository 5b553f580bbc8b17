"""Reduced models of the paper: the identified first-order model, eq. (7), and the reference model, eq. (8)."""

from __future__ import annotations

import numpy as np
from numba import njit

K_VOLT = 1.0  # k of eqs. (5)-(9): "voltage dimension and unitary value"
ATANH_SERIES_BELOW = 1e-4  # |x| below which atanh(x)/x is taken from its series 1 + x^2/3


@njit(cache=True, error_model="numpy")
def atanh_over_x(x):
    """atanh(x) / x with its removable singularity at x = 0 filled in (limit 1)."""
    if abs(x) < ATANH_SERIES_BELOW:
        return 1.0 + x * x / 3.0
    return np.arctanh(x) / x


@njit(cache=True, error_model="numpy")
def first_order_rate(y, u, a_p, a_s):
    """dy/dt of the first-order model, eq. (7): -a_p y + a_p y / (k atanh(y/a_s)) u.

    y / atanh(y/a_s) -> a_s at y = 0; defined for |y| < a_s (the model's steady state a_s tanh(u/k)
    never reaches |y| = a_s).
    """
    x = y / a_s
    if abs(x) >= 1.0:
        return -a_p * y
    return -a_p * y + a_p * a_s / (K_VOLT * atanh_over_x(x)) * u


def first_order_response(t_s: np.ndarray, u_v: np.ndarray, a_p: float, a_s: float, y0_m: float = 0.0) -> np.ndarray:
    """Response of eq. (7) to a sampled input (held between samples), RK4 with 4 substeps per sample."""
    return _first_order_response(np.asarray(t_s, float), np.asarray(u_v, float), a_p, a_s, y0_m)


@njit(cache=True, error_model="numpy")
def _first_order_response(t, u, a_p, a_s, y0):
    y = np.empty(t.size)
    y[0] = y0
    for i in range(t.size - 1):
        h = (t[i + 1] - t[i]) / 4.0
        yi = y[i]
        for _ in range(4):
            k1 = first_order_rate(yi, u[i], a_p, a_s)
            k2 = first_order_rate(yi + 0.5 * h * k1, u[i], a_p, a_s)
            k3 = first_order_rate(yi + 0.5 * h * k2, u[i], a_p, a_s)
            k4 = first_order_rate(yi + h * k3, u[i], a_p, a_s)
            yi += h * (k1 + 2 * k2 + 2 * k3 + k4) / 6.0
        y[i + 1] = yi
    return y


@njit(cache=True, error_model="numpy")
def reference_model_step(y_m, r, a_m, b_m, dt):
    """Exact zero-order-hold step of the reference model, eq. (8): y_m' = -a_m y_m + b_m r."""
    decay = np.exp(-a_m * dt)
    return decay * y_m + b_m / a_m * (1.0 - decay) * r
