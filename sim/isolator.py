"""Isolator under test: the Bouc-Wen restoring force of the paper, eq. (4).

    F_BW = k_d d + k_w w
    dw/dt = rho_BW d' { 1 + |w|^n sigma_BW [ 1 - sgn(d' w) - 1/sigma_BW ] }

Presets IUT_a and IUT_b are the paper's Tables I and II. User isolators come from JSON
objects with the keys ``name, rho_bw_per_m, sigma_bw, n, kd_n_per_m, kw_n`` and, optionally,
``design_vertical_load_n`` (the load its tests run under unless a test says otherwise) and ``description``.
"""

from __future__ import annotations

import json
import math
import re
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
from numba import njit

FIELDS = ("name", "rho_bw_per_m", "sigma_bw", "n", "kd_n_per_m", "kw_n")

# Allowed ranges for user isolators: wide enough for any real device, narrow enough to catch
# unit mistakes (e.g. kd in kN/m) and values that make eq. (4) meaningless.
LIMITS = {
    "rho_bw_per_m": (1.0, 1.0e5, "1/m"),
    "sigma_bw": (0.01, 100.0, "-"),
    "n": (0.2, 10.0, "-"),
    "kd_n_per_m": (0.0, 1.0e9, "N/m"),
    "kw_n": (0.0, 1.0e7, "N"),
}
DESIGN_LOAD_LIMIT_N = (0.0, 1.0e8)  # checked against the rig's jack when a test is made
NAME_PATTERN = re.compile(r"^[A-Za-z0-9_.\- ]{1,64}$")


class IsolatorError(ValueError):
    """An isolator definition is missing a field or has a value outside its allowed range."""


@dataclass(frozen=True)
class Isolator:
    """Bouc-Wen parameters of eq. (4), SI units."""

    name: str
    rho_bw_per_m: float
    sigma_bw: float
    n: float
    kd_n_per_m: float
    kw_n: float
    description: str = ""
    design_vertical_load_n: float | None = None  # the default vertical load of its tests (None: the rig's)

    def to_dict(self) -> dict:
        return asdict(self)

    def force_n(self, d_m, w):
        """Restoring force F_BW = k_d d + k_w w, eq. (4)."""
        return self.kd_n_per_m * d_m + self.kw_n * w

    def peak_force_n(self, amplitude_m: float) -> float:
        """Upper bound of |F_BW| on a cycle of amplitude ``amplitude_m``.

        On the loading branch (d' w > 0) eq. (4) reads dw/dt = rho d' (1 - |w|^n), so |w| <= 1.
        """
        return self.kd_n_per_m * abs(amplitude_m) + self.kw_n


PRESETS: dict[str, Isolator] = {
    "IUT_a": Isolator("IUT_a", 141.0, 0.5, 1.0, 1.25e6, 1.7e4, "paper Table I"),
    "IUT_b": Isolator("IUT_b", 90.0, 0.5, 1.0, 6.8e5, 6.2e3, "paper Table II"),
    # Two example isolators of clearly different character (assumed, for grids and demos).
    # Lead-rubber: characteristic strength Q_d ~ 40 kN, post-yield stiffness 0.7 kN/mm, yield displacement
    # 1/rho ~ 6.7 mm (elastic stiffness ~ 11x the post-yield stiffness, typical of lead-rubber bearings).
    "LRB_example": Isolator(
        "LRB_example", 150.0, 0.5, 1.0, 7.0e5, 4.0e4, "lead-rubber-like: large hysteretic force"
    ),
    "HDRB_soft": Isolator(
        "HDRB_soft", 60.0, 0.5, 2.0, 3.0e5, 8.0e3, "soft high-damping rubber, smooth (n = 2)"
    ),
}


