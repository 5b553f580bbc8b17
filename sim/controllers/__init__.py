"""Controllers behind one interface (see base.py). ``make_controller(name)`` builds one by name."""

from __future__ import annotations

from numba import njit

from . import excitation, mrac, pid, servo
from .base import Adapted, Controller, ControllerOptionError, Option
from .excitation import excitation_step, make_excitation
from .mrac import make_mrac, mrac_step
from .pid import make_pid, pid_step
from .servo import make_servo, servo_step

FACTORIES = {"mrac": make_mrac, "pid": make_pid, "servo": make_servo}
CONTROLLER_NAMES = tuple(FACTORIES)
DEFAULT_CONTROLLER = "servo"  # what `isorig simulate` and the dashboard use when none is chosen
#: controllers the loop runs that no test may choose: the commissioning excitation (sim.commission)
INTERNAL_FACTORIES = {"excitation": make_excitation}

OPTIONS: dict[str, dict[str, Option]] = {"mrac": mrac.OPTIONS, "pid": pid.OPTIONS, "servo": servo.OPTIONS}
#: what a controller's design adds to its options in force (reported, never set)
DESIGNED: dict[str, dict[str, Option]] = {"servo": servo.DESIGNED}
#: what each controller reports in the model_m, ar_hat, ay_hat, as_hat columns: name, unit, meaning
ADAPTED: dict[str, tuple[Adapted, ...]] = {"mrac": mrac.ADAPTED, "pid": pid.ADAPTED, "servo": servo.ADAPTED}
#: column -> "name (unit)" for the adapted parameters (ar_hat, ay_hat, as_hat) of each controller
ADAPTED_LABELS = {name: {a.column: f"{a.name} ({a.unit})" for a in adapted if a.column != "model_m"}
                  for name, adapted in ADAPTED.items()}


def describe_controllers() -> list[dict]:
    """Every controller with its options (default, range, unit, meaning) and what it reports (the API)."""
    return [{"name": name, "default": name == DEFAULT_CONTROLLER,
             "options": [spec.describe(key) for key, spec in OPTIONS[name].items()],
             "adapted": [a.to_dict() for a in ADAPTED[name]]} for name in CONTROLLER_NAMES]


def make_controller(name: str, rig=None, **options) -> Controller:
    """A controller by name with its defaults, overridden by ``options``; ``rig`` (RigParameters) is the rig the
    controller may assume (its nominal values), never the isolator."""
    factory = FACTORIES.get(name) or INTERNAL_FACTORIES.get(name)
    if factory is None:
        raise ValueError(f"unknown controller {name!r}; allowed: {', '.join(CONTROLLER_NAMES)}")
    return factory(rig=rig, **options)


@njit(cache=True, error_model="numpy", inline="always")
def controller_step(kind, params, state, meas, dt, report):
    """Dispatch one control period to the controller's compiled kernel."""
    if kind == mrac.KIND:
        return mrac_step(params, state, meas, dt, report)
    if kind == pid.KIND:
        return pid_step(params, state, meas, dt, report)
    if kind == servo.KIND:
        return servo_step(params, state, meas, dt, report)
    if kind == excitation.KIND:
        return excitation_step(params, state, meas, dt, report)
    return 0.0


__all__ = ["ADAPTED", "ADAPTED_LABELS", "CONTROLLER_NAMES", "DEFAULT_CONTROLLER", "DESIGNED", "OPTIONS", "Adapted",
           "Controller", "ControllerOptionError", "Option", "controller_step", "describe_controllers",
           "make_controller"]
