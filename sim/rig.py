"""The test rig: fifth-order model of the paper, eqs. (1)-(3), its parameters and its envelope.

State x = [y, y', P_L, v_e, v_e', w]:

    m y'' + (mu N + F_c) sgn(y') + sigma y' + F_BW = A_p P_L               (3), first line
    V_0 / (2 beta) P_L' = -A_p y' + K_q DZ(v_e) sqrt(P_s - sgn(v_e) P_L)   (3), second line
    v_e'' = -w_mv^2 v_e - 2 xi_v w_mv v_e' + w_mv^2 v_c                    (3), third line
    v_c = k_ep u + v_e0 (u > 0),  v_e0 (u = 0),  k_en u + v_e0 (u < 0)     (2)

plus the Bouc-Wen variable w of eq. (4). Three additions keep the model physical and defined, each
documented where it lives: a stick band for the friction (the table can rest), the valve flow gain
K_q written explicitly (the paper folds it into DZ), and a regularised orifice law below a small
pressure drop (the square root has infinite slope at 0 and is undefined below it).

A fourth describes a single-rod actuator (the paper's is double-rod): with A_B = alpha A_A the other side's area
and P_L = P_A - alpha P_B (docs/rig-protocol.md 4.2), a valve whose lands meter alike gives, from the flow into
one chamber and out of the other with the tank at 0,

    A_A y' = K_q' DZ(v_e) sqrt(P_s - P_L)   (v_e > 0),     A_A y' = K_q' DZ(v_e) sqrt(alpha P_s + P_L)   (v_e < 0)

with one K_q' = K_q / sqrt(1 + alpha^3) both ways: the second line of eq. (3) with P_s scaled by the supply share
s(v_e) = alpha towards -y (``supply_share``); alpha = 1 is the paper's law. Fitting the paper's law to such a rig
puts sqrt(alpha) into k_en (foreign rigs 57, 22, 3, fitted on their true spool position: k_en 0.69-0.73 for alpha
0.56-0.62; with the share, 0.92-0.97).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, fields, replace

import numpy as np
from numba import njit

from .errors import FieldError
from .isolator import Isolator, bouc_wen_rate

BAR_PA = 1.0e5


class RigError(FieldError):
    """A rig parameter out of its range, of the wrong type, or inconsistent with another one."""
LITRE_PER_MIN_M3_S = 1.0e-3 / 60.0


def _p(value, unit, origin, note, lo=0.0, hi=math.inf):
    """A rig parameter: default, unit, origin, note, and the range a lab's rig file may give it."""
    return field(default=value, metadata={"unit": unit, "origin": origin, "note": note, "min": lo, "max": hi})


def area_ratio_b(piston_area_m2: float, piston_area_b_m2: float) -> float:
    """A_B / A_A of the rig file's two areas: 1 on a double-rod actuator (piston_area_b_m2 = 0 says so)."""
    return piston_area_b_m2 / piston_area_m2 if piston_area_b_m2 > 0.0 else 1.0


