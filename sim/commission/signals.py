"""A commissioning record as the fits use it: the channels a rig measures, low-passed alike, their derivatives
and their sensors' noise.

What a rig measures each period: the valve command u it was sent (zero-order hold over the period), the
position reading y_L (the table's position ``L`` late), the load pressure P_L, the specimen's force F and the
supply pressure P_s. Low-passed alike (zero phase, ``CORNER_HZ``), so that derivatives can be taken, they obey
eq. (3) (sim.commission.flow, sim.commission.force). Each reading's white noise is measured from its content
above ``NOISE_BAND_HZ``: the balances are judged against what it leaves to explain (``explained``), and the
flow balance takes its regressor's noise out of its normal equations.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy import signal

from ..measurement import STATUS_COMMAND_MISSED, measured_rows
from ..samples import Samples

CORNER_HZ = 150.0  # the zero-phase low-pass before derivatives: above the oil column and most valves' bandwidth
FLOW_CORNER_HZ = 35.0  # the flow balance's own low-pass: its P_L' is the noisiest regressor of either balance
NOISE_BAND_HZ = 350.0  # a reading's content above this is its sensor's noise (the rig moves far below it)
EDGE_S = 0.05  # the filter's start and end transients are not fitted
ANOMALY_MARGIN_S = 0.015  # left out either side of a lost measurement or a late command
MAX_ANOMALY_SHARE = 0.1  # more than this share of lost or late periods: the record is not fitted


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
    #: the flow balance's velocity and P_L', low-passed at FLOW_CORNER_HZ (``flow_corner_hz``)
    v_flow: np.ndarray = field(init=False)
    p_load_rate_flow: np.ndarray = field(init=False)
    flow_corner_hz: float = field(init=False)
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
        self.flow_corner_hz = FLOW_CORNER_HZ
        self.v_flow = derivative(lowpass(self.y, self.dt_s, self.flow_corner_hz), self.dt_s)
        self.p_load_rate_flow = derivative(lowpass(self.p_load, self.dt_s, self.flow_corner_hz), self.dt_s)
        flow_gains = noise_gains(self.dt_s, self.flow_corner_hz)
        gains = noise_gains(self.dt_s)
        y, p, f = (noise_std(x, self.dt_s, self.valid) for x in (self.y, self.p_load, self.force))
        self.noise = {"position_m": y, "load_pressure_pa": p, "force_n": f,
                      "velocity_m_per_s": y * gains[1], "acceleration_m_per_s2": y * gains[2],
                      "load_pressure_f_pa": p * gains[0], "load_pressure_rate_pa_per_s": p * gains[1],
                      "force_f_n": f * gains[0], "velocity_flow_m_per_s": y * flow_gains[1],
                      "load_pressure_rate_flow_pa_per_s": p * flow_gains[1]}

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


def lowpass(x: np.ndarray, dt_s: float, corner_hz: float | None = None) -> np.ndarray:
    """Zero-phase 4th-order Butterworth low-pass (forwards and backwards), at ``corner_hz`` (CORNER_HZ)."""
    corner_hz = CORNER_HZ if corner_hz is None else corner_hz
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


def noise_gains(dt_s: float, corner_hz: float | None = None) -> tuple[float, float, float]:
    """How much of a unit white noise's sigma the fits' low-pass leaves in a reading, its derivative (1/s) and
    its second derivative (1/s^2): the square root of the summed squares of their impulse responses."""
    h = lowpass(_impulse(dt_s), dt_s, corner_hz)
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


def explained(residual: np.ndarray, target: np.ndarray, residual_noise_var: float, target_noise_var: float) -> float:
    """R^2 of a balance judged against what its readings' noise leaves to explain: the share of the target's
    variance beyond its noise that the fit explains, counting the residual's expected noise as explained."""
    unexplained = max(float(np.var(residual)) - residual_noise_var, 0.0)
    return 1.0 - unexplained / max(float(np.var(target)) - target_noise_var, 1e-300)
