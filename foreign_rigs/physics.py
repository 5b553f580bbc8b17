"""The physics of a foreign rig: a servo-hydraulic table written from first principles, not from isorig's model.

Nothing here comes from ``sim/``: the rig is what a lab has, described by its parts.

- **Servo valve**: a spool with second-order dynamics (its own natural frequency and damping) and end stops, driven
  through a coil with a null bias and a little mechanical play (backlash); four metering lands, each with its own
  lap (overlapped: a dead band; critically lapped; underlapped: both lands open round null, a higher small-signal
  flow gain and a leakage flow), each land an orifice (turbulent, sqrt of the drop, laminar below a transition
  drop) plus a radial-clearance leakage. The flow comes from the land geometry, not from a flow-gain law.
- **Actuator**: double- or single-rod (cap area A_a, rod-side area A_b), each chamber with its own dead volume and
  hose, the oil's bulk modulus lowered by entrained air at low pressure (isothermal gas), the hose walls' own
  compliance, leakage across the piston, cavitation held at the vapour pressure.
- **Supply**: a pressure-compensated pump (its flow falls to zero over a regulator band below its set point)
  into a gas accumulator (isothermal, precharged) and a line with a resistance to the valve: the supply sags with
  the flow the valve draws, and takes time to reach a new set point.
- **Isolation valve**: closed while the rig is not armed (the cylinder's ports blocked, the table held by its oil),
  open from ARM on.
- **Table**: a mass on guides whose friction is LuGre's (Canudas de Wit et al., 1995): pre-sliding bristles,
  Stribeck's dip from static to Coulomb friction, viscous friction, a Coulomb level that grows with the vertical
  load and with the seals' pressure, and a direction asymmetry.
- **Specimen**: none; a spring with elasto-plastic spring-sliders (Iwan); a bilinear lead-rubber bearing whose
  yield force falls as its lead core heats; a softening rubber bearing (stiffness falling with the largest
  displacement seen, a little hysteresis, rate-dependent damping).
- **Sensors**: the position late by a fraction of periods, noisy and quantised; two chamber pressure transducers;
  a load cell with its own resonance; all read at the start of a period, with noise that is a pure function of
  (seed, period, channel).

The state is advanced by classical RK4 at a fixed step; the elasto-plastic sliders are projected back onto their
yield surfaces after each step (return mapping), and the core's heating is the plastic work of that step.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

P_ATM_PA = 1.013e5
VAPOUR_GAUGE_PA = -0.95e5  # a chamber's gauge pressure cannot fall below the oil's vapour pressure
COMMAND_FULL_SCALE_V = 10.0  # the valve's rated input: full spool stroke at 10 V

# --- the state -------------------------------------------------------------------------------------------------
STATE_NAMES = ("position_m", "velocity_m_per_s", "pressure_a_pa", "pressure_b_pa", "spool", "spool_rate_per_s",
               "bristle_m", "accumulator_pa", "load_cell_n", "load_cell_rate_n_per_s", "core_heating_k",
               "slider_0_m", "slider_1_m", "slider_2_m", "slider_3_m", "largest_excursion_m")
(X_Y, X_V, X_PA, X_PB, X_SPOOL, X_SPOOL_RATE, X_BRISTLE, X_ACC, X_LC, X_LC_RATE, X_HEAT,
 X_SLIDER0, X_SLIDER1, X_SLIDER2, X_SLIDER3, X_EXCURSION) = range(len(STATE_NAMES))
N_STATES = len(STATE_NAMES)
N_SLIDERS = 4

# --- the parameters (one packed array for the compiled code; names and units in PARAM_NAMES) -------------------
PARAM_NAMES = (
    "mass_kg", "area_a_m2", "area_b_m2", "dead_volume_a_m3", "dead_volume_b_m3", "hose_volume_a_m3",
    "hose_volume_b_m3", "oil_bulk_modulus_pa", "hose_bulk_modulus_pa", "air_fraction", "piston_leak_m3_per_s_pa",
    "spool_frequency_rad_s", "spool_damping_ratio", "spool_play_v", "null_bias_v", "land_flow_m3_per_s_sqrt_pa",
    "lap_pa", "lap_at", "lap_pb", "lap_bt", "land_leak_m3_per_s_pa", "transition_pa", "tank_pa",
    "pump_flow_m3_per_s", "pump_set_pa", "regulator_band_pa", "accumulator_gas_m3", "precharge_pa",
    "supply_line_volume_m3", "supply_line_resistance_pa_s_per_m3", "relief_pa",
    "vertical_load_n", "coulomb_per_load", "coulomb_n", "seal_m2", "stribeck_ratio", "stribeck_velocity_m_per_s",
    "viscous_n_s_per_m", "bristle_stiffness_n_per_m", "bristle_damping_n_s_per_m", "friction_asymmetry",
    "specimen_kind", "spring_n_per_m", "slider_stiffness_0_n_per_m", "slider_stiffness_1_n_per_m",
    "slider_stiffness_2_n_per_m", "slider_stiffness_3_n_per_m", "slider_strength_0_n", "slider_strength_1_n",
    "slider_strength_2_n", "slider_strength_3_n", "heat_capacity_j_per_k", "strength_loss_per_k",
    "cooling_time_s", "softening_length_m", "rubber_damping_n_s_per_m",
    "load_cell_frequency_rad_s", "load_cell_damping_ratio",
    "position_latency_periods", "position_noise_m", "position_step_m", "pressure_noise_pa", "force_noise_n",
    "supply_noise_pa", "stroke_m", "noise_seed", "isolation_valve_closed",
)
(P_MASS, P_AREA_A, P_AREA_B, P_DEAD_A, P_DEAD_B, P_HOSE_A, P_HOSE_B, P_BETA_OIL, P_BETA_HOSE, P_AIR, P_PISTON_LEAK,
 P_SPOOL_W, P_SPOOL_ZETA, P_PLAY, P_NULL, P_LAND_FLOW, P_LAP_PA, P_LAP_AT, P_LAP_PB, P_LAP_BT, P_LAND_LEAK,
 P_TRANSITION, P_TANK, P_PUMP_FLOW, P_PUMP_SET, P_REG_BAND, P_ACC_GAS, P_PRECHARGE, P_LINE_VOLUME,
 P_LINE_RESISTANCE, P_RELIEF, P_LOAD, P_MU, P_COULOMB, P_SEAL, P_STRIBECK, P_STRIBECK_V, P_VISCOUS, P_BRISTLE_K,
 P_BRISTLE_C, P_ASYM, P_SPECIMEN, P_SPRING, P_SK0, P_SK1, P_SK2, P_SK3, P_SF0, P_SF1, P_SF2, P_SF3, P_HEAT_CAP,
 P_STRENGTH_LOSS, P_COOLING, P_SOFTENING, P_RUBBER_DAMPING, P_LC_W, P_LC_ZETA,
 P_POS_LATENCY, P_POS_NOISE, P_POS_STEP, P_PRESSURE_NOISE, P_FORCE_NOISE, P_SUPPLY_NOISE, P_STROKE,
 P_SEED, P_ISOLATED) = range(len(PARAM_NAMES))
N_PARAMS = len(PARAM_NAMES)

SPECIMEN_NONE, SPECIMEN_SLIDERS, SPECIMEN_LEAD_RUBBER, SPECIMEN_SOFT_RUBBER = 0, 1, 2, 3
SPECIMEN_KINDS = ("none", "spring_sliders", "lead_rubber", "soft_rubber")

# --- what is kept between periods beside the state (the play, the sensors' history) ----------------------------
HISTORY = 64  # periods of the position's history: the longest latency is HISTORY - 2 periods
AUX_PLAY, AUX_LAST_PERIOD = 0, 1  # aux[0]: the coil's input after the play; aux[1]: the last period recorded
N_AUX = 2 + HISTORY
READING_NAMES = ("position_m", "force_n", "load_pressure_pa", "supply_pressure_pa", "true_position_m",
                 "true_velocity_m_per_s", "flow_a_m3_per_s", "spool_v", "specimen_force_n")
(R_POSITION, R_FORCE, R_LOAD_PRESSURE, R_SUPPLY, R_TRUE_Y, R_TRUE_V, R_FLOW, R_SPOOL_V,
 R_SPECIMEN) = range(len(READING_NAMES))
N_READINGS = len(READING_NAMES)


@njit(cache=True, error_model="numpy", inline="always")
def _orifice(opening, drop_pa, p):
    """Flow through one metering land, m3/s: turbulent (sqrt of the drop) above the transition drop, laminar
    below it; ``opening`` is the share of the spool's full stroke that is open."""
    return p[P_LAND_FLOW] * opening * drop_pa / math.sqrt(abs(drop_pa) + p[P_TRANSITION])


