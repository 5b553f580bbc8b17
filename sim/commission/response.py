"""The rig's frequency response during the dither, as measured and as the fitted model predicts it.

The dither (sim.controllers.excitation) is a multisine whose lines are whole multiples of its lowest
frequency, so over whole periods of it the response at each line is read without leakage: the DFT of the
command and of the response over each period, at the line's bin, averaged over the periods. From the valve's
opening, the command past its dead zone (eq. 2 with the fitted null and k_en, then the fitted dead zone: the
command itself jumps across the dead zone at every reversal, which no linear response follows), to the
table's velocity (m/s per V, from the position reading) and to the load pressure (Pa per V).
The model's response is computed the same way from ``sim.commission.model.replay`` of the same commands,
so the two are compared like with like (the model's dead zone and friction included). The replay starts
afresh from the measured state every ``SEGMENT_S`` (an integrating table drifts on any model: what is judged
is the response, not where a drift of seconds leads). The velocity's normalised RMS error of that replay
over the dither is the fit's figure of quality.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..rig import RigParameters
from .flow import after_play, valve_voltage
from .force import dahl_state
from .model import replay
from .signals import Signals, derivative, lowpass

SETTLE_S = 1.0  # the first second of the dither (its fade-in) is not read
SEGMENT_S = 0.5
MIN_PERIODS = 2


@dataclass
class FrequencyResponse:
    """Measured and modelled responses at the dither's lines, and the replay's error over the dither."""

    frequency_hz: np.ndarray
    velocity_measured: np.ndarray  # complex, (m/s)/V
    velocity_model: np.ndarray
    pressure_measured: np.ndarray  # complex, Pa/V
    pressure_model: np.ndarray
    periods: int
    opening_share: float  # share of the dither's periods with the valve open past its fitted dead zone
    velocity_nrmse: float  # ||v_model - v_measured|| / ||v_measured|| over the dither (velocity from readings)
    pressure_nrmse: float

    def to_dict(self) -> dict:
        def split(h):
            return {"magnitude": np.abs(h).tolist(), "phase_deg": np.degrees(np.angle(h)).tolist()}

        return {"frequency_hz": self.frequency_hz.tolist(), "periods": self.periods,
                "input": "the valve command past the fitted dead zone (V)", "opening_share": self.opening_share,
                "velocity_per_volt": {"unit": "(m/s)/V", "measured": split(self.velocity_measured),
                                      "model": split(self.velocity_model)},
                "load_pressure_per_volt": {"unit": "Pa/V", "measured": split(self.pressure_measured),
                                           "model": split(self.pressure_model)},
                "velocity_nrmse": self.velocity_nrmse, "pressure_nrmse": self.pressure_nrmse}


def valve_opening(u: np.ndarray, rig: RigParameters) -> np.ndarray:
    """The command past the valve's dead zone, V: DZ(v_c) with v_c of eq. (2) (the valve's dynamics aside)."""
    v_c = np.where(u < 0.0, rig.driver_gain_negative * u, rig.driver_gain_positive * u) + rig.driver_offset_v
    return v_c - np.clip(v_c, -rig.dead_zone_v, rig.dead_zone_v)


def _line_response(u: np.ndarray, x: np.ndarray, n_period: int, bins: np.ndarray) -> np.ndarray:
    periods = u.size // n_period
    shape = (periods, n_period)
    cu = np.fft.rfft(u[: periods * n_period].reshape(shape), axis=1)[:, bins]
    cx = np.fft.rfft(x[: periods * n_period].reshape(shape), axis=1)[:, bins]
    return cx.mean(axis=0) / cu.mean(axis=0)


def replay_segments(sig: Signals, window: slice, rig: RigParameters, played: np.ndarray,
                    dahl: tuple[float, float, float] | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(velocity as read, load pressure) of the fitted rig's replay of the commands of ``window`` (``played``: the
    whole record's commands past the fitted valve's play, sim.commission.flow.after_play), started
    from the measured state (position and velocity moved back by the latency, load pressure, the valve as the
    fitted valve had it, the Dahl law's state from the measured motion) every ``SEGMENT_S``. ``dahl``: (F_c,
    delta, sigma_1) when the fit chose the Dahl friction law."""
    dt = sig.dt_s
    lag = rig.position_latency_s
    y0 = sig.at_latency(sig.y_f, lag)
    v0 = sig.at_latency(sig.v_f, lag)
    v_e = valve_voltage(played, dt, rig.valve_natural_frequency_rad_s / (2 * np.pi), rig.valve_damping_ratio,
                        rig.driver_offset_v, rig.driver_gain_negative)
    without_play = rig.with_changes(valve_play_v=0.0)
    v_e_rate = derivative(v_e, dt)
    z0 = dahl_state(y0, dahl[1]) if dahl is not None else np.zeros_like(y0)
    v_model = np.empty(window.stop - window.start)
    p_model = np.empty_like(v_model)
    step = int(round(SEGMENT_S / dt))
    for a in range(window.start, window.stop, step):
        b = min(a + step, window.stop)
        _y, v_model[a - window.start: b - window.start], p_model[a - window.start: b - window.start] = replay(
            without_play, played[a:b], sig.force[a:b], sig.p_supply[a:b], float(y0[a]), float(v0[a]),
            float(sig.p_load_f[a]), dt, float(v_e[a]), float(v_e_rate[a]), dahl, float(z0[a]))
    return v_model, p_model


def dither_response(sig: Signals, dither: slice, rig: RigParameters, lines_hz: np.ndarray,
                    period_s: float, dahl: tuple[float, float, float] | None = None) -> FrequencyResponse:
    """The responses over whole dither periods of ``dither`` (a slice of the record), the fitted ``rig``'s
    replay (with the Dahl friction law ``dahl`` where the fit chose it) from the state measured at its start."""
    dt = sig.dt_s
    start = dither.start + int(round(SETTLE_S / dt))
    n_period = int(round(period_s / dt))
    periods = (dither.stop - start) // n_period
    if periods < MIN_PERIODS:
        raise ValueError(f"the dither ran {periods} whole period(s) after its fade-in; at least {MIN_PERIODS} are "
                         "needed for a frequency response")
    window = slice(start, start + periods * n_period)
    played = after_play(sig.u, rig.valve_play_v)  # the play's state over the whole record, not the window's alone
    u = valve_opening(played[window], rig)
    v_model, p_model = replay_segments(sig, window, rig, played, dahl)
    diverged = not np.all(np.isfinite(v_model))
    v_model = lowpass(np.nan_to_num(v_model, posinf=0.0, neginf=0.0), dt)
    v_meas = sig.v_f[window]
    bins = np.round(lines_hz * period_s).astype(int)
    return FrequencyResponse(
        frequency_hz=np.asarray(lines_hz, dtype=float),
        velocity_measured=_line_response(u, v_meas, n_period, bins),
        velocity_model=_line_response(u, v_model, n_period, bins),
        pressure_measured=_line_response(u, sig.p_load[window], n_period, bins),
        pressure_model=_line_response(u, np.nan_to_num(p_model), n_period, bins),
        periods=periods,
        opening_share=float(np.mean(u != 0.0)),
        velocity_nrmse=math.nan if diverged else float(np.linalg.norm(v_model - v_meas)
                                                       / max(np.linalg.norm(v_meas), 1e-300)),
        pressure_nrmse=float(np.linalg.norm(np.nan_to_num(p_model) - sig.p_load[window])
                             / max(np.linalg.norm(sig.p_load[window] - np.mean(sig.p_load[window])), 1e-300)))
