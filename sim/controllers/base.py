"""The controller seam: a discrete controller stepped at the control rate.

A controller is a packed parameter vector, a state vector and a compiled step function
``step(params, state, meas, dt, report) -> u`` (volts, before saturation). ``meas`` holds what a
real rig measures plus the target; ``report`` receives what the controller shows the operator.
The Python-side ``Controller`` object describes one configured controller and can also step it
one period at a time (for a real rig driven from Python).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..errors import FieldError

# Measurement vector passed to every controller each period.
# M_HOLD_LEARNING: 1.0 where the loop was disturbed (lost measurements and their settling: sim.loop.hold_learning):
# a controller acts as usual but learns nothing from the period; else 0.0
M_TIME, M_TARGET, M_TARGET_RATE, M_POSITION, M_LOAD_PRESSURE, M_SUPPLY_PRESSURE, M_HOLD_LEARNING = range(7)
N_MEAS = 7

# Report vector filled by every controller each period (NaN where a controller has no such thing).
R_MODEL, R_AR, R_AY, R_AS = range(4)
N_REPORT = 4
REPORT_NAMES = ("model_m", "ar_hat", "ay_hat", "as_hat")


class ControllerOptionError(FieldError):
    """A controller option that is unknown, not a number, or outside its range; names option, value, range."""


@dataclass(frozen=True)
class Option:
    """One controller option: default, allowed range [lo, hi] (``None`` default: taken from elsewhere, e.g.
    the rig's nominal values), unit, kind (``float``, ``int`` or ``bool``) and what it does."""

    default: float | bool | None
    lo: float = -math.inf
    hi: float = math.inf
    unit: str = "-"
    kind: str = "float"
    meaning: str = ""

    def describe(self, name: str) -> dict:
        return {"name": name, "default": self.default, "min": self.lo, "max": self.hi, "unit": self.unit,
                "kind": self.kind, "meaning": self.meaning}


def check_options(controller: str, specs: dict[str, Option], options: dict) -> dict:
    """The controller's options: the defaults overridden by ``options``, each checked against its spec.

    Raises ``ControllerOptionError`` for an unknown name, a value that is not a (finite) number or a
    boolean where one is needed, a fraction where a whole number is needed, or a value out of range."""
    out = {name: spec.default for name, spec in specs.items()}
    for name, value in options.items():
        field = f"controller_options.{name}"
        if name not in specs:
            raise ControllerOptionError(field, value, ", ".join(sorted(specs)),
                                        f"unknown {controller} option {name!r}; allowed: {', '.join(sorted(specs))}")
        spec = specs[name]
        if value is None:
            continue
        if spec.kind == "bool":
            if not isinstance(value, bool) and value not in (0, 1):
                raise ControllerOptionError(field, value, "true or false",
                                            f"{controller} option {name} = {value!r} must be true or false")
            out[name] = bool(value)
            continue
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
            raise ControllerOptionError(field, value, f"a finite number in [{spec.lo:g}, {spec.hi:g}] {spec.unit}",
                                        f"{controller} option {name} = {value!r} must be a finite number "
                                        f"(unit {spec.unit})")
        if spec.kind == "int" and float(value) != int(value):
            raise ControllerOptionError(field, value, "a whole number",
                                        f"{controller} option {name} = {value!r} must be a whole number")
        if not (spec.lo <= value <= spec.hi):
            raise ControllerOptionError(field, value, f"[{spec.lo:g}, {spec.hi:g}] {spec.unit}",
                                        f"{controller} option {name} = {value:g} {spec.unit} is outside the allowed "
                                        f"range [{spec.lo:g}, {spec.hi:g}] {spec.unit}")
        out[name] = int(value) if spec.kind == "int" else float(value)
    return out


@dataclass(frozen=True)
class Adapted:
    """What a controller reports in one of the columns model_m, ar_hat, ay_hat, as_hat: name, unit, meaning."""

    column: str
    name: str
    unit: str
    meaning: str

    def to_dict(self) -> dict:
        return {"column": self.column, "name": self.name, "unit": self.unit, "meaning": self.meaning}


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
