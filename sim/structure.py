"""The numerical substructure of real-time hybrid simulation (RTHS): a shear building on the isolator.

Model (degrees of freedom u = [u_b, u_1, ..., u_n], displacements relative to the ground, m):

    M u'' + C u' + K_s u + e_b F_iso = -M 1 a_g                                                   (S1)

- ``M = diag(m_b, m_1, ..., m_n)``: the base mass (the slab above the isolator) and the storey masses;
- ``K_s``: the storey springs, k_1 between the base and storey 1, k_j between storeys j-1 and j;
- ``C = alpha diag(0, m_1..m_n) + beta K_s``: Rayleigh damping of the superstructure, fitted to
  ``damping_ratio`` at the first two fixed-base modes (base held); mass-proportional on the storey masses,
  stiffness-proportional on the storey springs (k_1 included). Nothing is added at the base: the isolator
  brings its own damping, its hysteresis;
- ``F_iso``: the isolator's restoring force on the base, positive when it resists a positive u_b; in
  RTHS it is **measured** on the rig, in the reference it is the Bouc-Wen model of eq. (4):
  F_iso = k_d u_b + k_w w;
- ``e_b = [1, 0, ..., 0]``, ``a_g``: the ground acceleration (m/s2).

Real-time integration: the CR algorithm (Chen, C. & Ricles, J. M., 2008, "Development of direct
integration algorithms for structural dynamics using discrete control theory", J. Eng. Mech. 134(8),
676-683):

    u_{i+1} = u_i + dt u'_i + dt^2 alpha_2 u''_i                                                 (CR1)
    u'_{i+1} = u'_i + dt alpha_1 u''_i                                                            (CR2)
    M u''_{i+1} = -M 1 a_g,{i+1} - C u'_{i+1} - K_s u_{i+1} - e_b F_iso,{i+1}                     (CR3)
    alpha_1 = alpha_2 = 4 (4 M + 2 dt C + dt^2 K_0)^-1 M

Displacement and velocity are explicit (CR1, CR2): the base displacement of the next step is known before
the specimen is moved, which is what RTHS needs. For linear systems with K_0 the true stiffness the scheme
is unconditionally stable and has the trapezoidal rule's accuracy (second order, no numerical damping); for
nonlinear softening systems it stays unconditionally stable when K_0 is the largest tangent stiffness
(Chen & Ricles 2008, "Stability analysis of direct integration algorithms applied to nonlinear structural
dynamics", J. Eng. Mech. 134(9), 703-711). K_0 = K_s + e_b e_b^T k_0
with k_0 the isolator's largest tangent stiffness (``isolator_tangent_stiffness_n_per_m``).

Offline reference: (S1) with the Bouc-Wen isolator as a first-order system in [u, u', w], integrated by the
classical fourth-order Runge-Kutta method with the ground acceleration linear between samples and a substep
no longer than 0.1 ms nor 0.05 / omega_max (``simulate_isolated_system``); the error is measured against
halving the substep in tests/test_structure.py.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numba import njit

from .errors import FieldError
from .isolator import Isolator, bouc_wen_rate, bouc_wen_step

G_M_PER_S2 = 9.80665
MAX_STOREYS = 50
MASS_LIMIT_KG = (0.0, 1.0e8)  # exclusive lower bound
STIFFNESS_LIMIT_N_PER_M = (0.0, 1.0e12)  # exclusive lower bound
FIELDS = ("base_mass_kg", "masses_kg", "stiffness_n_per_m", "damping_ratio")
OPTIONAL_FIELDS = ("name", "description")
REFERENCE_MAX_SUBSTEP_S = 1.0e-4


class StructureError(FieldError):
    """A structure file is missing a field or has a value outside its allowed range; ``field`` names it."""


def _positive(field: str, value, limits: tuple[float, float], unit: str) -> float:
    lo, hi = limits
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise StructureError(field, value, f"a finite number in ({lo:g}, {hi:g}] {unit}",
                             f"{field} = {value!r} is not a finite number (unit {unit})")
    if not (lo < value <= hi):
        raise StructureError(field, value, f"({lo:g}, {hi:g}] {unit}",
                             f"{field} = {value!r} {unit} must be positive and at most {hi:g} {unit}")
    return float(value)


@dataclass(frozen=True)
class ShearBuilding:
    """A shear building above the isolation level (SI units); see the module docstring for the model."""

    base_mass_kg: float
    masses_kg: tuple[float, ...]
    stiffness_n_per_m: tuple[float, ...]
    damping_ratio: float
    name: str = ""
    description: str = ""

    # ---- construction -------------------------------------------------------------------------------------
    @classmethod
    def from_dict(cls, data: dict) -> ShearBuilding:
        """Validate ``{"base_mass_kg", "masses_kg": [...], "stiffness_n_per_m": [...], "damping_ratio"}``
        (optional ``name``, ``description``); raise StructureError naming the field."""
        if not isinstance(data, dict):
            raise StructureError("structure", type(data).__name__, "a JSON object",
                                 "the structure must be a JSON object with the keys " + ", ".join(FIELDS))
        missing = [k for k in FIELDS if k not in data]
        if missing:
            raise StructureError(missing[0], None, "required",
                                 f"the structure is missing field(s) {', '.join(missing)}; "
                                 f"required: {', '.join(FIELDS)}")
        unknown = [k for k in data if k not in FIELDS + OPTIONAL_FIELDS]
        if unknown:
            raise StructureError(unknown[0], data[unknown[0]], "one of " + ", ".join(FIELDS + OPTIONAL_FIELDS),
                                 f"unknown field(s) {', '.join(map(repr, unknown))} in the structure; allowed: "
                                 f"{', '.join(FIELDS + OPTIONAL_FIELDS)}")
        base = _positive("base_mass_kg", data["base_mass_kg"], MASS_LIMIT_KG, "kg")
        lists = {}
        for key, limits, unit in (("masses_kg", MASS_LIMIT_KG, "kg"),
                                  ("stiffness_n_per_m", STIFFNESS_LIMIT_N_PER_M, "N/m")):
            raw = data[key]
            if not isinstance(raw, (list, tuple)) or not raw:
                raise StructureError(key, raw, f"a list of 1 to {MAX_STOREYS} numbers ({unit})",
                                     f"{key} must be a non-empty list of numbers in {unit}, one per storey "
                                     f"(got {raw!r})")
            if len(raw) > MAX_STOREYS:
                raise StructureError(key, len(raw), f"at most {MAX_STOREYS} storeys",
                                     f"{key} has {len(raw)} entries; at most {MAX_STOREYS} storeys are allowed")
            lists[key] = tuple(_positive(f"{key}[{i}]", v, limits, unit) for i, v in enumerate(raw))
        if len(lists["masses_kg"]) != len(lists["stiffness_n_per_m"]):
            raise StructureError("stiffness_n_per_m", len(lists["stiffness_n_per_m"]),
                                 f"{len(lists['masses_kg'])} entries, one per storey like masses_kg",
                                 f"stiffness_n_per_m has {len(lists['stiffness_n_per_m'])} entries but masses_kg "
                                 f"has {len(lists['masses_kg'])}: give one spring per storey (stiffness_n_per_m[0] "
                                 f"is the first storey's spring to the base)")
        zeta = data["damping_ratio"]
        if isinstance(zeta, bool) or not isinstance(zeta, (int, float)) or not math.isfinite(zeta) \
                or not (0.0 < zeta < 1.0):
            raise StructureError("damping_ratio", zeta, "(0, 1)",
                                 f"damping_ratio = {zeta!r} must be a number strictly between 0 and 1 "
                                 f"(a fraction of critical: 0.05 is 5 %)")
        name = data.get("name", "")
        description = data.get("description", "")
        for key, text in (("name", name), ("description", description)):
            if not isinstance(text, str):
                raise StructureError(key, text, "a string", f"{key} must be a string")
        return cls(base, lists["masses_kg"], lists["stiffness_n_per_m"], float(zeta), name[:64], description[:200])

    def to_dict(self) -> dict:
        return {"name": self.name, "description": self.description, "base_mass_kg": self.base_mass_kg,
                "masses_kg": list(self.masses_kg), "stiffness_n_per_m": list(self.stiffness_n_per_m),
                "damping_ratio": self.damping_ratio}

    # ---- matrices -----------------------------------------------------------------------------------------
    @property
    def n_storeys(self) -> int:
        return len(self.masses_kg)

    @property
    def n_dofs(self) -> int:
        """Base plus storeys."""
        return len(self.masses_kg) + 1

    @property
    def total_mass_kg(self) -> float:
        return self.base_mass_kg + sum(self.masses_kg)

    def mass_vector_kg(self) -> np.ndarray:
        """diag(M) = [m_b, m_1, ..., m_n]."""
        return np.array((self.base_mass_kg,) + self.masses_kg, dtype=np.float64)

    def stiffness_matrix(self) -> np.ndarray:
        """K_s on [u_b, u_1..u_n] (N/m): the storey springs only, the isolator excluded."""
        n = self.n_dofs
        k = np.zeros((n, n))
        for j, kj in enumerate(self.stiffness_n_per_m, start=1):  # spring between dof j-1 and dof j
            k[j - 1, j - 1] += kj
            k[j, j] += kj
            k[j - 1, j] -= kj
            k[j, j - 1] -= kj
        return k

    def fixed_base_modes(self) -> tuple[np.ndarray, np.ndarray]:
        """Circular frequencies (rad/s, ascending) and mass-normalised shapes (columns) with the base held."""
        from scipy.linalg import eigh

        kf = self.stiffness_matrix()[1:, 1:]
        mf = np.diag(self.mass_vector_kg()[1:])
        lam, phi = eigh(kf, mf)
        return np.sqrt(lam), phi

    def fixed_base_periods_s(self) -> np.ndarray:
        return 2.0 * np.pi / self.fixed_base_modes()[0]

    def rayleigh_coefficients(self) -> tuple[float, float]:
        """(alpha in 1/s, beta in s) of C = alpha M_storeys + beta K_s.

        zeta(omega) = alpha / (2 omega) + beta omega / 2 equals ``damping_ratio`` at the first two fixed-base
        modes: alpha = 2 zeta w1 w2 / (w1 + w2), beta = 2 zeta / (w1 + w2). With one storey (one mode) the
        damping is stiffness-proportional only, beta = 2 zeta / w1, so the isolated rigid-body motion is not
        damped by the superstructure's viscous model.
        """
        w = self.fixed_base_modes()[0]
        z = self.damping_ratio
        if w.size == 1:
            return 0.0, 2.0 * z / w[0]
        w1, w2 = w[0], w[1]
        return 2.0 * z * w1 * w2 / (w1 + w2), 2.0 * z / (w1 + w2)

    def damping_matrix(self) -> np.ndarray:
        """C on [u_b, u_1..u_n] (N s/m): Rayleigh on the superstructure, zero extra at the base."""
        alpha, beta = self.rayleigh_coefficients()
        m_storeys = self.mass_vector_kg()
        m_storeys[0] = 0.0
        return alpha * np.diag(m_storeys) + beta * self.stiffness_matrix()

    def modal_damping_ratios(self) -> np.ndarray:
        """The damping ratio each fixed-base mode gets from ``damping_matrix`` (checks the fit)."""
        w, phi = self.fixed_base_modes()
        cf = self.damping_matrix()[1:, 1:]
        return np.array([phi[:, i] @ cf @ phi[:, i] / (2.0 * w[i]) for i in range(w.size)])


def load_structure(path: str | Path) -> ShearBuilding:
    """A ShearBuilding from a JSON file; StructureError (a ValueError) naming the file or the field."""
    key = str(path)
    try:
        text = Path(key).read_text()
    except OSError as exc:
        raise StructureError("structure", key, "a readable JSON file",
                             f"cannot read structure file {key}: {exc.strerror}") from None
    try:
        data = json.loads(text)
    except json.JSONDecodeError as exc:
        raise StructureError("structure", key, "valid JSON",
                             f"structure file {key} is not valid JSON: {exc.msg} at line {exc.lineno}") from None
    try:
        return ShearBuilding.from_dict(data)
    except StructureError as exc:
        raise StructureError(exc.field, exc.value, exc.limit, f"structure file {key}: {exc}") from None


def isolator_tangent_stiffness_n_per_m(isolator: Isolator) -> float:
    """The largest tangent stiffness dF/dd of eq. (4): k_d + k_w rho max(1, 2 sigma) (with |w| <= 1:
    1 on first loading, 1 + |w|^n (2 sigma - 1) on unloading). The K_0 of the CR algorithm."""
    return isolator.kd_n_per_m + isolator.kw_n * isolator.rho_bw_per_m * max(1.0, 2.0 * isolator.sigma_bw)


def channel_names(building: ShearBuilding) -> list[str]:
    """Names of the structure's response channels, in the order of ``CRIntegrator.write_channels``:
    base displacement (relative to the ground), storey drifts u_j - u_{j-1} (u_0 = u_b), absolute
    accelerations u''_j + a_g of the base and of each storey, and the isolator force."""
    n = building.n_storeys
    return (["base_displacement_m"] + [f"drift_{j}_m" for j in range(1, n + 1)]
            + ["abs_acc_base_m_per_s2"] + [f"abs_acc_{j}_m_per_s2" for j in range(1, n + 1)]
            + ["isolator_force_n"])


# ---- CR algorithm: compiled predictor and corrector (callable from compiled loops) -------------------------
@njit(cache=True)
def cr_predict(x, v, a, xp, vp, dt, a1dt, a2dt2):
    """(CR1, CR2): xp = x + dt v + a2dt2 a, vp = v + a1dt a (a1dt = dt alpha_1, a2dt2 = dt^2 alpha_2).
    Returns the base displacement xp[0] (m), the next command to the rig."""
    n = x.size
    for i in range(n):
        s1 = 0.0
        s2 = 0.0
        for j in range(n):
            s1 += a1dt[i, j] * a[j]
            s2 += a2dt2[i, j] * a[j]
        vp[i] = v[i] + s1
        xp[i] = x[i] + dt * v[i] + s2
    return xp[0]


@njit(cache=True)
def cr_correct(x, v, a, xp, vp, mass, damping, stiffness, f_iso, ag):
    """(CR3) at the predicted state with the measured isolator force ``f_iso`` (N) and the ground
    acceleration ``ag`` (m/s2) of the new step; commits x, v, a. Returns the momentum sum m_i u'_i (kg m/s)."""
    n = x.size
    p = 0.0
    for i in range(n):
        s = -mass[i] * ag
        for j in range(n):
            s -= damping[i, j] * vp[j] + stiffness[i, j] * xp[j]
        if i == 0:
            s -= f_iso
        a[i] = s / mass[i]
    for i in range(n):
        x[i] = xp[i]
        v[i] = vp[i]
        p += mass[i] * v[i]
    return p