@dataclass(frozen=True)
class RigParameters:
    """Every rig parameter in one place, with unit and origin (paper / calibrated / assumed)."""

    mass_kg: float = _p(1200.0, "kg", "assumed", "table, rod and part of the isolator (rig-notes)",
                        lo=1.0, hi=1e6)
    friction_coefficient: float = _p(0.015, "-", "assumed", "mu of the linear guides, eq. (1)", lo=0.0, hi=1.0)
    vertical_load_n: float = _p(1.25e5, "N", "paper", "vertical load on the specimen, section V; a test "
                                "condition (sim.engine.Scenario.vertical_load_n), this is its default",
                                lo=0.0, hi=1e8)
    max_vertical_load_n: float = _p(850e3, "N", "paper", "capacity of the vertical jack, section II",
                                    lo=0.0, hi=1e8)
    coulomb_force_n: float = _p(1500.0, "N", "assumed",
                                "F_c, seal friction, eq. (1) (rig-notes; held in the calibration: a step test "
                                "sees mu N + F_c only, set by each table's vertical load)", lo=0.0, hi=1e7)
    viscous_n_s_per_m: float = _p(2.0e4, "N s/m", "assumed", "sigma, viscous friction, eq. (1)",
                                  lo=0.0, hi=1e9)
    piston_area_m2: float = _p(0.01334, "m2", "calibrated",
                               "A_p, static balance of the step tests, one rig for Tables III-IV with one vertical "
                               "load per table (scripts/calibrate.py, docs/identification.md)", lo=1e-5, hi=10.0)
    piston_area_b_m2: float = _p(0.0, "m2", "assumed",
                                 "A_B, the area of the chamber that drives the table towards -y (a single-rod "
                                 "actuator's other side, docs/rig-protocol.md 4.2); 0: equal to piston_area_m2 "
                                 "(a double-rod actuator)", lo=0.0, hi=10.0)
    half_volume_m3: float = _p(2.5e-3, "m3", "assumed", "V_0, oil volume per side at mid-stroke", lo=1e-6, hi=10.0)
    bulk_modulus_pa: float = _p(1.0e9, "Pa", "assumed", "beta, effective with hoses", lo=1e7, hi=1e11)
    flow_gain_m3_per_s_v_sqrt_pa: float = _p(2.764e-7, "m3/(s V sqrt(Pa))", "calibrated",
                                             "K_q inside DZ(v_e); sets a_p of Tables III-IV (scripts/calibrate.py)",
                                             lo=1e-12, hi=0.001)
    dead_zone_v: float = _p(0.8621, "V", "calibrated",
                            "half width of DZ(v_e), spool overlap; rise of a_p with the step voltage (Tables III-IV)",
                            lo=0.0, hi=100.0)
    underlap_v: float = _p(0.0, "V", "assumed",
                           "half width round null where both metering lands are open (an underlapped valve: about "
                           "twice the flow gain there, and a leak with P_L; sim.rig.load_flow); 0: none (a critically "
                           "lapped valve, or an overlapped one: dead_zone_v)", lo=0.0, hi=100.0)
    valve_play_v: float = _p(0.0, "V", "assumed",
                             "the valve's play (backlash) between command and spool, full width: a command that "
                             "reverses moves the spool only once it has come back this far (command_after_play)",
                             lo=0.0, hi=5.0)
    valve_natural_frequency_rad_s: float = _p(2 * np.pi * 40.0, "rad/s", "assumed", "omega_mv, eq. (3)",
                                              lo=1.0, hi=1e5)
    valve_damping_ratio: float = _p(0.7, "-", "assumed", "xi_v, eq. (3)", lo=0.01, hi=10.0)
    driver_gain_positive: float = _p(1.0, "V/V", "assumed", "k_ep, eq. (2)", lo=0.01, hi=100.0)
    driver_gain_negative: float = _p(1.0, "V/V", "assumed", "k_en, eq. (2)", lo=0.01, hi=100.0)
    driver_offset_v: float = _p(0.02, "V", "assumed", "v_e0, eq. (2), valve null offset", lo=-5.0, hi=5.0)
    orifice_regularisation_pa: float = _p(2.234e6, "Pa", "calibrated",
                                          "sqrt(dp) linear below this drop; flattens a_p over P_s (Tables III-IV)",
                                          lo=1.0, hi=1e8)
    stick_velocity_m_per_s: float = _p(1.0e-4, "m/s", "assumed", "below this speed static friction may hold",
                                       lo=1e-9, hi=1.0)
    stick_time_constant_s: float = _p(1.0e-3, "s", "assumed", "how fast a held table comes to rest", lo=1e-6, hi=1.0)
    stroke_m: float = _p(0.15, "m", "assumed", "half stroke: |y| must stay below this", lo=0.001, hi=10.0)
    pump_max_flow_m3_per_s: float = _p(313.0 * LITRE_PER_MIN_M3_S, "m3/s", "paper", "pump, 313 l/min",
                                       lo=1e-7, hi=10.0)
    max_supply_pa: float = _p(210.0 * BAR_PA, "Pa", "paper", "pump and relief valve, 210 bar",
                              lo=1e5, hi=1e8)
    min_supply_pa: float = _p(10.0 * BAR_PA, "Pa", "assumed", "below this the valve law is not meaningful",
                              lo=0.0, hi=1e8)
    command_limit_v: float = _p(10.0, "V", "paper", "valve command saturation +-10 V", lo=0.1, hi=100.0)
    # instrumentation (sim.sensors): what the controller reads is the true value late, noisy and rounded
    position_latency_s: float = _p(0.0, "s", "assumed", "position sensor and acquisition delay", lo=0.0, hi=0.2)
    position_noise_rms_m: float = _p(0.0, "m", "assumed", "RMS noise of the position reading", lo=0.0, hi=0.1)
    position_resolution_m: float = _p(0.0, "m", "assumed", "position reading rounded to this step (0: none)",
                                      lo=0.0, hi=0.01)
    pressure_latency_s: float = _p(0.0, "s", "assumed", "load pressure sensor delay", lo=0.0, hi=0.2)
    pressure_noise_rms_pa: float = _p(0.0, "Pa", "assumed", "RMS noise of the load pressure reading",
                                      lo=0.0, hi=1e7)

    @property
    def area_ratio_b(self) -> float:
        """A_B / A_A (``area_ratio_b``)."""
        return area_ratio_b(self.piston_area_m2, self.piston_area_b_m2)

    @property
    def friction_force_n(self) -> float:
        """mu N + F_c of eq. (1)."""
        return self.friction_coefficient * self.vertical_load_n + self.coulomb_force_n

    def max_force_n(self, supply_pa: float) -> float:
        """The largest force the cylinder can push towards +y: A_p P_s (its cap side at the supply)."""
        return self.piston_area_m2 * supply_pa

    def max_pull_force_n(self, supply_pa: float) -> float:
        """The largest force the cylinder can pull towards -y: A_B P_s (its rod side at the supply; A_p P_s on a
        double-rod actuator)."""
        return self.area_ratio_b * self.piston_area_m2 * supply_pa

    def with_changes(self, **changes) -> RigParameters:
        return replace(self, **changes)

    def check(self) -> None:
        """A clear ``RigError`` naming the first parameter that is out of its range or inconsistent."""
        for f in fields(self):
            value = getattr(self, f.name)
            lo, hi, unit = f.metadata["min"], f.metadata["max"], f.metadata["unit"]
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
                raise RigError(f.name, value, f"a finite number in [{lo:g}, {hi:g}] {unit}",
                               f"rig parameter {f.name} = {value!r} is not a finite number (unit {unit})")
            if not (lo <= value <= hi):
                raise RigError(f.name, value, f"[{lo:g}, {hi:g}] {unit}",
                               f"rig parameter {f.name} = {value:g} {unit} is outside the allowed range "
                               f"[{lo:g}, {hi:g}] {unit}")
        if self.dead_zone_v >= self.command_limit_v:
            raise RigError("dead_zone_v", self.dead_zone_v, f"< command_limit_v = {self.command_limit_v:g} V",
                           f"dead_zone_v = {self.dead_zone_v:g} V is as wide as the command range "
                           f"(+-{self.command_limit_v:g} V): the valve could never open")
        if self.dead_zone_v > 0.0 and self.underlap_v > 0.0:
            raise RigError("underlap_v", self.underlap_v, f"0 while dead_zone_v = {self.dead_zone_v:g} V",
                           f"underlap_v = {self.underlap_v:g} V and dead_zone_v = {self.dead_zone_v:g} V: a valve's "
                           "lands are either overlapped (a dead zone) or underlapped, not both; give one of them")
        if self.piston_area_b_m2 > 0.0 and not (0.2 <= self.area_ratio_b <= 5.0):
            raise RigError("piston_area_b_m2", self.piston_area_b_m2, f"0, or within [0.2, 5] x piston_area_m2 = "
                           f"{self.piston_area_m2:g} m2", f"piston_area_b_m2 = {self.piston_area_b_m2:g} m2 is "
                           f"{self.area_ratio_b:.3g} times piston_area_m2: a single-rod actuator's sides differ by "
                           "less than 5 times (0 says the sides are equal)")
        if self.min_supply_pa >= self.max_supply_pa:
            raise RigError("min_supply_pa", self.min_supply_pa, f"< max_supply_pa = {self.max_supply_pa:g} Pa",
                           f"min_supply_pa = {self.min_supply_pa:g} Pa is not below max_supply_pa "
                           f"= {self.max_supply_pa:g} Pa")
        if self.vertical_load_n > self.max_vertical_load_n:
            raise RigError("vertical_load_n", self.vertical_load_n, f"<= max_vertical_load_n = "
                           f"{self.max_vertical_load_n:g} N", f"vertical_load_n = {self.vertical_load_n:g} N is "
                           f"beyond the jack's capacity max_vertical_load_n = {self.max_vertical_load_n:g} N")

    def describe(self) -> list[dict]:
        """Each parameter with its value, unit, origin and note (for docs, API and reports)."""
        return [
            {"name": f.name, "value": getattr(self, f.name), **f.metadata}
            for f in fields(self)
        ]