def isolator_from_dict(data: dict) -> Isolator:
    """Validate a user isolator given as a dict; raise IsolatorError naming the bad field."""
    if not isinstance(data, dict):
        raise IsolatorError("isolator definition must be a JSON object with keys " + ", ".join(FIELDS))
    missing = [k for k in FIELDS if k not in data]
    if missing:
        raise IsolatorError(f"isolator is missing field(s) {', '.join(missing)}; required: {', '.join(FIELDS)}")
    name = data["name"]
    if not isinstance(name, str) or not NAME_PATTERN.match(name):
        raise IsolatorError(
            f"field 'name' = {name!r} is invalid: use 1-64 letters, digits, spaces, '_', '-' or '.'"
        )
    values = {}
    for key, (lo, hi, unit) in LIMITS.items():
        raw = data[key]
        if isinstance(raw, bool) or not isinstance(raw, (int, float)):
            raise IsolatorError(f"field '{key}' = {raw!r} is not a number (unit {unit})")
        value = float(raw)
        if not math.isfinite(value) or not (lo <= value <= hi):
            raise IsolatorError(f"field '{key}' = {raw!r} is outside the allowed range [{lo:g}, {hi:g}] {unit}")
        values[key] = value
    description = data.get("description", "")
    if not isinstance(description, str):
        raise IsolatorError("field 'description' must be a string")
    load = data.get("design_vertical_load_n")
    if load is not None:
        lo, hi = DESIGN_LOAD_LIMIT_N
        if isinstance(load, bool) or not isinstance(load, (int, float)) or not math.isfinite(load) \
                or not (lo <= load <= hi):
            raise IsolatorError(f"field 'design_vertical_load_n' = {load!r} must be a number of newtons in "
                                f"[{lo:g}, {hi:g}] N (or absent)")
        load = float(load)
    return Isolator(name=name, description=description[:200], design_vertical_load_n=load, **values)
#: no specimen mounted (commissioning a bare rig): no restoring force, a valid isolator all the same
NO_SPECIMEN = Isolator("none", 1.0, 0.5, 1.0, 0.0, 0.0, "no specimen mounted", 0.0)


def load_isolator(spec: str | Path) -> Isolator:
    """A preset by name (``IUT_a``), ``none`` (no specimen) or a user isolator from a JSON file path."""
    key = str(spec)
    if key in PRESETS:
        return PRESETS[key]
    if key == NO_SPECIMEN.name:
        return NO_SPECIMEN
    path = Path(key)
    if not path.suffix == ".json" and not path.exists():
        raise IsolatorError(f"unknown isolator {key!r}: use one of {', '.join(PRESETS)} or a path to a .json file")
    try:
        text = path.read_text()
    except OSError as exc:
        raise IsolatorError(f"cannot read isolator file {key}: {exc.strerror}") from None
    try:
        data = json.loads(text)
    except json.JSONDecodeError as exc:
        raise IsolatorError(f"isolator file {key} is not valid JSON: {exc.msg} at line {exc.lineno}") from None
    return isolator_from_dict(data)


@njit(cache=True, error_model="numpy")
def bouc_wen_rate(w, d_dot, rho, sigma, n):
    """dw/dt of eq. (4), written exactly as the paper does (|w|^n without a power call for n = 1, the
    exponent of Tables I-II: the same value, a fifth of the engine's time saved)."""
    prod = d_dot * w
    sgn = 1.0 if prod > 0.0 else (-1.0 if prod < 0.0 else 0.0)
    wn = abs(w) if n == 1.0 else abs(w) ** n
    return rho * d_dot * (1.0 + wn * sigma * (1.0 - sgn - 1.0 / sigma))


def simulate_loop(isolator: Isolator, d_m: np.ndarray, dt_s: float, substeps: int = 10) -> np.ndarray:
    """Force history of eq. (4) for a prescribed displacement history (RK4 on linear interpolation)."""
    return _loop_forces(
        np.ascontiguousarray(d_m, dtype=np.float64), dt_s, substeps,
        isolator.rho_bw_per_m, isolator.sigma_bw, isolator.n, isolator.kd_n_per_m, isolator.kw_n,
    )


@njit(cache=True, error_model="numpy")
def bouc_wen_step(w, d0, d1, dt, substeps, rho, sigma, nexp):
    """w after the displacement moves linearly from d0 to d1 (m) in dt (s): RK4, ``substeps`` substeps.
    The isolator force at d1 is then k_d d1 + k_w w (eq. 4)."""
    d_dot = (d1 - d0) / dt
    h = dt / substeps
    for _ in range(substeps):
        k1 = bouc_wen_rate(w, d_dot, rho, sigma, nexp)
        k2 = bouc_wen_rate(w + 0.5 * h * k1, d_dot, rho, sigma, nexp)
        k3 = bouc_wen_rate(w + 0.5 * h * k2, d_dot, rho, sigma, nexp)
        k4 = bouc_wen_rate(w + h * k3, d_dot, rho, sigma, nexp)
        w += h * (k1 + 2.0 * k2 + 2.0 * k3 + k4) / 6.0
    return w


@njit(cache=True, error_model="numpy")
def _loop_forces(d, dt, substeps, rho, sigma, n, kd, kw):
    out = np.empty(d.size)
    w = 0.0
    out[0] = kd * d[0]
    for i in range(d.size - 1):
        w = bouc_wen_step(w, d[i], d[i + 1], dt, substeps, rho, sigma, n)
        out[i + 1] = kd * d[i + 1] + kw * w
    return out
