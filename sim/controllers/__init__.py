"""Controllers behind one interface (see base.py). ``make_controller(name)`` builds one by name."""

from __future__ import annotations

from numba import njit

from . import mrac, pid, servo
from .base import Controller
from .mrac import make_mrac, mrac_step
from .pid import make_pid, pid_step
from .servo import make_servo, servo_step

FACTORIES = {"mrac": make_mrac, "pid": make_pid, "servo": make_servo}
CONTROLLER_NAMES = tuple(FACTORIES)
DEFAULT_CONTROLLER = "servo"  # what `isorig simulate` and the dashboard use when none is chosen

# What each controller reports in the ar_hat, ay_hat, as_hat columns (label with unit); none for pid.
ADAPTED_LABELS = {
    "mrac": {"ar_hat": "a_r_hat (-), eq. (20)", "ay_hat": "a_y_hat (-), eq. (19)", "as_hat": "a_s_hat (m), eq. (18)"},
    "servo": {"ar_hat": "flow gain, true / nominal (-)", "ay_hat": "dead zone estimate (V)",
              "as_hat": "locked target frequency (Hz)"},
    "pid": {},
}


def make_controller(name: str, **options) -> Controller:
    """A controller by name with its defaults, overridden by ``options``."""
    if name not in FACTORIES:
        raise ValueError(f"unknown controller {name!r}; allowed: {', '.join(CONTROLLER_NAMES)}")
    return FACTORIES[name](**options)


@njit(cache=True)
def controller_step(kind, params, state, meas, dt, report):
    """Dispatch one control period to the controller's compiled kernel."""
    if kind == mrac.KIND:
        return mrac_step(params, state, meas, dt, report)
    if kind == pid.KIND:
        return pid_step(params, state, meas, dt, report)
    if kind == servo.KIND:
        return servo_step(params, state, meas, dt, report)
    return 0.0
