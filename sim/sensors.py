"""Sensor model of the simulated rig: latency, noise and resolution of the position and pressure readings.

Each period the true table position and load pressure enter a history; the reading is the value
``latency`` ago (linear interpolation between periods, the initial value before the history starts),
plus Gaussian noise of the given RMS, rounded to the resolution (position only). All zero by default:
the reading is then the true value.

The noise is a pure function of (seed, period, channel) (splitmix64 hashed to two uniforms, Box-Muller),
so the compiled engine, the driver's per-period path and the rig emulator read exactly the same values,
whatever chunking or call order they use.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

HISTORY = 256  # periods of history kept: the longest latency is HISTORY - 2 periods
MAX_LATENCY_S = 0.2

# Packed parameters.
S_POS_LATENCY, S_POS_NOISE, S_POS_RESOLUTION, S_PL_LATENCY, S_PL_NOISE, S_SEED = range(6)
N_SENSOR_PARAMS = 6
CH_POSITION, CH_PRESSURE = 0, 1


def pack_sensors(rig, control_period_s: float, seed: int = 0) -> np.ndarray:
    """Sensor parameters of a ``RigParameters`` (latencies in periods) for the compiled ``sense``."""
    for name in ("position_latency_s", "pressure_latency_s"):
        latency = getattr(rig, name)
        if not (0.0 <= latency <= MAX_LATENCY_S):
            raise ValueError(f"{name} = {latency!r} s is outside the allowed range [0, {MAX_LATENCY_S:g}] s")
    for name in ("position_noise_rms_m", "position_resolution_m", "pressure_noise_rms_pa"):
        value = getattr(rig, name)
        if not (math.isfinite(value) and value >= 0.0):
            raise ValueError(f"{name} = {value!r} must be a finite number >= 0")
    if not (isinstance(seed, int) and 0 <= seed < 2 ** 63):
        raise ValueError(f"noise seed = {seed!r} must be a whole number in [0, 2**63)")
    p = np.empty(N_SENSOR_PARAMS)
    p[S_POS_LATENCY] = rig.position_latency_s / control_period_s
    p[S_POS_NOISE] = rig.position_noise_rms_m
    p[S_POS_RESOLUTION] = rig.position_resolution_m
    p[S_PL_LATENCY] = rig.pressure_latency_s / control_period_s
    p[S_PL_NOISE] = rig.pressure_noise_rms_pa
    p[S_SEED] = float(seed)
    return p


def new_history() -> np.ndarray:
    """Sensor state: row 0 and 1 the position and pressure history, [2, 0] the last period recorded."""
    h = np.zeros((3, HISTORY))
    h[2, 0] = -1.0
    return h


@njit(cache=True, error_model="numpy")
def _splitmix64(z):
    z = z + np.uint64(0x9E3779B97F4A7C15)
    z = (z ^ (z >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
    z = (z ^ (z >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
    return z ^ (z >> np.uint64(31))


@njit(cache=True, error_model="numpy")
def standard_normal(seed, period, channel):
    """A standard normal number that depends only on (seed, period, channel)."""
    key = np.uint64(seed) * np.uint64(0x100000001B3) + np.uint64(period) * np.uint64(8) + np.uint64(channel)
    z1 = _splitmix64(key)
    z2 = _splitmix64(z1)
    u1 = (float(z1 >> np.uint64(11)) + 0.5) * (1.0 / 9007199254740992.0)
    u2 = float(z2 >> np.uint64(11)) * (1.0 / 9007199254740992.0)
    return math.sqrt(-2.0 * math.log(u1)) * math.cos(2.0 * math.pi * u2)


@njit(cache=True, error_model="numpy")
def _delayed(history, row, k, latency_periods):
    """The recorded value of ``row`` latency_periods before period k (interpolated)."""
    whole = int(latency_periods)
    frac = latency_periods - whole
    i0 = k - whole
    if i0 < 0:
        i0 = 0
    i1 = i0 - 1 if frac > 0.0 else i0
    if i1 < 0:
        i1 = 0
    a = history[row, i0 % HISTORY]
    if i1 == i0:
        return a
    return (1.0 - frac) * a + frac * history[row, i1 % HISTORY]


@njit(cache=True, error_model="numpy", inline="always")
def sense(position_m, load_pressure_pa, k, sp, history, out):
    """Readings at period k: out[0] the position, out[1] the load pressure. Records the true values once
    per period (a second call in the same period reads without recording)."""
    if k > history[2, 0]:
        history[0, k % HISTORY] = position_m
        history[1, k % HISTORY] = load_pressure_pa
        history[2, 0] = k
    y = position_m
    if sp[S_POS_LATENCY] > 0.0:
        y = _delayed(history, 0, k, sp[S_POS_LATENCY])
    if sp[S_POS_NOISE] > 0.0:
        y += sp[S_POS_NOISE] * standard_normal(int(sp[S_SEED]), k, CH_POSITION)
    res = sp[S_POS_RESOLUTION]
    if res > 0.0:
        y = np.round(y / res) * res
    pl = load_pressure_pa
    if sp[S_PL_LATENCY] > 0.0:
        pl = _delayed(history, 1, k, sp[S_PL_LATENCY])
    if sp[S_PL_NOISE] > 0.0:
        pl += sp[S_PL_NOISE] * standard_normal(int(sp[S_SEED]), k, CH_PRESSURE)
    out[0] = y
    out[1] = pl