@njit(cache=True, error_model="numpy", inline="always")
def supply_at_valve(x, p):
    """The supply pressure at the valve's P port, Pa: the accumulator's less the line's drop (the valve's draw
    estimated from the accumulator's pressure)."""
    ps = x[X_ACC]
    xs = x[X_SPOOL]
    o_pa = max(0.0, xs - p[P_LAP_PA])
    o_pb = max(0.0, -xs - p[P_LAP_PB])
    draw = (_orifice(o_pa, ps - x[X_PA], p) + _orifice(o_pb, ps - x[X_PB], p)
            + p[P_LAND_LEAK] * (2.0 * ps - x[X_PA] - x[X_PB]))
    return ps - p[P_LINE_RESISTANCE] * max(draw, 0.0)


@njit(cache=True, error_model="numpy", inline="always")
def _compliance(volume_m3, hose_m3, gauge_pa, p):
    """dV/dp of one chamber and its hose, m3/Pa: the oil (with entrained air, isothermal) and the hose walls."""
    absolute = max(gauge_pa + P_ATM_PA, 0.2 * P_ATM_PA)
    oil = 1.0 / p[P_BETA_OIL] + p[P_AIR] * P_ATM_PA / (absolute * absolute)
    return volume_m3 * oil + hose_m3 * (oil + 1.0 / p[P_BETA_HOSE])