DEFAULT_RIG = RigParameters()

# Packed parameter vector for the compiled right-hand side (indices are compile-time constants).
P_MASS, P_FRICTION, P_VISCOUS, P_AREA, P_VOLUME, P_BETA, P_KQ, P_DZ = range(8)
P_WV, P_XIV, P_KEP, P_KEN, P_VE0, P_DPREG, P_VSTICK, P_TSTICK = range(8, 16)
P_SUPPLY, P_RHO, P_SIGMA, P_N, P_KD, P_KW, P_ULIM, P_AREA_RATIO_B = range(16, 24)
P_UNDERLAP, P_PLAY, P_PLAY_HELD = range(24, 27)  # P_PLAY_HELD: the play's state, the command the spool follows
N_PLANT_PARAMS = 27

# State indices.
X_Y, X_V, X_PL, X_VE, X_VED, X_W = range(6)
N_STATES = 6


def pack_plant(rig: RigParameters, isolator: Isolator, supply_pa: float) -> np.ndarray:
    """Parameter vector of the rig with one isolator at one supply pressure."""
    p = np.empty(N_PLANT_PARAMS)
    p[P_MASS] = rig.mass_kg
    p[P_FRICTION] = rig.friction_force_n
    p[P_VISCOUS] = rig.viscous_n_s_per_m
    p[P_AREA] = rig.piston_area_m2
    p[P_VOLUME] = rig.half_volume_m3
    p[P_BETA] = rig.bulk_modulus_pa
    p[P_KQ] = rig.flow_gain_m3_per_s_v_sqrt_pa
    p[P_DZ] = rig.dead_zone_v
    p[P_WV] = rig.valve_natural_frequency_rad_s
    p[P_XIV] = rig.valve_damping_ratio
    p[P_KEP] = rig.driver_gain_positive
    p[P_KEN] = rig.driver_gain_negative
    p[P_VE0] = rig.driver_offset_v
    p[P_DPREG] = rig.orifice_regularisation_pa
    p[P_VSTICK] = rig.stick_velocity_m_per_s
    p[P_TSTICK] = rig.stick_time_constant_s
    p[P_SUPPLY] = supply_pa
    p[P_RHO] = isolator.rho_bw_per_m
    p[P_SIGMA] = isolator.sigma_bw
    p[P_N] = isolator.n
    p[P_KD] = isolator.kd_n_per_m
    p[P_KW] = isolator.kw_n
    p[P_ULIM] = rig.command_limit_v
    p[P_AREA_RATIO_B] = rig.area_ratio_b
    p[P_UNDERLAP] = rig.underlap_v
    p[P_PLAY] = rig.valve_play_v
    p[P_PLAY_HELD] = 0.0
    return p


