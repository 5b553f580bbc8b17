"""The controller seam: a discrete controller stepped at the control rate.

A controller is a packed parameter vector, a state vector and a compiled step function
``step(params, state, meas, dt, report) -> u`` (volts, before saturation). ``meas`` holds what a
real rig measures plus the target; ``report`` receives what the controller shows the operator.
The Python-side ``Controller`` object describes one configured controller and can also step it
one period at a time (for a real rig driven from Python).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

# Measurement vector passed to every controller each period.
M_TIME, M_TARGET, M_TARGET_RATE, M_POSITION, M_LOAD_PRESSURE, M_SUPPLY_PRESSURE = range(6)
N_MEAS = 6

# Report vector filled by every controller each period (NaN where a controller has no such thing).
R_MODEL, R_AR, R_AY, R_AS = range(4)
N_REPORT = 4
REPORT_NAMES = ("model_m", "ar_hat", "ay_hat", "as_hat")


@dataclass
class Controller:
    """One configured controller: which kernel, its parameters and its initial state."""

    name: str
    kind: int
    params: np.ndarray
    initial_state: np.ndarray
    options: dict

    def new_state(self) -> np.ndarray:
        return self.initial_state.copy()

    def step(self, state: np.ndarray, meas: np.ndarray, dt_s: float) -> tuple[float, np.ndarray]:
        """Advance one control period; returns (u before saturation, report)."""
        from . import controller_step

        report = np.full(N_REPORT, np.nan)
        u = controller_step(self.kind, self.params, state, meas, dt_s, report)
        return u, report