@njit(cache=True, error_model="numpy", inline="always")
def specimen_force(x, p):
    """The specimen's force on the table, N (positive when deformed towards +y): elastic part and sliders as
    they stand (the sliders' state is on their yield surface after each step)."""
    kind = int(p[P_SPECIMEN])
    y = x[X_Y]
    if kind == SPECIMEN_NONE:
        return 0.0
    f = p[P_SPRING] * y
    if kind == SPECIMEN_SOFT_RUBBER:
        f = p[P_SPRING] * y / (1.0 + x[X_EXCURSION] / p[P_SOFTENING]) + p[P_RUBBER_DAMPING] * x[X_V]
    for i in range(N_SLIDERS):
        k = p[P_SK0 + i]
        if k > 0.0:
            f += k * (y - x[X_SLIDER0 + i])
    return f


@njit(cache=True, error_model="numpy", inline="always")
def slider_strength(i, x, p):
    """Slider i's yield force, N; a lead core's (slider 0 of a lead-rubber bearing) falls as it heats."""
    strength = p[P_SF0 + i]
    if int(p[P_SPECIMEN]) == SPECIMEN_LEAD_RUBBER and i == 0:
        strength *= max(0.3, 1.0 - p[P_STRENGTH_LOSS] * x[X_HEAT])
    return strength


@njit(cache=True, error_model="numpy", inline="always")
def friction_level(x, p):
    """The guides' and seals' Coulomb level g(v) of LuGre, N: Coulomb at the vertical load and the seals'
    pressure, Stribeck's static peak at rest, asymmetric by direction."""
    v = x[X_V]
    coulomb = p[P_MU] * p[P_LOAD] + p[P_COULOMB] + p[P_SEAL] * (abs(x[X_PA]) + abs(x[X_PB]))
    ratio = v / p[P_STRIBECK_V]
    level = coulomb * (1.0 + (p[P_STRIBECK] - 1.0) * math.exp(-ratio * ratio))
    if v > 0.0:
        level *= 1.0 + p[P_ASYM]
    else:
        level *= 1.0 - p[P_ASYM]
    return max(level, 1.0)