@njit(cache=True, error_model="numpy", inline="always")
def past_play(u, held, half):
    """The command the spool follows past a play of ``half`` each way, where it followed ``held`` before: held
    until u moves more than half away from it, then u less half, that way (a backlash)."""
    if u - held > half:
        return u - half
    if u - held < -half:
        return u + half
    return held


@njit(cache=True, error_model="numpy")
def command_after_play(u, p):
    """The command past the valve's play (valve_play_v, full width; ``past_play``); the held command is the
    plant's state, kept in p[P_PLAY_HELD] (0 V at the start)."""
    half = 0.5 * p[P_PLAY]
    if half <= 0.0:
        return u
    p[P_PLAY_HELD] = past_play(u, p[P_PLAY_HELD], half)
    return p[P_PLAY_HELD]


@njit(cache=True, error_model="numpy")
def valve_command(u, p):
    """v_c from the control action u, eq. (2), past the valve's play (``command_after_play``; called once per
    command, in order)."""
    u = command_after_play(u, p)
    if u > 0.0:
        return p[P_KEP] * u + p[P_VE0]
    if u < 0.0:
        return p[P_KEN] * u + p[P_VE0]
    return p[P_VE0]


@njit(cache=True, error_model="numpy")
def dead_zone(v, width):
    """DZ(v_e): zero inside +-width, shifted linear outside."""
    if v > width:
        return v - width
    if v < -width:
        return v + width
    return 0.0