class CRIntegrator:
    """The numerical substructure for RTHS, one control period at a time (CR algorithm, module docstring).

    Use, every period k (time t_k = k dt):

        command_m = step.next_base_displacement()   # u_b(t_{k+1}) relative to the ground: the rig's target
        ... the rig moves the isolator to it; measure the isolator force F_iso (N) ...
        step.advance(F_iso, a_g(t_{k+1}))           # closes the step with the MEASURED force

    ``isolator`` (an Isolator, or a stiffness in N/m) gives K_0's isolator term, the largest tangent
    stiffness (``isolator_tangent_stiffness_n_per_m``): unconditional stability for the softening Bouc-Wen
    specimen. ``ground_acc0_m_per_s2``: a_g at t = 0 (the state starts at rest). Each call does one compiled
    O(n_dofs^2) pass on preallocated arrays (no allocation). ``input_energy_j`` is the relative input energy
    -integral a_g sum(m_i u'_i) dt (Uang & Bertero 1990), for the stability monitor's threshold.
    """

    def __init__(self, building: ShearBuilding, dt_s: float, isolator: Isolator | float,
                 ground_acc0_m_per_s2: float = 0.0):
        if not (isinstance(dt_s, (int, float)) and math.isfinite(dt_s) and 0.0 < dt_s <= 0.1):
            raise StructureError("dt_s", dt_s, "(0, 0.1] s", f"dt_s = {dt_s!r} must be in (0, 0.1] s")
        self.building = building
        self.dt_s = float(dt_s)
        k0 = isolator_tangent_stiffness_n_per_m(isolator) if isinstance(isolator, Isolator) else float(isolator)
        if not (math.isfinite(k0) and k0 >= 0.0):
            raise StructureError("isolator", k0, ">= 0 N/m", f"isolator stiffness {k0!r} N/m must be >= 0")
        self.isolator_stiffness_n_per_m = k0
        self.mass = np.ascontiguousarray(building.mass_vector_kg())
        self.stiffness = np.ascontiguousarray(building.stiffness_matrix())
        self.damping = np.ascontiguousarray(building.damping_matrix())
        k_0 = self.stiffness.copy()
        k_0[0, 0] += k0
        dt = self.dt_s
        m = np.diag(self.mass)
        alpha = 4.0 * np.linalg.solve(4.0 * m + 2.0 * dt * self.damping + dt * dt * k_0, m)
        self.a1dt = np.ascontiguousarray(dt * alpha)
        self.a2dt2 = np.ascontiguousarray(dt * dt * alpha)
        n = building.n_dofs
        self.x = np.zeros(n)
        self.v = np.zeros(n)
        self.a = np.zeros(n)
        self.xp = np.zeros(n)
        self.vp = np.zeros(n)
        self.reset(ground_acc0_m_per_s2)

    def reset(self, ground_acc0_m_per_s2: float = 0.0) -> None:
        """Back to rest at t = 0."""
        self.x[:] = 0.0
        self.v[:] = 0.0
        self.a[:] = -ground_acc0_m_per_s2  # M a = -M 1 a_g at rest with no force
        self.step_index = 0
        self.isolator_force_n = 0.0
        self.ground_acc_m_per_s2 = float(ground_acc0_m_per_s2)
        self.input_energy_j = 0.0
        self._momentum = 0.0
        self._predicted = False

    def set_state(self, displacement_m, velocity_m_per_s, ground_acc_m_per_s2: float, isolator_force_n: float,
                  step_index: int = 0) -> None:
        """Start from a given state (u and u' of every dof relative to the ground, m and m/s; a_g and the
        isolator force at that instant): u'' follows from (S1). For resuming a test or starting on a known
        solution; ``input_energy_j`` restarts from 0."""
        u = np.asarray(displacement_m, dtype=np.float64)
        v = np.asarray(velocity_m_per_s, dtype=np.float64)
        if u.shape != self.x.shape or v.shape != self.x.shape or not (np.all(np.isfinite(u))
                                                                        and np.all(np.isfinite(v))):
            raise ValueError(f"displacement_m and velocity_m_per_s must be {self.x.size} finite numbers")
        self.reset(ground_acc_m_per_s2)
        self.xp[:] = u
        self.vp[:] = v
        self._momentum = cr_correct(self.x, self.v, self.a, self.xp, self.vp, self.mass, self.damping,
                                    self.stiffness, isolator_force_n, ground_acc_m_per_s2)
        self.isolator_force_n = float(isolator_force_n)
        self.step_index = int(step_index)

    @property
    def time_s(self) -> float:
        """Time of the committed state (s)."""
        return self.step_index * self.dt_s

    def next_base_displacement(self) -> float:
        """u_b at t_{k+1} (m, relative to the ground): explicit from the committed state. Calling it again
        before ``advance`` returns the same value."""
        if not self._predicted:
            cr_predict(self.x, self.v, self.a, self.xp, self.vp, self.dt_s, self.a1dt, self.a2dt2)
            self._predicted = True
        return self.xp[0]

    def advance(self, isolator_force_n: float, ground_acc_m_per_s2: float) -> None:
        """Close step k -> k+1 with the isolator force measured at the commanded displacement (N, positive
        when it resists a positive u_b, as F = k_d d + k_w w of eq. 4) and a_g(t_{k+1}) (m/s2)."""
        if not self._predicted:
            cr_predict(self.x, self.v, self.a, self.xp, self.vp, self.dt_s, self.a1dt, self.a2dt2)
        p = cr_correct(self.x, self.v, self.a, self.xp, self.vp, self.mass, self.damping, self.stiffness,
                       isolator_force_n, ground_acc_m_per_s2)
        self.input_energy_j -= 0.5 * self.dt_s * (self.ground_acc_m_per_s2 * self._momentum + ground_acc_m_per_s2 * p)
        self._momentum = p
        self.ground_acc_m_per_s2 = ground_acc_m_per_s2
        self.isolator_force_n = isolator_force_n
        self.step_index += 1
        self._predicted = False

    @property
    def base_displacement_m(self) -> float:
        return self.x[0]

    def write_channels(self, out: np.ndarray) -> None:
        """Fill ``out`` (length len(channel_names(building))) with the committed state's channels."""
        n = self.x.size
        out[0] = self.x[0]
        for j in range(1, n):
            out[j] = self.x[j] - self.x[j - 1]
        for j in range(n):
            out[n + j] = self.a[j] + self.ground_acc_m_per_s2
        out[2 * n] = self.isolator_force_n