@njit(cache=True, error_model="numpy")
def derivatives(x, p, coil_v, dx):
    """dx/dt of the whole rig for the coil input ``coil_v`` (volts after the play)."""
    y, v = x[X_Y], x[X_V]
    pa, pb = x[X_PA], x[X_PB]
    xs = x[X_SPOOL]
    # the spool: a second-order response to the coil, in shares of its full stroke
    demand = (coil_v + p[P_NULL]) / COMMAND_FULL_SCALE_V
    w = p[P_SPOOL_W]
    dx[X_SPOOL] = x[X_SPOOL_RATE]
    dx[X_SPOOL_RATE] = w * w * (demand - xs) - 2.0 * p[P_SPOOL_ZETA] * w * x[X_SPOOL_RATE]
    # the four metering lands
    ps = supply_at_valve(x, p)
    pt = p[P_TANK]
    leak = p[P_LAND_LEAK]
    q_pa = _orifice(max(0.0, xs - p[P_LAP_PA]), ps - pa, p) + leak * (ps - pa)
    q_at = _orifice(max(0.0, -xs - p[P_LAP_AT]), pa - pt, p) + leak * (pa - pt)
    q_pb = _orifice(max(0.0, -xs - p[P_LAP_PB]), ps - pb, p) + leak * (ps - pb)
    q_bt = _orifice(max(0.0, xs - p[P_LAP_BT]), pb - pt, p) + leak * (pb - pt)
    if p[P_ISOLATED] > 0.0:  # the isolation valve between the servo valve and the cylinder is closed: no flow
        q_pa = q_at = q_pb = q_bt = 0.0
    q_cross = p[P_PISTON_LEAK] * (pa - pb)
    # the chambers
    a_a, a_b = p[P_AREA_A], p[P_AREA_B]
    c_a = _compliance(p[P_DEAD_A] + a_a * y, p[P_HOSE_A], pa, p)
    c_b = _compliance(p[P_DEAD_B] - a_b * y, p[P_HOSE_B], pb, p)
    dpa = (q_pa - q_at - a_a * v - q_cross) / c_a
    dpb = (q_pb - q_bt + a_b * v + q_cross) / c_b
    if pa <= VAPOUR_GAUGE_PA and dpa < 0.0:
        dpa = 0.0
    if pb <= VAPOUR_GAUGE_PA and dpb < 0.0:
        dpb = 0.0
    dx[X_PA] = dpa
    dx[X_PB] = dpb
    # the pump into the accumulator, the valve drawing from it
    acc = x[X_ACC]
    pump = p[P_PUMP_FLOW] * min(1.0, max(0.0, (p[P_PUMP_SET] - acc) / p[P_REG_BAND]))
    if acc > p[P_RELIEF]:
        pump -= (acc - p[P_RELIEF]) * 1e-9  # the relief valve spills
    absolute = acc + P_ATM_PA
    gas = 0.0
    if absolute > p[P_PRECHARGE] + P_ATM_PA:
        gas = p[P_ACC_GAS] * (p[P_PRECHARGE] + P_ATM_PA) / (absolute * absolute)
    c_s = gas + p[P_LINE_VOLUME] / p[P_BETA_OIL]
    drawn = q_pa + q_pb
    dx[X_ACC] = (pump - drawn) / c_s
    # the table: actuator, LuGre friction, specimen
    level = friction_level(x, p)
    z = x[X_BRISTLE]
    dz = v - p[P_BRISTLE_K] * abs(v) * z / level
    friction = p[P_BRISTLE_K] * z + p[P_BRISTLE_C] * dz + p[P_VISCOUS] * v
    spec = specimen_force(x, p)
    dx[X_Y] = v
    dx[X_V] = (pa * a_a - pb * a_b - friction - spec) / p[P_MASS]
    dx[X_BRISTLE] = dz
    # the load cell's own resonance, driven by the specimen's force
    wl = p[P_LC_W]
    dx[X_LC] = x[X_LC_RATE]
    dx[X_LC_RATE] = wl * wl * (spec - x[X_LC]) - 2.0 * p[P_LC_ZETA] * wl * x[X_LC_RATE]
    # the core cools (its heating is the sliders' plastic work, added in the return mapping)
    dx[X_HEAT] = -x[X_HEAT] / p[P_COOLING]
    for i in range(N_SLIDERS):
        dx[X_SLIDER0 + i] = 0.0
    dx[X_EXCURSION] = 0.0