@njit(cache=True, error_model="numpy")
def regularised_sqrt(dp, dp_reg):
    """sqrt(dp) above dp_reg, the secant line dp / sqrt(dp_reg) below it (continuous, odd for dp < 0).

    Below dp_reg the orifice is treated as laminar: this removes the infinite slope at dp = 0
    and keeps the flow defined (and reversing) when the pressure drop is zero or negative.
    """
    if dp >= dp_reg:
        return np.sqrt(dp)
    return dp / np.sqrt(dp_reg)


@njit(cache=True, error_model="numpy", inline="always")
def supply_share(v_e, area_ratio_b):
    """s(v_e) of the valve law: 1 towards +y, A_B / A_A towards -y (module docstring)."""
    return 1.0 if v_e > 0.0 else area_ratio_b


@njit(cache=True, error_model="numpy")
def load_flow(v_e, p_load, p):
    """Q_L = K_q DZ(v_e) sqrt(s P_s - sgn(v_e) P_L), eq. (3), second line, in m3/s; s = 1 on the paper's
    double-rod actuator (``supply_share``, module docstring). An underlapped valve (underlap_v = U > 0) has both
    metering lands open round null: K_q [(v_e + U)+ sqrt(P_s - P_L) - (U - v_e)+ sqrt(s P_s + P_L)], the same
    law beyond +-U with the opening shifted by U."""
    underlap = p[P_UNDERLAP]
    if underlap > 0.0:
        towards_plus = max(v_e + underlap, 0.0) * regularised_sqrt(p[P_SUPPLY] - p_load, p[P_DPREG])
        towards_minus = max(underlap - v_e, 0.0) * regularised_sqrt(p[P_AREA_RATIO_B] * p[P_SUPPLY] + p_load,
                                                                   p[P_DPREG])
        return p[P_KQ] * (towards_plus - towards_minus)
    opening = dead_zone(v_e, p[P_DZ])
    if opening == 0.0:
        return 0.0
    sgn = 1.0 if v_e > 0.0 else -1.0
    return p[P_KQ] * opening * regularised_sqrt(supply_share(v_e, p[P_AREA_RATIO_B]) * p[P_SUPPLY] - sgn * p_load,
                                                p[P_DPREG])


@njit(cache=True, error_model="numpy")
def table_acceleration(v, net_force, p):
    """y'' from eq. (3), first line, with Coulomb friction and a stick band.

    ``net_force`` is A_p P_L - F_BW - sigma y'. Outside the stick band the friction is
    (mu N + F_c) sgn(y'). Inside it (|y'| < v_stick), static friction holds the table when
    |net_force| does not exceed mu N + F_c, and the residual speed decays with time constant
    t_stick; otherwise the table breaks away in the direction of the net force.
    """
    friction = p[P_FRICTION]
    if abs(v) < p[P_VSTICK]:
        if abs(net_force) <= friction:
            return -v / p[P_TSTICK]
        direction = 1.0 if net_force > 0.0 else -1.0
        return (net_force - friction * direction) / p[P_MASS]
    direction = 1.0 if v > 0.0 else -1.0
    return (net_force - friction * direction) / p[P_MASS]