# ---- offline reference ----------------------------------------------------------------------------------
@njit(cache=True)
def _system_rates(y, ag, n, mass, damping, stiffness, bw, dy):
    """d/dt of y = [u (n), u' (n), w] for (S1) with eq. (4); bw = [rho, sigma, n_exp, k_d, k_w]."""
    f_iso = bw[3] * y[0] + bw[4] * y[2 * n]
    for i in range(n):
        s = -mass[i] * ag
        for j in range(n):
            s -= damping[i, j] * y[n + j] + stiffness[i, j] * y[j]
        if i == 0:
            s -= f_iso
        dy[n + i] = s / mass[i]
        dy[i] = y[n + i]
    dy[2 * n] = bouc_wen_rate(y[2 * n], y[n], bw[0], bw[1], bw[2])


@njit(cache=True)
def _rk4_isolated(ag, substeps, h, mass, damping, stiffness, bw, out):
    """RK4 from rest; out[k] = [u, u', u''_rel, w] at sample k (a_g linear between samples)."""
    n = mass.size
    m = 2 * n + 1
    y = np.zeros(m)
    yt = np.zeros(m)
    k = np.zeros((4, m))
    stage_c = (0.0, 0.5, 0.5, 1.0)
    for i in range(ag.size):
        _system_rates(y, ag[i], n, mass, damping, stiffness, bw, yt)
        for j in range(2 * n):
            out[i, j] = y[j]
        for j in range(n):
            out[i, 2 * n + j] = yt[n + j]
        out[i, 3 * n] = y[2 * n]
        if i == ag.size - 1:
            break
        slope = ag[i + 1] - ag[i]
        for s in range(substeps):
            for st in range(4):
                c = stage_c[st]
                if st == 0:
                    for j in range(m):
                        yt[j] = y[j]
                else:
                    for j in range(m):
                        yt[j] = y[j] + c * h * k[st - 1, j]
                _system_rates(yt, ag[i] + slope * (s + c) / substeps, n, mass, damping, stiffness, bw, k[st])
            for j in range(m):
                y[j] += h * (k[0, j] + 2.0 * k[1, j] + 2.0 * k[2, j] + k[3, j]) / 6.0