@njit(cache=True, error_model="numpy")
def _return_mapping(x, p):
    """After a step: spool at its stops, chambers above vapour pressure, each slider back onto its yield surface
    (the slip's plastic work heats the core), the largest excursion kept."""
    if x[X_SPOOL] > 1.05:
        x[X_SPOOL] = 1.05
        x[X_SPOOL_RATE] = min(x[X_SPOOL_RATE], 0.0)
    elif x[X_SPOOL] < -1.05:
        x[X_SPOOL] = -1.05
        x[X_SPOOL_RATE] = max(x[X_SPOOL_RATE], 0.0)
    x[X_PA] = max(x[X_PA], VAPOUR_GAUGE_PA)
    x[X_PB] = max(x[X_PB], VAPOUR_GAUGE_PA)
    y = x[X_Y]
    for i in range(N_SLIDERS):
        k = p[P_SK0 + i]
        if k <= 0.0:
            continue
        limit = slider_strength(i, x, p) / k
        stretch = y - x[X_SLIDER0 + i]
        if stretch > limit:
            slip = stretch - limit
        elif stretch < -limit:
            slip = stretch + limit
        else:
            continue
        x[X_SLIDER0 + i] += slip
        if p[P_HEAT_CAP] > 0.0:
            x[X_HEAT] += slider_strength(i, x, p) * abs(slip) / p[P_HEAT_CAP]
    x[X_EXCURSION] = max(x[X_EXCURSION], abs(y))


@njit(cache=True, error_model="numpy")
def _rk4(x, p, coil_v, h, k1, k2, k3, k4, tmp):
    derivatives(x, p, coil_v, k1)
    for j in range(N_STATES):
        tmp[j] = x[j] + 0.5 * h * k1[j]
    derivatives(tmp, p, coil_v, k2)
    for j in range(N_STATES):
        tmp[j] = x[j] + 0.5 * h * k2[j]
    derivatives(tmp, p, coil_v, k3)
    for j in range(N_STATES):
        tmp[j] = x[j] + h * k3[j]
    derivatives(tmp, p, coil_v, k4)
    for j in range(N_STATES):
        x[j] += h / 6.0 * (k1[j] + 2.0 * k2[j] + 2.0 * k3[j] + k4[j])
    _return_mapping(x, p)


@njit(cache=True, error_model="numpy")
def coil_after_play(command_v, aux, p):
    """The coil's input after the torque motor's play: it follows the command only once the command has moved
    past half the play from it."""
    half = 0.5 * p[P_PLAY]
    if command_v - aux[AUX_PLAY] > half:
        aux[AUX_PLAY] = command_v - half
    elif command_v - aux[AUX_PLAY] < -half:
        aux[AUX_PLAY] = command_v + half
    return aux[AUX_PLAY]


@njit(cache=True, error_model="numpy")
def advance(x, p, aux, old_command_v, new_command_v, switch_step, steps, h):
    """One control period of ``steps`` RK4 steps of h seconds; the command changes from old to new after
    ``switch_step`` steps (a command that arrives within the period). False if the state went non-finite."""
    k1 = np.empty(N_STATES)
    k2 = np.empty(N_STATES)
    k3 = np.empty(N_STATES)
    k4 = np.empty(N_STATES)
    tmp = np.empty(N_STATES)
    coil = coil_after_play(old_command_v, aux, p)
    for i in range(steps):
        if i == switch_step:
            coil = coil_after_play(new_command_v, aux, p)
        _rk4(x, p, coil, h, k1, k2, k3, k4, tmp)
    for j in range(N_STATES):
        if not math.isfinite(x[j]):
            return False
    return True