@njit(cache=True, error_model="numpy", inline="always")
def rig_rates(y, v, p_load, v_e, v_e_dot, w, v_c, p):
    """Right-hand side of eq. (3) with eq. (4) for the isolator, on the six states as numbers; returns their
    rates (y', y'', P_L', v_e', v_e'', w'). Scalars in and out, so that compiled RK4 keeps the state in registers."""
    f_bw = p[P_KD] * y + p[P_KW] * w
    net = p[P_AREA] * p_load - f_bw - p[P_VISCOUS] * v
    acceleration = table_acceleration(v, net, p)
    q = load_flow(v_e, p_load, p)
    p_load_rate = 2.0 * p[P_BETA] / p[P_VOLUME] * (-p[P_AREA] * v + q)
    wv = p[P_WV]
    v_e_ddot = -wv * wv * v_e - 2.0 * p[P_XIV] * wv * v_e_dot + wv * wv * v_c
    w_rate = bouc_wen_rate(w, v, p[P_RHO], p[P_SIGMA], p[P_N])
    return v, acceleration, p_load_rate, v_e_dot, v_e_ddot, w_rate


@njit(cache=True, error_model="numpy")
def rig_derivatives(x, v_c, p, dx):
    """Right-hand side of eq. (3) with eq. (4) for the isolator (``rig_rates`` on the state vector); writes dx."""
    dx[X_Y], dx[X_V], dx[X_PL], dx[X_VE], dx[X_VED], dx[X_W] = rig_rates(
        x[X_Y], x[X_V], x[X_PL], x[X_VE], x[X_VED], x[X_W], v_c, p)


@njit(cache=True, error_model="numpy", inline="always")
def _rates_at(s, c, k, v_c, p):
    """``rig_rates`` at the state s + c k (an RK4 stage; s and k are 6-tuples)."""
    return rig_rates(s[0] + c * k[0], s[1] + c * k[1], s[2] + c * k[2], s[3] + c * k[3], s[4] + c * k[4],
                     s[5] + c * k[5], v_c, p)


@njit(cache=True, error_model="numpy", inline="always")
def rk4_steps(x, v_c, p, h, n):
    """n classical Runge-Kutta steps of length h with v_c held (zero-order hold); in place on x.

    The state lives in local numbers between the stages and steps (no arrays in the inner loop): the
    same operations in the same order as stage arrays would give, so the same result to the last bit.
    """
    s = (x[X_Y], x[X_V], x[X_PL], x[X_VE], x[X_VED], x[X_W])
    half = 0.5 * h
    for _ in range(n):
        k1 = rig_rates(s[0], s[1], s[2], s[3], s[4], s[5], v_c, p)
        k2 = _rates_at(s, half, k1, v_c, p)
        k3 = _rates_at(s, half, k2, v_c, p)
        k4 = _rates_at(s, h, k3, v_c, p)
        s = (s[0] + h * (k1[0] + 2.0 * k2[0] + 2.0 * k3[0] + k4[0]) / 6.0,
             s[1] + h * (k1[1] + 2.0 * k2[1] + 2.0 * k3[1] + k4[1]) / 6.0,
             s[2] + h * (k1[2] + 2.0 * k2[2] + 2.0 * k3[2] + k4[2]) / 6.0,
             s[3] + h * (k1[3] + 2.0 * k2[3] + 2.0 * k3[3] + k4[3]) / 6.0,
             s[4] + h * (k1[4] + 2.0 * k2[4] + 2.0 * k3[4] + k4[4]) / 6.0,
             s[5] + h * (k1[5] + 2.0 * k2[5] + 2.0 * k3[5] + k4[5]) / 6.0)
    x[X_Y], x[X_V], x[X_PL], x[X_VE], x[X_VED], x[X_W] = s


@njit(cache=True, error_model="numpy")
def rk4_step(x, v_c, p, h):
    """One classical Runge-Kutta step of length h with v_c held (zero-order hold); in place."""
    rk4_steps(x, v_c, p, h, 1)


def rig_derivatives_py(t, x, v_c, p):
    """Python wrapper of rig_derivatives for scipy integrators (t unused: the model is autonomous)."""
    dx = np.empty(N_STATES)
    rig_derivatives(np.asarray(x, dtype=np.float64), v_c, p, dx)
    return dx