def _uniform_step(time_s: np.ndarray, ground_acc: np.ndarray) -> float:
    if time_s.ndim != 1 or time_s.shape != ground_acc.shape or time_s.size < 2:
        raise ValueError("time_s and the ground acceleration must be 1-D arrays of the same length (>= 2)")
    if not (np.all(np.isfinite(time_s)) and np.all(np.isfinite(ground_acc))):
        raise ValueError("time_s and the ground acceleration must be finite")
    steps = np.diff(time_s)
    dt = float(steps.mean())
    if dt <= 0.0 or np.max(np.abs(steps - dt)) > 1e-6 * dt + 1e-12:
        raise ValueError("time_s must be uniformly spaced and increasing (resample the record first)")
    return dt


def simulate_isolated_system(mass_kg: np.ndarray, damping: np.ndarray, stiffness: np.ndarray, isolator: Isolator,
                             time_s, ground_acc_m_per_s2, substeps: int | None = None) -> dict:
    """Integrate (S1) with the Bouc-Wen isolator of eq. (4) on dof 0, from rest, under a_g(t).

    ``mass_kg`` diag(M) (n,), ``damping`` C and ``stiffness`` K_s (n, n), both without the isolator;
    ``time_s`` uniform. Classical RK4 on [u, u', w], a_g linear between samples, ``substeps`` per sample
    (default: the substep is at most 0.1 ms and 0.05 / omega_max, omega_max the highest circular frequency
    with the isolator's largest tangent stiffness). Returns ``u_m``, ``v_m_per_s``, ``a_rel_m_per_s2``
    (n_samples, n), ``w`` (n_samples,) and ``isolator_force_n`` = k_d u_b + k_w w.
    """
    t = np.ascontiguousarray(time_s, dtype=np.float64)
    ag = np.ascontiguousarray(ground_acc_m_per_s2, dtype=np.float64)
    dt = _uniform_step(t, ag)
    mass = np.ascontiguousarray(mass_kg, dtype=np.float64)
    damping = np.ascontiguousarray(damping, dtype=np.float64)
    stiffness = np.ascontiguousarray(stiffness, dtype=np.float64)
    if substeps is None:
        k0 = stiffness.copy()
        k0[0, 0] += isolator_tangent_stiffness_n_per_m(isolator)
        w_max = math.sqrt(max(np.max(np.linalg.eigvals(k0 / mass[:, None]).real), 0.0))
        h_max = min(REFERENCE_MAX_SUBSTEP_S, 0.05 / w_max if w_max > 0 else REFERENCE_MAX_SUBSTEP_S)
        substeps = max(1, math.ceil(dt / h_max - 1e-9))
    n = mass.size
    out = np.empty((ag.size, 3 * n + 1))
    bw = np.array([isolator.rho_bw_per_m, isolator.sigma_bw, isolator.n, isolator.kd_n_per_m, isolator.kw_n])
    _rk4_isolated(ag, int(substeps), dt / int(substeps), mass, damping, stiffness, bw, out)
    xs, vs, acc, ws = out[:, :n], out[:, n:2 * n], out[:, 2 * n:3 * n], out[:, 3 * n].copy()
    return {"u_m": xs, "v_m_per_s": vs, "a_rel_m_per_s2": acc, "w": ws,
            "isolator_force_n": isolator.kd_n_per_m * xs[:, 0] + isolator.kw_n * ws, "substeps": int(substeps)}