# the noise generator: the same splitmix64 and Box-Muller as sim.sensors, written again here on purpose (the
# instrument imports nothing from sim; a rig of its own has its own noise)
@njit(cache=True, error_model="numpy")
def _splitmix64(z):
    z = z + np.uint64(0x9E3779B97F4A7C15)
    z = (z ^ (z >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
    z = (z ^ (z >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
    return z ^ (z >> np.uint64(31))


@njit(cache=True, error_model="numpy")
def gaussian(seed, period, channel):
    """A standard normal number that depends only on (seed, period, channel) (Box-Muller on splitmix64)."""
    key = np.uint64(seed) * np.uint64(1099511628211) + np.uint64(period) * np.uint64(16) + np.uint64(channel)
    z1 = _splitmix64(key)
    z2 = _splitmix64(z1)
    u1 = (float(z1 >> np.uint64(11)) + 0.5) * (1.0 / 9007199254740992.0)
    u2 = float(z2 >> np.uint64(11)) * (1.0 / 9007199254740992.0)
    return math.sqrt(-2.0 * math.log(u1)) * math.cos(2.0 * math.pi * u2)


@njit(cache=True, error_model="numpy")
def read(x, p, aux, period, out):
    """The rig's readings at the start of ``period`` into ``out`` (READING_NAMES): the position late, noisy and
    quantised; the load pressure P_A - (A_B/A_A) P_B from two noisy transducers; the supply at the valve; the
    load cell's reading. The true position is recorded once per period for the latency."""
    last = int(aux[AUX_LAST_PERIOD])
    if period > last:
        aux[2 + period % HISTORY] = x[X_Y]
        if last < 0:  # the first reading: the table rested here before
            for i in range(HISTORY):
                aux[2 + i] = x[X_Y]
        aux[AUX_LAST_PERIOD] = period
    lag = p[P_POS_LATENCY]
    whole = int(lag)
    frac = lag - whole
    i0 = max(period - whole, 0)
    i1 = max(i0 - 1, 0)
    y = (1.0 - frac) * aux[2 + i0 % HISTORY] + frac * aux[2 + i1 % HISTORY]
    seed = int(p[P_SEED])
    y += p[P_POS_NOISE] * gaussian(seed, period, 0)
    if p[P_POS_STEP] > 0.0:
        y = math.floor(y / p[P_POS_STEP] + 0.5) * p[P_POS_STEP]
    out[R_POSITION] = y
    out[R_FORCE] = x[X_LC] + p[P_FORCE_NOISE] * gaussian(seed, period, 1)
    # the load pressure as docs/rig-protocol.md 4.2 defines it: the actuator's force over the +y side's area,
    # P_A - (A_B / A_A) P_B, from the two transducers' readings (P_A - P_B on a double-rod actuator)
    area_ratio = p[P_AREA_B] / p[P_AREA_A]
    out[R_LOAD_PRESSURE] = (x[X_PA] + p[P_PRESSURE_NOISE] * gaussian(seed, period, 2)
                            - area_ratio * (x[X_PB] + p[P_PRESSURE_NOISE] * gaussian(seed, period, 3)))
    supply = supply_at_valve(x, p)
    out[R_SUPPLY] = supply + p[P_SUPPLY_NOISE] * gaussian(seed, period, 4)
    out[R_TRUE_Y] = x[X_Y]
    out[R_TRUE_V] = x[X_V]
    xs = x[X_SPOOL]
    out[R_FLOW] = (_orifice(max(0.0, xs - p[P_LAP_PA]), supply - x[X_PA], p)
                   - _orifice(max(0.0, -xs - p[P_LAP_AT]), x[X_PA] - p[P_TANK], p))
    out[R_SPOOL_V] = xs * COMMAND_FULL_SCALE_V
    out[R_SPECIMEN] = specimen_force(x, p)


def new_aux() -> np.ndarray:
    """The play and the sensors' history, before the first period."""
    aux = np.zeros(N_AUX)
    aux[AUX_LAST_PERIOD] = -1.0
    return aux