def reference_response(building: ShearBuilding, isolator: Isolator, time_s, ground_acc_m_per_s2,
                       substeps: int | None = None) -> dict:
    """The full-numerical reference: (S1) with the Bouc-Wen isolator, integrated offline (RK4, see
    ``simulate_isolated_system``) from rest on the record's uniform time grid.

    Returns a dict of 1-D float64 arrays: ``time_s``, ``ground_acc_m_per_s2``, the ``channel_names``
    (``base_displacement_m``, ``drift_j_m``, ``abs_acc_base_m_per_s2``, ``abs_acc_j_m_per_s2``,
    ``isolator_force_n``), plus ``base_velocity_m_per_s`` and ``bouc_wen_w``; and ``substeps`` (int).
    """
    t = np.ascontiguousarray(time_s, dtype=np.float64)
    ag = np.ascontiguousarray(ground_acc_m_per_s2, dtype=np.float64)
    sol = simulate_isolated_system(building.mass_vector_kg(), building.damping_matrix(),
                                   building.stiffness_matrix(), isolator, t, ag, substeps)
    u, acc = sol["u_m"], sol["a_rel_m_per_s2"]
    out = {"time_s": t.copy(), "ground_acc_m_per_s2": ag.copy(), "base_displacement_m": u[:, 0].copy()}
    for j in range(1, building.n_dofs):
        out[f"drift_{j}_m"] = u[:, j] - u[:, j - 1]
    out["abs_acc_base_m_per_s2"] = acc[:, 0] + ag
    for j in range(1, building.n_dofs):
        out[f"abs_acc_{j}_m_per_s2"] = acc[:, j] + ag
    out["isolator_force_n"] = sol["isolator_force_n"]
    out["base_velocity_m_per_s"] = sol["v_m_per_s"][:, 0].copy()
    out["bouc_wen_w"] = sol["w"]
    out["substeps"] = sol["substeps"]
    return out


# ---- a virtual specimen for checks without the rig ------------------------------------------------------
def virtual_rths(building: ShearBuilding, isolator: Isolator, time_s, ground_acc_m_per_s2,
                 delay_steps: int = 0, monitor=None) -> dict:
    """RTHS with an ideal actuator that reaches each command ``delay_steps`` periods late (a pure delay),
    the specimen being the Bouc-Wen model: a check of the integrator and of the stability monitor without
    the rig. Returns ``command_m``, ``measured_m``, ``isolator_force_n``, the channels, and
    ``input_energy_j`` (arrays over the record's samples). ``monitor``: an optional
    sim.hybrid_metrics.EnergyMonitor, updated every period; the run stops when it trips (arrays truncated).
    """
    t = np.ascontiguousarray(time_s, dtype=np.float64)
    ag = np.ascontiguousarray(ground_acc_m_per_s2, dtype=np.float64)
    dt = _uniform_step(t, ag)
    step = CRIntegrator(building, dt, isolator, ag[0])
    names = channel_names(building)
    channels = np.zeros((t.size, len(names)))
    command = np.zeros(t.size)
    measured = np.zeros(t.size)
    force = np.zeros(t.size)
    energy = np.zeros(t.size)
    w = 0.0
    sub = max(1, math.ceil(dt / 1e-4))
    p = (isolator.rho_bw_per_m, isolator.sigma_bw, isolator.n)
    end = t.size
    for k in range(t.size - 1):
        command[k + 1] = step.next_base_displacement()
        measured[k + 1] = command[k + 1 - delay_steps] if k + 1 >= delay_steps else 0.0
        w = bouc_wen_step(w, measured[k], measured[k + 1], dt, sub, *p)
        force[k + 1] = isolator.kd_n_per_m * measured[k + 1] + isolator.kw_n * w
        step.advance(force[k + 1], ag[k + 1])
        step.write_channels(channels[k + 1])
        energy[k + 1] = step.input_energy_j
        if monitor is not None and monitor.update(force[k + 1], command[k + 1], measured[k + 1],
                                                  step.input_energy_j, t[k + 1]):
            end = k + 2
            break
    out = {"time_s": t[:end].copy(), "command_m": command[:end], "measured_m": measured[:end],
           "isolator_force_n": force[:end], "input_energy_j": energy[:end]}
    for i, name in enumerate(names[:-1]):
        out[name] = channels[:end, i]
    return out
