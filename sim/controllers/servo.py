"""Learning servo controller: flow-linearised velocity feed-forward, position feedback, an estimate of the
valve's true flow gain, dead zone and null offset, harmonic learning of the periodic error, and what a lab's
declared rig adds (a damping load-pressure feedback on a soft oil column, the sensor latency, and on small fast
tests the oil's compression flow fed forward). Design and stability argument: docs/controller.md.

    v    = r' + tau_v r'' + K_p (r(t - L) - y_L) + dv + v_c      velocity demand, m/s (y_L: the reading, L late)
    dv   = c_0 + V_env Re sum_k c_k exp(j k theta)              learned periodic feed-forward
    v_c  = (V_0 / (2 beta A_n)) Re sum_k s_k j k w P_k exp(j k theta) / V(j k w)
                                                                compression flow (eq. 3 second line), fed forward
    u_l  = A_n (v / g) / (K_qn R(P_s - sgn(v) P_L))             inverse of the valve flow law, eq. (3) second line
    u    = u_l + DZ ramp(u_l / delta) - o + u_pf                dead-zone inverse (ramp over +-delta), null offset
           (time histories: ramp((u_l - u_fb) / delta + u_fb / delta_fb), u_fb the command of K_p e + c_0; where
           the target is still, the ramp's share moves at most 0.5 V/s towards the error's side: no relay; under a
           ringing target, still_share, the side of the table's error from the centre of the swings)
    u_pf = -A_n k_pf HP(P_L) / (g K_qn R(P_s - sgn(v) P_L))     load-pressure feedback (soft oil columns only)
    u_s  = U^-1(u) + (b / 2) side                               across an underlap U (``_across_underlap``: the
           four-land law inverted round null) and the valve's play b (``_across_play``: the command leads the
           spool by half the play the way u moves it, and keeps its side while u holds)

R is the orifice law of the rig model: sqrt(dp), linear below the declared regularisation drop. g is the ratio of
the true to the nominal flow gain (K_q A_n / (K_qn A_p)), DZ the valve's dead zone and o its null offset (v_e0 of
eq. 2), estimated by least squares of the table's velocity (optionally plus the oil's compression flow
(V_0 / (2 beta A_n)) P_L', eq. 3 second line: ``compressibility_share``) on what the nominal valve gives for the
command sent tau_l + L earlier: y' = g (x - DZ w + o z), x = u K_qn R(dp) / A_n, w = sgn(u + o) K_qn R(dp) / A_n,
z = K_qn R(dp) / A_n (exponential forgetting, a prior at the nominal values, projection; the offset over a longer
window); it keeps the loop gain at K_p whatever the valve and the nominal values.

theta and V_env (the phase and the velocity amplitude of the sine target) come from the target rate r' and
its differences, so the controller needs no profile information: for r = A sin(w t), w^2 = -r''' r' / r'^2
at every instant. The complex coefficients c_k (harmonic k = 1..H of the target frequency, dimensionless:
relative to the target's peak velocity) learn the periodic error:

    c_k += gamma_k dt / (pi A_eff) (r(t - L) - y_L) exp(-j k theta) L_k
    L_k = (K_p + j k w) exp(j k w (tau_l + L)) (1 - (k w / w_h)^2 + 2 j zeta_h k w / w_h)
    gamma_k = gamma min(1, K_p / (k w))

that is, the error's k-th Fourier coefficient divided by a nominal model of the closed loop from dv to y
(1 / (s + K_p) with a pure delay for the valve and the reading, and the declared oil column w_h damped by the
pressure feedback's zeta_h), so each harmonic's error shrinks by about (1 - gamma_k) per cycle. H is 15 harmonics,
up to 12 Hz and half the declared column; on a fast test (peak target velocity from 10 mm/s, while the valve's
pressure-flow slope at that velocity, which the inverse cancels a valve lag late, would damp the declared column by
less than 0.25) 64, up to 25 Hz and 1.2 times the column. On such tests up to 30 mm/s, v_c feeds forward the flow
that compresses the oil as the load pressure changes (at each reversal the friction flips): P_k are the load
pressure's harmonics over the last whole steady cycles, V the declared valve with the sampling delay, s_k Lanczos
factors, from K_p to 30 Hz. The learning
runs only on a steady sine (not in a taper, not at a block change; a new frequency clears it), is frozen while
the command saturates (the error then says nothing about the feed-forward) and each |c_k| is projected onto a
bound. Only the measured position, the load pressure, the supply pressure setting and declared rig values (A_p,
K_q, dead zone, null offset, orifice regularisation, command limit; m, V_0, beta and the valve's frequency and
damping for the pressure feedback; the position sensor's latency) are used; never the isolator's parameters.

Time histories (the integral on, HISTORY_MODE): where the target is slow, the feedback's correction ramps in the
dead zone over at least delta_fb (dead_zone_feedback_ramp_v), so the dead zone's side follows the target's motion
and a table at rest holds its valve closed; the integral pauses while it does; and the error with the sign of the
opening trims the compensated dead zone down (never up) by what the estimate has too much (docs/controller.md,
"Time histories at rest").

Report: model_m = r (the feed-forward removes the reference lag: the reference model is the target itself);
ar_hat = g, the estimated ratio of the true to the nominal flow gain; ay_hat = the estimated dead zone in V;
as_hat = the target frequency the learning is locked to, in Hz (0 before the first steady cycle).
"""

from __future__ import annotations

import math
from functools import lru_cache

import numpy as np
from numba import njit

from ..rig import area_ratio_b, supply_share
from .base import (
    M_HOLD_LEARNING,
    M_LOAD_PRESSURE,
    M_POSITION,
    M_SUPPLY_PRESSURE,
    M_TARGET,
    M_TARGET_RATE,
    R_AR,
    R_AS,
    R_AY,
    R_MODEL,
    Adapted,
    Controller,
    ControllerOptionError,
    Option,
    check_options,
)

KIND = 3
MAX_HARMONICS = 64

# Parameter indices.
(P_AREA, P_KQ, P_DZ, P_ULIM, P_KP, P_TAU_V, P_TAU_L, P_GAMMA, P_NH, P_FMAX, P_DZ_RAMP, P_DP_MIN,
 P_TW, P_AFLOOR, P_C1MAX, P_CKMAX, P_C0MAX, P_DZ_FRAC, P_GW, P_GMIN, P_GMAX, P_GVMIN, P_STEADY,
 P_PL_SHARE, P_DZ_ADAPT, P_DZ_LO, P_DZ_HI) = range(27)
P_JERK_LEAD, P_INTEGRAL = 27, 28
(P_RAMP_SHARE, P_RAMP_MIN, P_OFFSET_MAX, P_KPF, P_PF_WC, P_LAT, P_COMPLIANCE, P_WH, P_ZH, P_OFFSET_ADAPT,
 P_OW, P_DP_REG, P_OVMIN, P_OVT) = range(29, 43)
P_FB_RAMP, P_EDGE_TRIM = 43, 44
(P_NH_FAST, P_FMAX_FAST, P_V_FAST, P_ZC_MAX, P_ZC_PER_V, P_COMP, P_CFMAX, P_CGAIN, P_WV, P_XV, P_CVMAX) = range(45, 56)
# a still target (docs/controller.md, "A still target, a still valve")
(P_STILL_SWING, P_STILL_SWING_V, P_STILL_SPEED_T, P_STILL_SPEED, P_STILL_ACC_T, P_STILL_RATE, P_STILL_BAND,
 P_STILL_REST, P_STILL_SHARE) = range(56, 65)
P_STILL_HOLD_SHARE = 65
P_STILL_CENTRE = 66
STILL_FAST_RATE_SHARE = 20.0  # the still share's rate for an error of many bands, times still_command_rate_v_per_s
P_AREA_RATIO_B = 67  # A_B / A_A of a single-rod actuator (1: double-rod)
P_PLAY = 68  # the valve's play that the command crosses at each reversal, V (full width)
P_UNDERLAP = 69  # the valve's underlap, V: round null the command inverts the four-land law
P_PF_SMALL, P_PF_FULL_V = 70, 71  # the pressure feedback's share on small motions; the velocity from which all of it
P_LB_FACTOR, P_LB_CYCLES = 72, 73  # the learned feed-forward's bounds times this after that many cycles learned
N_PARAMS = 74
DELAY_LINE = 256  # periods of regressor and target history kept (valve estimate, position latency)

# State indices; the delay line and the harmonic coefficients (real, imaginary) follow.
(S_STARTED, S_RD1, S_RD2, S_NUM, S_DEN, S_OMEGA_LEARNED, S_C0, S_SAT, S_VENV, S_YPREV, S_GXY, S_GXX,
 S_GAIN, S_HEAD, S_STEADY_S, S_GXW, S_GWW, S_GWY, S_DZ_HAT, S_NEW_FREQ_S) = range(20)
(S_OFFSET, S_GZZ, S_GXZ, S_GWZ, S_GZY, S_PL_PREV, S_PL_HP) = range(20, 27)
S_EDGE = 27  # trim of the compensated dead zone, V (<= 0; time histories, slow motions)
# the same sums over the offset's longer window: xx, xw, ww, xz, wz, zz, xy, wy, zy
S_LONG = 28
S_LINE_X = S_LONG + 9
S_LINE_W = S_LINE_X + DELAY_LINE
S_LINE_Z = S_LINE_W + DELAY_LINE
S_LINE_R = S_LINE_Z + DELAY_LINE
S_C = S_LINE_R + DELAY_LINE
S_P = S_C + 2 * MAX_HARMONICS  # the load pressure's harmonics (Pa, real and imaginary) over the last cycles
S_PACC = S_P + 2 * MAX_HARMONICS  # ... their sums over the running cycle
S_PCYC = S_PACC + 2 * MAX_HARMONICS  # 1: the running cycle has been steady throughout
S_THETA_PREV = S_PCYC + 1  # the target's phase of the last period
# a still target (target_stillness, still_dead_zone_share): the target's swings (where the running one began, its
# extreme so far, its direction, the last whole swing, the one before and the largest, m), its recent peak speed
# (m/s) and the
# dead zone's compensated share (-1..1) of the last period
(S_SWING_FROM, S_SWING_EXT, S_SWING_DIR, S_SWING_LAST, S_SWING_PREV, S_SWING_MAX, S_SPEED_REC, S_SIDE) = range(
    S_THETA_PREV + 1, S_THETA_PREV + 9)
S_HELD = S_SIDE + 1  # the held part of the target's stillness (0-1) this period, as still_hold_share weighs it
# the centre of the target's swings (m): the mean of the last two whole swings' midpoints, and the last midpoint; and
# the ringing part of the stillness this period (0-1: still_share times the ringing's stillness where it is no hold)
S_CENTRE, S_MID_LAST, S_RING = S_HELD + 1, S_HELD + 2, S_HELD + 3
# the valve's play: the command the spool follows (V) and the side the command last led it on (-1, 0, 1)
S_PLAY_HELD, S_PLAY_SIDE = S_RING + 1, S_RING + 2
S_LEARNED_S = S_PLAY_SIDE + 1  # how long the learning has been locked to its frequency on a steady sine, s
N_STATE = S_LEARNED_S + 1


def _nominal_rig(rig=None) -> dict:
    """The nominal values the servo takes from the rig the lab describes (default: sim.rig.DEFAULT_RIG)."""
    from ..rig import DEFAULT_RIG

    rig = rig or DEFAULT_RIG
    return {name: getattr(rig, name) for name in RIG_OPTIONS}


#: the servo's options that default to the rig's value of the same name (what the lab's rig file says)
RIG_OPTIONS = ("piston_area_m2", "flow_gain_m3_per_s_v_sqrt_pa", "dead_zone_v", "command_limit_v", "mass_kg",
               "half_volume_m3", "bulk_modulus_pa", "valve_natural_frequency_rad_s", "valve_damping_ratio",
               "orifice_regularisation_pa", "driver_offset_v", "position_latency_s", "piston_area_b_m2",
               "valve_play_v", "underlap_v")
SAMPLING_DELAY_S = 1.5e-3  # what the loop adds to the valve: half a 1 ms period of zero-order hold and one period


OPTIONS = {
    # nominal rig values (the rig's, never the isolator's); taken from sim.rig.DEFAULT_RIG when not given
    "piston_area_m2": Option(None, 1e-4, 1.0, "m2", meaning="nominal piston area A_p"),
    "flow_gain_m3_per_s_v_sqrt_pa": Option(None, 1e-10, 1e-4, "m3/(s V sqrt(Pa))", meaning="nominal valve flow gain"),
    "dead_zone_v": Option(None, 0.0, 5.0, "V", meaning="nominal valve dead zone (half width)"),
    "command_limit_v": Option(None, 0.1, 20.0, "V", meaning="valve command saturation"),
    "mass_kg": Option(None, 1.0, 1e6, "kg", meaning="nominal moving mass m (sets the oil column's frequency)"),
    "half_volume_m3": Option(None, 1e-6, 10.0, "m3", meaning="nominal oil volume per side V_0, hoses included"),
    "bulk_modulus_pa": Option(None, 1e7, 1e11, "Pa", meaning="nominal effective bulk modulus beta"),
    "valve_natural_frequency_rad_s": Option(None, 1.0, 1e5, "rad/s", meaning="nominal valve natural frequency "
                                            "(the design of the pressure feedback)"),
    "valve_damping_ratio": Option(None, 0.01, 10.0, "-", meaning="nominal valve damping ratio"),
    "orifice_regularisation_pa": Option(None, 0.0, 1e8, "Pa", meaning="nominal pressure drop below which the "
                                        "valve's flow goes as dp, not sqrt(dp) (the rig model's; 0: sqrt always)"),
    "driver_offset_v": Option(None, -5.0, 5.0, "V", meaning="nominal valve null offset v_e0 (eq. 2): where the "
                              "estimate of the offset starts"),
    "position_latency_s": Option(None, 0.0, 0.2, "s", meaning="declared delay of the position reading: the "
                                 "controller aims the table, not the late reading"),
    "piston_area_b_m2": Option(None, 0.0, 10.0, "m2", meaning="nominal area of the side that pushes towards -y (a "
                               "single-rod actuator's; 0: equal to piston_area_m2): the valve law's supply share "
                               "towards -y (sim.rig)"),
    "valve_play_v": Option(None, 0.0, 5.0, "V", meaning="nominal valve play (backlash between command and spool, "
                           "full width): the command crosses it at each reversal (0: none)"),
    "underlap_v": Option(None, 0.0, 5.0, "V", meaning="nominal valve underlap (both lands open round null, "
                         "sim.rig.load_flow): the command inverts the four-land law there (0: none)"),
    # fixed design constants, the same on every isolator (docs/controller.md)
    "kp_per_s": Option(30.0, 1e-3, 500.0, "1/s", meaning="position loop gain: velocity demand per metre of error "
                       "(the largest: lowered where the rig's loop would keep less than min_gain_margin)"),
    "min_gain_margin": Option(2.0, 0.0, 20.0, "-", meaning="the position loop keeps this gain margin on the rig it is "
                              "told of: kp_per_s is lowered until the linearised loop stays stable with the valve's "
                              "flow this many times the estimate (0: kp_per_s as given)"),
    "min_kp_share": Option(0.2, 0.01, 1.0, "-", meaning="... down to this share of kp_per_s: a rig that needs less is "
                           "refused before anything moves"),
    "velocity_lead_s": Option(0.006, 0.0, 0.1, "s", meaning="feed-forward lead for the valve lag (r' + tau r'')"),
    "learning_lag_s": Option(0.007, 0.0, 0.05, "s", meaning="delay of the nominal loop model the learning inverts"),
    "learning_gain": Option(0.8, 0.0, 1.5, "-", meaning="share of each harmonic's error removed per cycle"),
    "harmonics": Option(15, 0, MAX_HARMONICS, "-", "int", "harmonics of the target frequency learned"),
    "learning_max_hz": Option(12.0, 1e-3, 100.0, "Hz", meaning="harmonics above this frequency are not learned"),
    "learning_max_oil_share": Option(0.5, 0.01, 10.0, "-", meaning="... nor above this share of the nominal "
                                     "oil-column frequency"),
    # fast tests where the oil column stays damped (docs/controller.md, "Soft columns, friction and reversals")
    "fast_harmonics": Option(MAX_HARMONICS, 0, MAX_HARMONICS, "-", "int", "harmonics learned on a fast test"),
    "fast_learning_max_hz": Option(25.0, 1e-3, 100.0, "Hz", meaning="on a fast test harmonics are learned up to this "
                                   "frequency"),
    "fast_learning_max_oil_share": Option(1.2, 0.01, 10.0, "-", meaning="... and up to this share of the declared "
                                          "oil-column frequency"),
    "fast_velocity_m_per_s": Option(0.01, 0.0, 10.0, "m/s", meaning="a test is fast from this peak target "
                                    "velocity (fading in from half of it; below, the learned harmonics and the "
                                    "compression pulses would throw the narrow dead-zone inverse across its dead zone "
                                    "mid-stroke)"),
    "fast_max_valve_damping": Option(0.25, 0.0, 10.0, "-", meaning="... while the damping the valve's pressure-flow "
                                     "slope would give the declared column at the target's peak velocity, V_env / "
                                     "(4 P_s sqrt(C / m)), is below this (fading out at twice it): the valve-law "
                                     "inverse cancels that slope a valve lag late and the column's mode is then less "
                                     "damped than the loop model says"),
    "compression_feedforward_share": Option(1.0, 0.0, 2.0, "-", meaning="on a fast test, share of the oil's "
                                            "compression flow (V_0 / (2 beta)) P_L' fed forward from the load "
                                            "pressure's harmonics of the last cycles, from K_p up (0: off)"),
    "compression_max_velocity_m_per_s": Option(0.03, 0.0, 10.0, "m/s", meaning="the compression feed-forward serves "
                                               "tests up to this peak target velocity (fading out at twice it)"),
    "compression_max_hz": Option(30.0, 0.1, 200.0, "Hz", meaning="the compression feed-forward's highest harmonic"),
    "compression_gain": Option(0.5, 0.0, 1.0, "-", meaning="share of a whole steady cycle's pressure harmonics the "
                               "compression feed-forward takes"),
    "dead_zone_ramp_v": Option(0.05, 1e-4, 2.0, "V", meaning="the dead-zone inverse ramps in over +-this"),
    "dead_zone_share": Option(1.0, 0.0, 2.0, "-", meaning="share of the dead zone that is compensated"),
    "min_pressure_drop_share": Option(0.05, 1e-3, 1.0, "-", meaning="floor of P_s - sgn(v) P_L, share of P_s"),
    "frequency_window_s": Option(0.1, 1e-3, 10.0, "s", meaning="forgetting time of the target-frequency estimate"),
    "amplitude_floor_m": Option(1.0e-4, 1e-6, 0.1, "m", meaning="learning normalises by max(envelope, this)"),
    "c1_max": Option(1.5, 0.0, 10.0, "-", meaning="projection bound of |c_1| (relative velocity)"),
    "ck_max": Option(0.5, 0.0, 10.0, "-", meaning="projection bound of |c_k|, k >= 2"),
    "learned_bound_factor": Option(2.0, 1.0, 10.0, "-", meaning="c1_max and ck_max times this once the learning has "
                                   "run learned_bound_cycles at its frequency (1: never)"),
    "learned_bound_cycles": Option(2.0, 0.0, 100.0, "-", meaning="cycles learned before the bounds widen"),
    "c0_max_m_per_s": Option(0.02, 0.0, 1.0, "m/s", meaning="projection bound of the learned constant velocity"),
    "gain_window_s": Option(0.3, 1e-3, 100.0, "s", meaning="forgetting time of the flow-gain estimate"),
    "gain_min": Option(0.25, 1e-3, 1.0, "-", meaning="lower projection of the flow-gain ratio"),
    "gain_max": Option(6.0, 1.0, 100.0, "-", meaning="upper projection of the flow-gain ratio"),
    "gain_min_velocity_m_per_s": Option(0.005, 1e-6, 1.0, "m/s",
                                        meaning="the gain estimate moves only with this much RMS nominal velocity"),
    "steady_envelope_rate": Option(0.05, 1e-4, 1.0, "-", meaning="learning runs while the envelope is this steady"),
    "load_pressure_share": Option(1.0, 0.0, 1.0, "-", meaning="1: the valve inverse uses the measured P_L"),
    "dead_zone_adaptive": Option(1.0, 0.0, 1.0, "-", meaning="1: the dead zone is estimated with the flow gain"),
    "dead_zone_min_share": Option(0.5, 0.0, 1.0, "-", meaning="lower projection of the dead zone, share of nominal"),
    "dead_zone_max_share": Option(1.5, 1.0, 5.0, "-", meaning="upper projection of the dead zone, share of nominal"),
    "dead_zone_tolerance_v": Option(0.1, 0.0, 5.0, "V", meaning="the dead zone's projection widens by this on each "
                                    "side: a small declared dead zone is known to some tens of mV, not to 50 %"),
    # arbitrary (non-periodic) commands: the second-order lag of the valve and the oil column, fed forward
    "jerk_lead_s2": Option(0.0, 0.0, 1e-3, "s2", meaning="feed-forward of the target jerk (0: off, as on "
                           "sines, where the learning does it; time histories turn it on)"),
    "integral_per_s": Option(0.0, 0.0, 100.0, "1/s", meaning="integral action on the position error (0: off, as "
                             "on sines, where the learned constant does it; time histories turn it on)"),
    # small amplitudes, soft oil columns (docs/controller.md, "Robustness")
    "dead_zone_ramp_share": Option(0.05, 0.0, 1.0, "-", meaning="the dead-zone ramp shrinks to this share of the "
                                   "target's peak velocity (0: always dead_zone_ramp_v)"),
    "dead_zone_ramp_min_v": Option(1e-4, 1e-6, 2.0, "V", meaning="the narrowest dead-zone ramp"),
    "dead_zone_feedback_ramp_v": Option(2e-3, 0.0, 2.0, "V", meaning="the narrowest dead-zone ramp of the position "
                                        "feedback's correction (0: the feed-forward's)"),
    "dead_zone_edge_trim": Option(1.0, 0.0, 1.0, "-", meaning="1: on slow motions of a time history the integral "
                                  "trims the compensated dead zone too"),
    "null_offset_adaptive": Option(1.0, 0.0, 1.0, "-", meaning="1: the valve's null offset is estimated with the "
                                   "flow gain and the dead zone (0: the nominal driver_offset_v is kept)"),
    "null_offset_window_s": Option(3.0, 1e-3, 1000.0, "s", meaning="forgetting time of the null-offset estimate (a "
                                   "constant of the valve: longer than the gain's)"),
    "null_offset_min_velocity_m_per_s": Option(5e-4, 0.0, 1.0, "m/s", meaning="on a sine the learning is locked "
                                               "to, the offset is estimated once the valve model predicts this RMS "
                                               "velocity over its window (anywhere else: gain_min_velocity_m_per_s)"),
    "null_offset_min_target_velocity_m_per_s": Option(1e-3, 0.0, 1.0, "m/s", meaning="... and the sine's peak "
                                                      "velocity is at least this (below, a millivolt of estimation "
                                                      "error moves the table more than the target does)"),
    "null_offset_max_v": Option(0.2, 0.0, 5.0, "V", meaning="bound of the estimated valve null offset (0: not "
                                "estimated)"),
    "pressure_feedback_max_damping": Option(0.5, 0.0, 2.0, "-", meaning="the largest damping ratio the load-pressure "
                                            "feedback may add to the oil column; the design picks the one that damps "
                                            "the linearised loop of the declared rig best (0: no pressure feedback)"),
    "pressure_feedback_corner_share": Option(0.5, 0.01, 1.0, "-", meaning="high-pass corner of the pressure "
                                             "feedback, share of the oil-column frequency"),
    "pressure_feedback_small_share": Option(0.6, 0.0, 1.0, "-", meaning="on a periodic test whose peak target "
                                            "velocity is below half of pressure_feedback_full_velocity_m_per_s, this "
                                            "share of the load-pressure feedback (all of it from that velocity up, "
                                            "in between in proportion): on small motions the load pressure is mostly "
                                            "the guides' friction flipping at each reversal, which the feedback, a "
                                            "leak, would hold back"),
    "pressure_feedback_full_velocity_m_per_s": Option(0.01, 0.0, 10.0, "m/s", meaning="... see "
                                                      "pressure_feedback_small_share"),
    "pressure_feedback_min_improvement": Option(0.02, 0.0, 1.0, "-", meaning="the pressure feedback is used only "
                                                "where it raises the smallest damping ratio of the linearised loop "
                                                "by at least this much"),
    "compressibility_share": Option(0.0, 0.0, 1.0, "-", meaning="1: the valve estimate regresses the flow that "
                                    "compresses the oil, (V_0 / (2 beta)) P_L', with the table's (0, the default: the "
                                    "table's velocity alone, what the loop gain is about; measured better)"),
    # a still target gets a still valve (issue 32; docs/controller.md, "A still target, a still valve")
    # still_share (a ringing target too) off by default: it holds a hybrid test's small motions instead of following
    # them (J2 0.67 -> 1.54 %, and 1.02 -> 6.10 % for far_field_long x 0.6; docs/controller.md); a held target gets
    # it by default (still_hold_share)
    "still_share": Option(0.0, 0.0, 1.0, "-", meaning="1: where the target is still the dead zone's compensation "
                          "moves slowly and smoothly with the position error instead of switching with the "
                          "demand's sign (0: off, the switch everywhere)"),
    "still_hold_share": Option(1.0, 0.0, 1.0, "-", meaning="1: where the target is held (slower than "
                               "still_speed_m_per_s: a hold, a move's or a sine's end), this share of it, whatever "
                               "still_share says (a held target has no motion to follow)"),
    "still_centre_share": Option(1.0, 0.0, 1.0, "-", meaning="1: under a ringing target the dead zone's side "
                                 "follows the table's error from the centre of the target's swings (the table holds "
                                 "it), at the held target's faster rate for an error of many bands (0: the error "
                                 "itself, at still_command_rate_v_per_s)"),
    "still_swing_m": Option(5e-4, 0.0, 0.1, "m", meaning="a target that reverses within swings smaller than this "
                            "(wholly; not at all from 1.5 times it) ..."),
    "still_swing_speed_m_per_s": Option(5e-3, 0.0, 1.0, "m/s", meaning="... at a recent peak speed below this (wholly; "
                                        "not at all from twice it) is still: a building ringing down, not a wiggle "
                                        "in a shaking"),
    "still_speed_window_s": Option(0.25, 1e-3, 10.0, "s", meaning="the recent peak speed forgets with this time "
                                   "constant"),
    "still_speed_m_per_s": Option(2e-5, 0.0, 1.0, "m/s", meaning="... and so is a target slower than this (a hold, a "
                                  "move's last micrometres; not at all from twice it): about where the feed-forward's "
                                  "narrow dead-zone ramp lets go of its side ..."),
    "still_acceleration_s": Option(0.05, 0.0, 10.0, "s", meaning="... its speed taken with its acceleration times "
                                   "this: a sine's reversal (no speed, an acceleration) is no rest"),
    "still_command_rate_v_per_s": Option(0.5, 1e-3, 100.0, "V/s", meaning="where the target is still, the "
                                         "compensated share of the dead zone follows the error's side, moving the "
                                         "command by at most this (a ramp of 0.5 V/s: a std of 0.14 V over a "
                                         "second)"),
    "still_error_band_m": Option(3e-5, 1e-7, 0.01, "m", meaning="... towards the whole side of a position error "
                                 "beyond this; within it the share stays where it is, at most still_rest_share"),
    "still_rest_share": Option(0.2, 0.0, 1.0, "-", meaning="... so that the valve rests near the middle of its dead "
                               "zone (a share of the dead zone)"),
}
DEFAULTS = {name: spec.default for name, spec in OPTIONS.items()}
#: what the servo's design adds to its options in force (``loop_design``): not set by anyone, reported
DESIGNED = {
    "kp_in_force_per_s": Option(None, unit="1/s", meaning="the position loop gain the servo runs with: kp_per_s, "
                                "lowered where the rig's linearised loop would keep less than min_gain_margin"),
    "gain_margin": Option(None, unit="-", meaning="the factor on the valve's flow at which the rig's linearised loop "
                          "would lose stability, at that gain (50: at least)"),
    "pressure_feedback_small_share_in_force": Option(None, unit="-", meaning="the share of the load-pressure feedback "
                                                     "on small periodic motions: pressure_feedback_small_share, raised "
                                                     "where the loop would keep less gain margin with it"),
}
#: what a time history (no repeating cycle to learn) runs with: no harmonic learning; an integral on the position
#: error takes over the learned constant (the valve's null offset, the friction's asymmetry)
HISTORY_MODE = {"learning_gain": 0.0, "integral_per_s": 1.0}
#: what a rig commissioned by isorig (a trusted fit: its flow gain within 10 % at one sigma, the supply read each
#: period) runs with: the flow-gain estimate stays within 25 % of the commissioned gain. The 0.25-6 band is for a
#: rig file nobody measured; on a commissioned foreign rig whose guides stick or whose valve sits near its lap the
#: estimate ran to 6 (rig 52 at 2 mm: 3.8 -> 35 % of the amplitude in one cycle). docs/controller.md
COMMISSIONED_MODE = {"gain_min": 0.8, "gain_max": 1.25}
ADAPTED = (
    Adapted("model_m", "target r", "m", "the reference is the target itself: the feed-forward removes its lag"),
    Adapted("ar_hat", "flow gain ratio g", "-", "the valve's true flow gain over the nominal one (estimated)"),
    Adapted("ay_hat", "dead zone", "V", "the valve's dead zone (estimated)"),
    Adapted("as_hat", "learned frequency", "Hz", "the target frequency the learning is locked to (0: none)"),
)


def make_servo(rig=None, **options) -> Controller:
    """The learning servo controller; nominal rig values from ``rig`` (what the lab's rig file says; default
    sim.rig.DEFAULT_RIG) unless given as options."""
    o = check_options("servo", OPTIONS, options)
    for key, value in _nominal_rig(rig).items():
        if o[key] is None:
            o[key] = value
    params = np.zeros(N_PARAMS)
    params[P_AREA] = o["piston_area_m2"]
    params[P_KQ] = o["flow_gain_m3_per_s_v_sqrt_pa"]
    params[P_DZ] = o["dead_zone_v"]
    params[P_ULIM] = o["command_limit_v"]
    # the position loop's gain and the load-pressure feedback, designed on the declared rig (loop_design)
    design = loop_design(o)
    o["kp_in_force_per_s"] = design["kp_per_s"]
    o["gain_margin"] = design["gain_margin"]
    params[P_KP] = design["kp_per_s"]
    params[P_TAU_V] = o["velocity_lead_s"]
    params[P_TAU_L] = o["learning_lag_s"]
    params[P_GAMMA] = o["learning_gain"]
    params[P_NH] = o["harmonics"]
    params[P_FMAX] = o["learning_max_hz"]
    params[P_DZ_RAMP] = o["dead_zone_ramp_v"]
    params[P_DP_MIN] = o["min_pressure_drop_share"]
    params[P_TW] = o["frequency_window_s"]
    params[P_AFLOOR] = o["amplitude_floor_m"]
    params[P_C1MAX] = o["c1_max"]
    params[P_CKMAX] = o["ck_max"]
    params[P_C0MAX] = o["c0_max_m_per_s"]
    params[P_DZ_FRAC] = o["dead_zone_share"]
    params[P_GW] = o["gain_window_s"]
    params[P_GMIN] = o["gain_min"]
    params[P_GMAX] = o["gain_max"]
    params[P_GVMIN] = o["gain_min_velocity_m_per_s"]
    params[P_STEADY] = o["steady_envelope_rate"]
    params[P_PL_SHARE] = o["load_pressure_share"]
    params[P_DZ_ADAPT] = o["dead_zone_adaptive"]
    params[P_DZ_LO] = max(o["dead_zone_min_share"] * o["dead_zone_v"] - o["dead_zone_tolerance_v"], 0.0)
    params[P_DZ_HI] = o["dead_zone_max_share"] * o["dead_zone_v"] + o["dead_zone_tolerance_v"]
    params[P_JERK_LEAD] = o["jerk_lead_s2"]
    params[P_INTEGRAL] = o["integral_per_s"]
    params[P_RAMP_SHARE] = o["dead_zone_ramp_share"]
    params[P_RAMP_MIN] = min(o["dead_zone_ramp_min_v"], o["dead_zone_ramp_v"])
    # the feedback's ramp, the integral's pause inside it and the edge trim belong to the integral's mode (time
    # histories): on sines the learning removes what the narrow ramp leaves, and a sine test never rests
    params[P_FB_RAMP] = min(o["dead_zone_feedback_ramp_v"], o["dead_zone_ramp_v"]) if o["integral_per_s"] > 0 else 0.0
    params[P_EDGE_TRIM] = o["dead_zone_edge_trim"]
    params[P_OFFSET_MAX] = o["null_offset_max_v"]
    params[P_OFFSET_ADAPT] = o["null_offset_adaptive"]
    params[P_OW] = o["null_offset_window_s"]
    params[P_OVMIN] = o["null_offset_min_velocity_m_per_s"]
    params[P_OVT] = o["null_offset_min_target_velocity_m_per_s"]
    params[P_DP_REG] = o["orifice_regularisation_pa"]
    params[P_AREA_RATIO_B] = area_ratio_b(o["piston_area_m2"], o["piston_area_b_m2"])
    params[P_PLAY] = o["valve_play_v"]
    params[P_UNDERLAP] = o["underlap_v"]
    compliance = o["half_volume_m3"] / (2.0 * o["bulk_modulus_pa"])
    params[P_KPF] = design["gain_m_per_s_per_pa"]
    params[P_PF_WC] = design["corner_rad_s"]
    # on a small periodic motion a share of it (a time history's HISTORY_MODE keeps all of it)
    o["pressure_feedback_small_share_in_force"] = small_motion_share(o, design) if o["learning_gain"] > 0.0 else 1.0
    params[P_PF_SMALL] = o["pressure_feedback_small_share_in_force"]
    params[P_PF_FULL_V] = o["pressure_feedback_full_velocity_m_per_s"]
    params[P_LB_FACTOR] = o["learned_bound_factor"]
    params[P_LB_CYCLES] = o["learned_bound_cycles"]
    params[P_LAT] = o["position_latency_s"]
    params[P_COMPLIANCE] = o["compressibility_share"] * compliance / o["piston_area_m2"]
    params[P_WH] = oil_column_rad_s(o)
    params[P_ZH] = design["damping"]
    # harmonics close to the oil column are not learned: there the loop model is least sure
    params[P_FMAX] = min(o["learning_max_hz"], o["learning_max_oil_share"] * params[P_WH] / (2.0 * np.pi))
    # fast tests: more harmonics, up to and past the oil column, and the compression feed-forward
    params[P_NH_FAST] = max(o["fast_harmonics"], o["harmonics"])
    params[P_FMAX_FAST] = max(min(o["fast_learning_max_hz"], o["fast_learning_max_oil_share"] * params[P_WH]
                                  / (2.0 * np.pi)), params[P_FMAX])
    params[P_V_FAST] = o["fast_velocity_m_per_s"]
    params[P_ZC_MAX] = o["fast_max_valve_damping"]
    # the damping ratio a leak of k per pascal gives the column is k / (2 sqrt(C / m)) (pressure_feedback_design);
    # the valve's pressure-flow slope is a leak of |v| / (2 dp): at the target's peak velocity and dp = P_s,
    # V_env / (4 P_s sqrt(C / m))
    params[P_ZC_PER_V] = 1.0 / (4.0 * np.sqrt(compliance / o["mass_kg"]))
    # the compression feed-forward belongs to the learning of a periodic test (not a time history's HISTORY_MODE)
    params[P_COMP] = (o["compression_feedforward_share"] * compliance / o["piston_area_m2"]
                      if o["learning_gain"] > 0.0 else 0.0)
    params[P_CFMAX] = o["compression_max_hz"]
    params[P_CVMAX] = o["compression_max_velocity_m_per_s"]
    params[P_CGAIN] = o["compression_gain"]
    params[P_WV] = o["valve_natural_frequency_rad_s"]
    params[P_XV] = o["valve_damping_ratio"]
    params[P_STILL_SWING] = o["still_swing_m"]
    params[P_STILL_SPEED] = o["still_speed_m_per_s"]
    params[P_STILL_SPEED_T] = o["still_speed_window_s"]
    params[P_STILL_RATE] = o["still_command_rate_v_per_s"]
    params[P_STILL_BAND] = o["still_error_band_m"]
    params[P_STILL_SHARE] = o["still_share"]
    params[P_STILL_HOLD_SHARE] = o["still_hold_share"]
    params[P_STILL_CENTRE] = o["still_centre_share"]
    params[P_STILL_SWING_V] = o["still_swing_speed_m_per_s"]
    params[P_STILL_ACC_T] = o["still_acceleration_s"]
    params[P_STILL_REST] = o["still_rest_share"]
    state = np.zeros(N_STATE)
    state[S_SWING_LAST] = 1.0  # no swing seen yet (1 m, more than any stroke): a target that starts moving moves
    state[S_SWING_PREV] = -1.0  # ... and its first swing is one that grows
    state[S_GAIN] = 1.0
    state[S_DZ_HAT] = o["dead_zone_v"]
    # prior of the valve estimate: two pseudo-samples consistent with the nominal valve (g = 1, DZ = DZ_n),
    # a moving one (x = a, w = 0, velocity a) and one at the dead-zone edge (x = a, w = a / DZ_n, velocity 0);
    # it fades with the forgetting time, so the first samples cannot throw the estimate to its bounds
    a = o["gain_min_velocity_m_per_s"]
    b = a / max(o["dead_zone_v"], 1e-3)
    state[S_GXX] = a * a + (o["dead_zone_v"] * b) ** 2
    state[S_GXW] = o["dead_zone_v"] * b * b
    state[S_GWW] = b * b
    state[S_GXY] = a * a
    state[S_GWY] = 0.0
    state[S_GZZ] = b * b  # a third one at rest (x = w = 0, z = b, velocity 0): the nominal null offset
    state[S_OFFSET] = min(max(o["driver_offset_v"], -o["null_offset_max_v"]), o["null_offset_max_v"])
    state[S_GZY] = b * b * state[S_OFFSET]
    long = (state[S_GXX], state[S_GXW], state[S_GWW], 0.0, 0.0, state[S_GZZ], state[S_GXY], state[S_GWY], state[S_GZY])
    state[S_LONG:S_LONG + 9] = long
    return Controller("servo", KIND, params, state, o)


def oil_column_rad_s(o: dict) -> float:
    """Natural frequency of the oil column on the nominal rig, rad/s: sqrt(2 beta A_p^2 / (V_0 m)) (the first two lines
    of eq. 3 without friction, isolator and valve flow slope)."""
    return float(np.sqrt(2.0 * o["bulk_modulus_pa"] * o["piston_area_m2"] ** 2 / (o["half_volume_m3"] * o["mass_kg"])))


def _pade(delay_s: float) -> tuple[np.ndarray, np.ndarray]:
    """First-order Pade approximation of exp(-s delay): (numerator, denominator), coefficients highest power first."""
    return np.array([-0.5 * delay_s, 1.0]), np.array([0.5 * delay_s, 1.0])


def _product(*polynomials) -> np.ndarray:
    """The product of polynomials (coefficient arrays, highest power first)."""
    out = np.ones(1)
    for p in polynomials:
        out = np.convolve(out, p)
    return out


def linearised_poles(o: dict, damping: float, compliance_scale: float = 1.0, flow_scale: float = 1.0) -> np.ndarray:
    """Closed-loop poles of the servo's loop on the declared rig, eq. (3) linearised: the valve (second order, flow per
    velocity demand 1 after the inverse) with the sampling delay, the oil column (compliance V_0 / (2 beta)) on
    the mass m (isolator and friction left out: the worst case for damping), the position loop K_p on the reading
    (late by the declared latency) and the load-pressure feedback k_pf s / (s + w_c) P_L for the added damping
    ratio ``damping``. The natural damping of the valve's pressure-flow slope is left out too: the inverse with the
    measured P_L cancels it. ``compliance_scale``: the plant's oil compliance over the declared one (the feedback
    stays designed on the declared rig); ``flow_scale``: the valve's flow per volt over what the servo takes it for
    (the loop's gain, both feedbacks alike: ``gain_margin``)."""
    area, mass = o["piston_area_m2"], o["mass_kg"]
    compliance = o["half_volume_m3"] / (2.0 * o["bulk_modulus_pa"])
    wv, xv = o["valve_natural_frequency_rad_s"], o["valve_damping_ratio"]
    s = np.array([1.0, 0.0])
    valve_n, valve_d = np.array([flow_scale * wv * wv]), np.array([1.0, 2.0 * xv * wv, wv * wv])
    dn, dd = _pade(SAMPLING_DELAY_S)
    ln, ld = _pade(o["position_latency_s"])
    kpf = 2.0 * damping * float(np.sqrt(compliance / mass))  # designed on the declared column
    compliance *= compliance_scale  # the plant's column: softer than declared for a scale above 1
    wc = o["pressure_feedback_corner_share"] * oil_column_rad_s(o)
    hn, hd = np.array([1.0, 0.0]), np.array([1.0, wc])
    # q = V D (-K_p L y - k_pf H P),  C s P = A (q - s y),  m s^2 y = A P
    g_n, g_d = _product(valve_n, dn), _product(valve_d, dd)
    mass_p = np.array([mass, 0.0, 0.0])
    feedback = np.polyadd(o["kp_per_s"] * area * _product(ln, hd), kpf * _product(hn, ld, mass_p))
    char = np.polyadd(compliance * _product(s, g_d, hd, ld, mass_p),
                      area * np.polyadd(_product(g_n, feedback), area * _product(s, g_d, hd, ld)))
    return np.roots(char)


def smallest_damping_ratio(poles: np.ndarray) -> float:
    """The smallest damping ratio -Re/|p| among the poles (negative: unstable)."""
    mag = np.abs(poles)
    mag[mag == 0.0] = 1.0
    return float(np.min(-poles.real / mag))


#: the plant's oil compliance (V_0 / beta, or m for the column's frequency) over the declared one that the design
#: must damp: the declared rig, and one whose column is 1/sqrt(1.5) = 0.82 times as fast
COMPLIANCE_SCALES = (1.0, 1.5)
#: the high-pass corners the pressure-feedback design tries, shares of pressure_feedback_corner_share
CORNER_STEPS = (1.0, 0.7)
#: what the pressure-feedback design reads of the options
DESIGN_KEYS = ("piston_area_m2", "mass_kg", "half_volume_m3", "bulk_modulus_pa", "valve_natural_frequency_rad_s",
               "valve_damping_ratio", "position_latency_s", "kp_per_s", "pressure_feedback_max_damping",
               "pressure_feedback_corner_share", "pressure_feedback_min_improvement")


def pressure_feedback_design(o: dict) -> dict:
    """The load-pressure feedback for the declared rig.

    A leak of A k_pf per pascal adds the damping ratio xi to an oil column of compliance C = V_0 / (2 beta) on the
    mass m: k_pf = 2 xi sqrt(C / m) (m/s of velocity demand per Pa; from the second and first lines of eq. 3),
    high-passed at a share of the column's frequency w_h = sqrt(2 beta A^2 / (V_0 m)) so that the test's own
    frequencies pass. Through the valve the leak lags: where the column lies near or above the valve's frequency
    (the paper's rig: 55 Hz against 40 Hz) it would remove damping. So xi is picked from 0 to
    pressure_feedback_max_damping (11 steps), and the corner from pressure_feedback_corner_share times CORNER_STEPS
    of the column's frequency, as the pair whose linearised loop has the largest smallest damping
    ratio (``linearised_poles``) over the declared column and one 1.5 times as compliant (``COMPLIANCE_SCALES``: a
    lab's V_0 with hoses, beta with air and m are rough), and kept only if it adds at least
    pressure_feedback_min_improvement to it: the
    linearised loop leaves out the valve's pressure-flow slope, friction and the isolator, so a smaller gain is
    within its error and not worth the feedback's transients. 0 wins on a stiff column."""
    return dict(_design(tuple(float(o[k]) for k in DESIGN_KEYS)))


@lru_cache(maxsize=256)
def _design(values: tuple) -> tuple:
    """``pressure_feedback_design`` on the DESIGN_KEYS values (cached: a grid builds thousands of controllers on a
    handful of rigs, and the design costs milliseconds)."""
    o = dict(zip(DESIGN_KEYS, values, strict=True))
    wh = oil_column_rad_s(o)
    xi_max = o["pressure_feedback_max_damping"]
    scales = COMPLIANCE_SCALES

    def worst(xi: float, corner: float) -> float:  # the smallest damping ratio over the plants the rig may be
        oc = dict(o, pressure_feedback_corner_share=corner)
        return min(smallest_damping_ratio(linearised_poles(oc, xi, c)) for c in scales)

    top = o["pressure_feedback_corner_share"]
    without = worst(0.0, top)
    best = (without, 0.0, top)
    if xi_max > 0.0:
        for corner in (step * top for step in CORNER_STEPS):
            for xi in np.linspace(0.0, xi_max, 11)[1:]:
                zeta = worst(float(xi), corner)
                if zeta > best[0]:
                    best = (zeta, float(xi), corner)
    if best[0] < without + o["pressure_feedback_min_improvement"]:
        best = (without, 0.0, top)
    compliance = o["half_volume_m3"] / (2.0 * o["bulk_modulus_pa"])
    return (("oil_column_hz", wh / (2.0 * np.pi)), ("damping", best[1]),
            ("gain_m_per_s_per_pa", 2.0 * best[1] * float(np.sqrt(compliance / o["mass_kg"]))),
            ("corner_rad_s", best[2] * wh), ("corner_share", best[2]),
            ("loop_damping_without", without), ("loop_damping", best[0]))


#: the valve flow's factor up to which ``gain_margin`` looks for the loop's edge of stability
GAIN_MARGIN_SEARCH_MAX = 50.0
#: each step of ``loop_design`` lowers K_p by this factor
DETUNE_STEP = 0.9
#: below this gain margin at its best K_p the servo refuses a rig (``loop_design``)
MIN_GAIN_MARGIN_TO_RUN = 1.5
#: what ``loop_design`` reads of the options
LOOP_KEYS = DESIGN_KEYS + ("min_gain_margin", "min_kp_share")


class LoopMarginError(ControllerOptionError):
    """A rig on which the servo's loop, at its best gain down to ``min_kp_share`` of kp_per_s, keeps a gain margin
    below MIN_GAIN_MARGIN_TO_RUN (``loop_design``)."""


def _stable(o: dict, design: dict, flow_scale: float) -> bool:
    """Whether the linearised loop (``linearised_poles``: K_p and the pressure feedback of ``design``) is stable
    with the valve's flow ``flow_scale`` times the estimate, on the declared column and one 1.5 times as compliant
    (COMPLIANCE_SCALES)."""
    oc = dict(o, pressure_feedback_corner_share=design["corner_share"])
    return min(smallest_damping_ratio(linearised_poles(oc, design["damping"], c, flow_scale))
               for c in COMPLIANCE_SCALES) > 0.0


#: the steps by which ``small_motion_share`` raises the pressure feedback's share on small motions
SMALL_SHARE_STEP = 0.1


def small_motion_share(o: dict, design: dict) -> float:
    """The share of the load-pressure feedback on small periodic motions (``_pressure_feedback_velocity``):
    pressure_feedback_small_share, raised by SMALL_SHARE_STEP until the linearised loop at the gain in force keeps the
    gain margin the design keeps with all of it (at most min_gain_margin); 1 where no smaller share does. A loop on a
    rig as told that needs its whole pressure feedback keeps it on small motions too."""
    share = o["pressure_feedback_small_share"]
    if share >= 1.0 or design["damping"] <= 0.0:
        return 1.0
    needed = max(min(o["min_gain_margin"], design["gain_margin"]), 1.0)
    oc = dict(o, kp_per_s=design["kp_per_s"])
    while share < 1.0 - 1e-9:
        weaker = dict(design, damping=design["damping"] * share)
        if _stable(oc, weaker, 1.0) and _stable(oc, weaker, needed):
            return float(round(share, 6))
        share += SMALL_SHARE_STEP
    return 1.0


def gain_margin(o: dict, design: dict) -> float:
    """The factor on the valve's flow at which the linearised loop loses stability (``_stable``): 0 if it is
    unstable as declared, GAIN_MARGIN_SEARCH_MAX if it holds up to that. A rig's flow per volt varies with the
    supply's sag, the lands and the load pressure about what the servo's estimate says, and a latency or a column
    softer than told takes phase the same way: the margin is the room for all of them (docs/controller.md,
    "Stability argument" 5)."""
    if not _stable(o, design, 1.0):
        return 0.0
    lo, hi = 1.0, GAIN_MARGIN_SEARCH_MAX
    if _stable(o, design, hi):
        return hi
    for _ in range(16):  # bisection in log: the edge to within 1.3 %
        mid = math.sqrt(lo * hi)
        lo, hi = (mid, hi) if _stable(o, design, mid) else (lo, mid)
    return lo


def loop_design(o: dict) -> dict:
    """The position loop gain the servo runs with on the declared rig: kp_per_s, lowered by DETUNE_STEP (with the
    pressure feedback designed again for each) until the loop keeps ``min_gain_margin`` (``gain_margin``), down to
    ``min_kp_share`` of it; where no gain reaches the margin, the one with the largest. A rig whose best margin is
    below MIN_GAIN_MARGIN_TO_RUN raises LoopMarginError: the servo cannot follow it safely as told. Measured on 41
    commissioned foreign rigs (docs/controller.md, "Stability argument" 5): at K_p = 30 /s rigs 38, 52, 147 and 204
    (margins 1.2-1.7) oscillated; rig 204 (oil column 13 Hz, latency 1.8 ms) runs at a margin of 2."""
    return dict(_loop_design(tuple(float(o[k]) for k in LOOP_KEYS)))


@lru_cache(maxsize=256)
def _loop_design(values: tuple) -> tuple:
    o = dict(zip(LOOP_KEYS, values, strict=True))
    asked, needed = o["kp_per_s"], o["min_gain_margin"]
    if not needed > 0.0:  # K_p as given, unchecked
        design = pressure_feedback_design(o)
        return (("kp_per_s", asked), ("gain_margin", gain_margin(o, design)), ("detuned", False), *design.items())
    kp, best = asked, None
    while True:
        oc = dict(o, kp_per_s=kp)
        design = pressure_feedback_design(oc)
        if _stable(oc, design, 1.0) and _stable(oc, design, max(needed, 1.0)):
            return (("kp_per_s", kp), ("gain_margin", gain_margin(oc, design)), ("detuned", kp < asked),
                    *design.items())
        margin = gain_margin(oc, design)
        if best is None or margin > best[0]:
            best = (margin, kp, design)
        if kp * DETUNE_STEP < o["min_kp_share"] * asked:
            break
        kp *= DETUNE_STEP
    margin, kp, design = best
    if margin < MIN_GAIN_MARGIN_TO_RUN:
        raise LoopMarginError(
            "controller_options.kp_per_s", asked, f"a loop with a gain margin of at least {MIN_GAIN_MARGIN_TO_RUN:g}",
            f"the servo's position loop cannot be made stable enough on this rig as told: its best gain margin, at "
            f"kp_per_s = {kp:.3g} 1/s ({100 * kp / asked:.0f} % of {asked:g}), is {margin:.2f} (at least "
            f"{MIN_GAIN_MARGIN_TO_RUN:g} is needed; the linearised loop with the oil column at "
            f"{design['oil_column_hz']:.1f} Hz, the valve at {o['valve_natural_frequency_rad_s'] / (2 * math.pi):.0f} "
            f"Hz and a position latency of {1e3 * o['position_latency_s']:.2f} ms). Lower kp_per_s, check the rig "
            "file (commission the rig again: isorig identify rig), or run another controller")
    return (("kp_per_s", kp), ("gain_margin", margin), ("detuned", kp < asked), *design.items())


@njit(cache=True, error_model="numpy")
def orifice_root(dp, dp_reg):
    """The orifice law's sqrt(dp), linear below the regularisation drop dp_reg as in the rig model (sim.rig:
    dp / sqrt(dp_reg) there; dp_reg = 0: the plain square root)."""
    if dp >= dp_reg:
        return np.sqrt(dp)
    return dp / np.sqrt(dp_reg)


@njit(cache=True, error_model="numpy")
def valve_inverse(v, p_load, p_supply, area, kq, dz, dz_ramp, dp_min_share, dp_reg=0.0, area_ratio_b=1.0):
    """Command u that makes the nominal valve pass the flow area * v: inverse of eq. (3) with the dead zone."""
    u_lin, ramp = valve_inverse_ramp(v, p_load, p_supply, area, kq, dz_ramp, dp_min_share, dp_reg, 0.0, 0.0,
                                     area_ratio_b)
    return u_lin + dz * ramp


@njit(cache=True, error_model="numpy")
def valve_inverse_ramp(v, p_load, p_supply, area, kq, dz_ramp, dp_min_share, dp_reg, v_fb, fb_ramp,
                       area_ratio_b=1.0):
    """The two parts of ``valve_inverse``: the command u_l of the valve without dead zone, and the share (-1..1)
    of the dead zone added to it (the ramp; -1 or 1: the whole dead zone, the valve opens). Where ``fb_ramp`` is
    wider than ``dz_ramp``, the part ``v_fb`` of ``v`` (the position feedback's correction) ramps in over
    ``fb_ramp``, the rest over ``dz_ramp``. ``area_ratio_b``: A_B / A_A, the supply's share towards -y of a
    single-rod actuator's valve law (sim.rig's docstring)."""
    sgn = 1.0 if v >= 0.0 else -1.0
    dp = supply_share(sgn, area_ratio_b) * p_supply - sgn * p_load
    dp_min = dp_min_share * p_supply
    if dp < dp_min:
        dp = dp_min
    flow_per_volt = kq * orifice_root(dp, dp_reg)
    u_lin = area * v / flow_per_volt
    if fb_ramp > dz_ramp:
        u_fb = area * v_fb / flow_per_volt
        ramp = (u_lin - u_fb) / dz_ramp + u_fb / fb_ramp
    else:
        ramp = u_lin / dz_ramp
    if ramp > 1.0:
        ramp = 1.0
    elif ramp < -1.0:
        ramp = -1.0
    return u_lin, ramp


@njit(cache=True, error_model="numpy")
def _delayed(s, base, head, lag):
    """The value ``lag`` periods (fractional) before the newest one of a ring of DELAY_LINE in s[base:]."""
    whole = int(lag)
    frac = lag - whole
    a = s[base + (head - whole) % DELAY_LINE]
    if frac <= 0.0:
        return a
    return (1.0 - frac) * a + frac * s[base + (head - whole - 1) % DELAY_LINE]


@njit(cache=True, error_model="numpy")
def _solve3(m11, m12, m13, m22, m23, m33, b1, b2, b3):
    """Solution of the symmetric 3x3 system M t = b (Cramer's rule) and det(M)."""
    c11 = m22 * m33 - m23 * m23
    c12 = m13 * m23 - m12 * m33
    c13 = m12 * m23 - m13 * m22
    det = m11 * c11 + m12 * c12 + m13 * c13
    if det == 0.0:
        return 0.0, 0.0, 0.0, 0.0
    c22 = m11 * m33 - m13 * m13
    c23 = m12 * m13 - m11 * m23
    c33 = m11 * m22 - m12 * m12
    t1 = (c11 * b1 + c12 * b2 + c13 * b3) / det
    t2 = (c12 * b1 + c22 * b2 + c23 * b3) / det
    t3 = (c13 * b1 + c23 * b2 + c33 * b3) / det
    return t1, t2, t3, det


@njit(cache=True, error_model="numpy")
def compression_feedforward(p, s, theta, omega, kp, p_meas, steady, dt):
    """The oil's compression flow (V_0 / (2 beta)) P_L' (eq. 3, second line) that the test's periodic load pressure
    needs, as a velocity demand (m/s): (V_0 / (2 beta A)) Re sum_k sigma_k j k w P_k exp(j k theta) / V(j k w) over
    the harmonics k w from K_p to compression_max_hz, P_k the load pressure's harmonics over the last cycles, V the
    declared valve (w_v^2 exp(-j k w D) / (w_v^2 - (k w)^2 + 2 j xi_v w_v k w), D the sampling delay: the flow arrives
    when the pressure must change), sigma_k Lanczos factors (no Gibbs ringing at the reversals' pressure steps).
    Also sums this period's load pressure into the running cycle's harmonics; at the cycle's end (theta wraps), if the
    cycle was steady throughout, P_k moves by compression_gain towards them."""
    nc = min(int(p[P_CFMAX] * 2.0 * np.pi / omega), MAX_HARMONICS)
    c1 = np.cos(theta)
    s1 = np.sin(theta)
    if s[S_THETA_PREV] > 0.5 * np.pi and theta < -0.5 * np.pi:
        if s[S_PCYC] > 0.5:
            for i in range(2 * MAX_HARMONICS):
                s[S_P + i] += p[P_CGAIN] * (s[S_PACC + i] - s[S_P + i])
        for i in range(2 * MAX_HARMONICS):
            s[S_PACC + i] = 0.0
        s[S_PCYC] = 1.0
    if not steady:
        s[S_PCYC] = 0.0
    s[S_THETA_PREV] = theta
    wv = p[P_WV]
    step = p_meas * omega * dt / np.pi
    ck, sk = c1, s1
    acc = 0.0
    for k in range(nc):
        s[S_PACC + 2 * k] += step * ck
        s[S_PACC + 2 * k + 1] -= step * sk
        kw = (k + 1) * omega
        if kw >= kp:
            # j k w P_k / V(j k w)
            vr = 1.0 - (kw / wv) ** 2
            vi = 2.0 * p[P_XV] * kw / wv
            cd = np.cos(kw * SAMPLING_DELAY_S)
            sd = np.sin(kw * SAMPLING_DELAY_S)
            vr, vi = vr * cd - vi * sd, vr * sd + vi * cd
            fr = -kw * s[S_P + 2 * k + 1]
            fi = kw * s[S_P + 2 * k]
            x = np.pi * (k + 1) / (nc + 1)
            acc += np.sin(x) / x * ((fr * vr - fi * vi) * ck - (fr * vi + fi * vr) * sk)
        ck, sk = ck * c1 - sk * s1, sk * c1 + ck * s1
    return p[P_COMP] * acc


@njit(cache=True, error_model="numpy")
def _smoothstep(x):
    """0 below 0, 1 above 1, 3 x^2 - 2 x^3 between (continuous, with a continuous slope)."""
    if x <= 0.0:
        return 0.0
    if x >= 1.0:
        return 1.0
    return x * x * (3.0 - 2.0 * x)


@njit(cache=True, error_model="numpy")
def target_stillness(p, s, r, rd, rdd, dt):
    """How still the target is, 0 (it moves) to 1 (still): it reverses within swings below still_swing_m at a
    recent peak speed below still_swing_speed_m_per_s, not growing (a building ringing down, a sine's last taper;
    not its first, nor a ground motion's start), or it is slower than still_speed_m_per_s, its acceleration times
    still_acceleration_s included (a hold, a move's end); smooth up to 1.5 times the swing, twice the speeds. A
    swing is the travel between reversals (the largest of the last two and the running one counts), a reversal a
    move back by 2 % of still_swing_m."""
    eps = 0.02 * p[P_STILL_SWING]
    direction = s[S_SWING_DIR]
    if direction == 0.0:
        if abs(r - s[S_SWING_FROM]) > eps:
            s[S_SWING_DIR] = 1.0 if r > s[S_SWING_FROM] else -1.0
            s[S_SWING_EXT] = r
    elif (r - s[S_SWING_EXT]) * direction > 0.0:
        s[S_SWING_EXT] = r
    elif (s[S_SWING_EXT] - r) * direction > eps:
        # the centre of a ringing target: the midpoints of a decaying ring's swings alternate about it, and the mean of
        # two in a row cancels most of that
        mid = 0.5 * (s[S_SWING_EXT] + s[S_SWING_FROM])
        s[S_CENTRE] = 0.5 * (mid + s[S_MID_LAST])
        s[S_MID_LAST] = mid
        s[S_SWING_PREV] = s[S_SWING_LAST] if s[S_SWING_PREV] >= 0.0 else 0.0  # (the first: one that grows)
        s[S_SWING_LAST] = abs(s[S_SWING_EXT] - s[S_SWING_FROM])
        s[S_SWING_MAX] = max(s[S_SWING_MAX], s[S_SWING_LAST])
        s[S_SWING_FROM] = s[S_SWING_EXT]
        s[S_SWING_EXT] = r
        s[S_SWING_DIR] = -direction
    travel = abs(s[S_SWING_EXT] - s[S_SWING_FROM])
    swing = max(s[S_SWING_LAST], s[S_SWING_PREV], travel)  # the last two and this one: one small swing is no rest
    s[S_SPEED_REC] = max(abs(rd), s[S_SPEED_REC] * np.exp(-dt / p[P_STILL_SPEED_T]))
    still = 0.0  # the ringing's stillness (still_share) ...
    if p[P_STILL_SWING] > 0.0 and p[P_STILL_SWING_V] > 0.0:
        # not while swings of some size grow before any has been large (a sine's taper-in, a ground motion's start;
        # a ringing that beats is still): from 1.2 times the one before (this one so far, or the last), from a
        # quarter of still_swing_m, until a swing has passed 1.5 times it
        growth = travel / s[S_SWING_LAST] if travel > s[S_SWING_LAST] else s[S_SWING_LAST] / max(s[S_SWING_PREV], 1e-12)
        growing = (_smoothstep((growth - 1.2) / 0.3) * _smoothstep(4.0 * swing / p[P_STILL_SWING] - 1.0)
                   * (1.0 - _smoothstep(2.0 * (s[S_SWING_MAX] / p[P_STILL_SWING] - 1.0))))
        still = ((1.0 - _smoothstep(2.0 * (swing / p[P_STILL_SWING] - 1.0)))
                 * (1.0 - _smoothstep(s[S_SPEED_REC] / p[P_STILL_SWING_V] - 1.0)) * (1.0 - growing))
    held = 0.0  # ... and the hold's (still_share, and at least still_hold_share)
    if p[P_STILL_SPEED] > 0.0:
        held = 1.0 - _smoothstep((abs(rd) + p[P_STILL_ACC_T] * abs(rdd)) / p[P_STILL_SPEED] - 1.0)
    s[S_HELD] = p[P_STILL_HOLD_SHARE] * held
    s[S_RING] = p[P_STILL_SHARE] * still * (1.0 - held)
    return max(p[P_STILL_SHARE] * max(still, held), p[P_STILL_HOLD_SHARE] * held)


@njit(cache=True, error_model="numpy")
def still_dead_zone_share(p, s, ramp_at, still, e, dz_c, dt):
    """The dead zone's compensated share (-1..1): the demand's side (``ramp_at``, the switch of the dead-zone
    inverse) where the target moves; where it is still (``still``, target_stillness) the whole side of a position
    error beyond still_error_band_m, within it where it is (at most still_rest_share), reached moving the
    command by at most still_command_rate_v_per_s (divided by ``still``^4; in between, the demand's side if
    ``still`` < 1/2). Under a ringing target ``e`` is the table's error from the centre of the swings
    (still_centre_share; servo_step), so the table holds that centre, not where the stillness caught it.
    A relay in a loop with a lag (the valve, friction, the oil's give) has a limit cycle at any loop gain: its
    describing function 4 DZ / (pi a) grows without bound as the amplitude a falls. Rate-limited, the share cannot
    cross the dead zone (2 DZ) within a swing of a ringing target: the valve stays closed or on one side, the table
    holds the middle of the swings, and at rest the valve closes, the table within the band, the command still."""
    share = ramp_at
    if still > 0.0:
        # mostly still: the error's side; the rate limit falls from none (moving) to still_command_rate_v_per_s (as
        # still^-4: 16 times it at still 1/2), so that the share is continuous and never a blend of two sides (half a
        # dead zone compensated is a dead band)
        goal = ramp_at
        if still >= 0.5:  # the error's side beyond the band; within it where it is, near the dead zone's middle
            rest = p[P_STILL_REST]
            goal = min(max(s[S_SIDE], -rest), rest) if abs(e) <= p[P_STILL_BAND] else (1.0 if e > 0.0 else -1.0)
        # a held target (still_hold_share) with an error of many bands (a braked target's rest, a table left short)
        # crosses the dead zone sooner: the rate grows as the square of the error in bands, up to
        # STILL_FAST_RATE_SHARE times; under a ringing target so does the error from the swings' centre
        # (still_centre_share; the error from the target itself would make that a relay again: it swings)
        fast_share = max(s[S_HELD], p[P_STILL_CENTRE] * s[S_RING])
        fast = 1.0 + (min(max((abs(e) / p[P_STILL_BAND]) ** 2, 1.0), STILL_FAST_RATE_SHARE) - 1.0) * fast_share
        step = dt * p[P_STILL_RATE] * fast / (still ** 4 * max(dz_c, 1e-3))
        share = s[S_SIDE] + min(max(goal - s[S_SIDE], -step), step)
    s[S_SIDE] = share
    return share


# servo_step's stages, in the order it calls them. Each is inlined into servo_step by numba (inline="always": the
# compiled loop is the one the single function gave, bit for bit); s is the state, p the parameters.
stage = njit(cache=True, error_model="numpy", inline="always")


@stage
def _start(s, r, rd, y, p_meas):
    """First period: the differences, the delay lines (regressors NaN: no sample yet) and the swings start here."""
    if s[S_STARTED] < 0.5:
        s[S_RD1] = rd
        s[S_RD2] = rd
        s[S_YPREV] = y
        s[S_PL_PREV] = p_meas
        for i in range(3 * DELAY_LINE):
            s[S_LINE_X + i] = np.nan
        for i in range(DELAY_LINE):
            s[S_LINE_R + i] = r
        s[S_SWING_FROM] = r
        s[S_SWING_EXT] = r
        s[S_CENTRE] = r
        s[S_MID_LAST] = r
        s[S_STARTED] = 1.0


@stage
def _target_differences(s, rd, dt):
    """Target acceleration and jerk from r': (r'_n-1, (r'_n - r'_n-1) / dt, (r'_n - 2 r'_n-1 + r'_n-2) / dt^2)."""
    rd1 = s[S_RD1]
    rd2 = s[S_RD2]
    rdd = (rd - rd1) / dt
    rddd = (rd - 2.0 * rd1 + rd2) / (dt * dt)
    s[S_RD2] = rd1
    s[S_RD1] = rd
    return rd1, rdd, rddd


@stage
def _frequency_estimate(p, s, rd1, rddd, dt):
    """The target's frequency: w^2 = -r''' r' / r'^2 for a sine, numerator and denominator averaged with forgetting."""
    forget = dt / p[P_TW]
    s[S_NUM] += forget * (-rddd * rd1 - s[S_NUM])
    s[S_DEN] += forget * (rd1 * rd1 - s[S_DEN])
    omega_est = 0.0
    if s[S_DEN] > 1e-30 and s[S_NUM] > 0.0:
        omega_est = np.sqrt(s[S_NUM] / s[S_DEN])
    return omega_est


@stage
def _steady_envelope(p, s, rd_mid, rdd, omega_est, dt):
    """V_est = sqrt(r'^2 + (r'' / w_est)^2), steady (relative rate below steady_envelope_rate per radian) for a quarter
    of a period: (steady, V_est). The learning runs only then (not in a taper, not at a block change)."""
    # the velocity amplitude seen with the current frequency estimate (constant on a steady sine; with the
    # frequency learned before, a new block's sine would never look steady)
    v_est = 0.0
    if omega_est > 0.0:
        v_est = np.sqrt(rd_mid * rd_mid + (rdd / omega_est) ** 2)
    if omega_est > 2.0 * np.pi * 1e-3 and v_est > 0.0 and (
            abs(v_est - s[S_VENV]) < p[P_STEADY] * omega_est * v_est * dt):
        s[S_STEADY_S] += dt
    else:
        s[S_STEADY_S] = 0.0
    steady = omega_est > 0.0 and s[S_STEADY_S] > 0.5 * np.pi / omega_est
    s[S_VENV] = v_est
    return steady, v_est


@stage
def _learned_frequency(s, steady, omega_est, dt):
    """The frequency w the learning is locked to: locks on to w_est, refines over a quarter period, and a steady sine
    more than 5 % away for a whole period clears what was learned: (steady, w)."""
    w_l = s[S_OMEGA_LEARNED]
    if steady and w_l > 0.0 and abs(omega_est - w_l) > 0.05 * w_l:
        # a new frequency only once it has been seen on a steady sine for a whole period: the start of a
        # taper-out looks steady for a while, with a frequency estimate bent by the fading envelope
        s[S_NEW_FREQ_S] += dt
        steady = s[S_NEW_FREQ_S] > 2.0 * np.pi / omega_est
        if steady:  # what was learned at the old frequency does not apply
            for i in range(2 * MAX_HARMONICS):
                s[S_C + i] = 0.0
                s[S_P + i] = 0.0
                s[S_PACC + i] = 0.0
            s[S_PCYC] = 0.0
            s[S_LEARNED_S] = 0.0
            w_l = 0.0
    else:
        s[S_NEW_FREQ_S] = 0.0
    if steady:
        if w_l <= 0.0:  # lock on
            s[S_OMEGA_LEARNED] = omega_est
        else:  # refine, over a quarter period: a short bend of the estimate (a taper's start) barely moves it
            s[S_OMEGA_LEARNED] = w_l + min(1.0, dt * omega_est / (0.5 * np.pi)) * (omega_est - w_l)
            s[S_LEARNED_S] += dt
    return steady, s[S_OMEGA_LEARNED]


@stage
def _harmonic_band(p, omega, rd_mid, rdd, p_supply):
    """V_env = sqrt(r'^2 + (r'' / w)^2), the harmonics H learned (up to learning_max_hz), and how fast the test is
    (0..1: V_env from fast_velocity_m_per_s, valve-slope damping V_env / (4 P_s sqrt(C / m)) below
    fast_max_valve_damping) with its band H_fast: (V_env, H, fast, H_fast)."""
    nh = int(p[P_NH])
    v_env = 0.0
    if omega > 0.0:
        v_env = np.sqrt(rd_mid * rd_mid + (rdd / omega) ** 2)
        nmax = int(p[P_FMAX] * 2.0 * np.pi / omega)
        if nmax < nh:
            nh = nmax
    # a fast test (fast: 0..1) learns more harmonics (nh_fast) and feeds the oil's compression flow forward: where
    # the target's peak velocity passes the dead zone's narrow inverse mid-stroke, and while the valve's
    # pressure-flow slope at that velocity (cancelled by the inverse a valve lag late) is small
    fast = 0.0
    nh_fast = nh
    if omega > 0.0:
        fast = 1.0
        if p[P_V_FAST] > 0.0:
            fast = min(max(2.0 * v_env / p[P_V_FAST] - 1.0, 0.0), 1.0)
        if p[P_ZC_MAX] > 0.0:
            zeta_c = v_env * p[P_ZC_PER_V] / max(p_supply, 1.0)
            fast *= min(max(2.0 - zeta_c / p[P_ZC_MAX], 0.0), 1.0)
        else:
            fast = 0.0
        if fast > 0.0:
            nh_fast = max(min(int(p[P_NH_FAST]), int(p[P_FMAX_FAST] * 2.0 * np.pi / omega)), nh)
    return v_env, nh, fast, nh_fast


@stage
def _delayed_regressors(p, s, dt):
    """The valve estimate's regressors (x, w, z) of the command sent tau_l + L earlier (L: the reading's latency)."""
    # the position reading is late by the declared latency L: the table's velocity and the error it shows are
    # those of L ago, so the valve estimate and the learning look L further back
    lag = int(round((p[P_TAU_L] + p[P_LAT]) / dt))
    if lag > DELAY_LINE - 1:
        lag = DELAY_LINE - 1
    if lag < 1:
        lag = 1
    old = (int(s[S_HEAD]) - lag) % DELAY_LINE
    return s[S_LINE_X + old], s[S_LINE_W + old], s[S_LINE_Z + old]


@stage
def _valve_flow_velocity(p, s, y, p_meas, dt):
    """The flow the valve passed, as a velocity: y' + (V_0 / (2 beta A_n)) P_L' (eq. 3 second line;
    compressibility_share, 0 by default: the table's velocity alone)."""
    vel = (y - s[S_YPREV]) / dt + p[P_COMPLIANCE] * (p_meas - s[S_PL_PREV]) / dt
    s[S_YPREV] = y
    return vel


@stage
def _regression_sums(p, s, xd, wd, zd, vel, dt):
    """The normal equations of y' = g (x - DZ w + o z): exponentially forgotten sums of the products of x, w, z, y'
    (gain_window_s; the offset's over null_offset_window_s)."""
    gf = dt / p[P_GW]
    s[S_GXX] += gf * (xd * xd - s[S_GXX])
    s[S_GXY] += gf * (vel * xd - s[S_GXY])
    s[S_GXW] += gf * (xd * wd - s[S_GXW])
    s[S_GWW] += gf * (wd * wd - s[S_GWW])
    s[S_GWY] += gf * (vel * wd - s[S_GWY])
    s[S_GZZ] += gf * (zd * zd - s[S_GZZ])
    s[S_GXZ] += gf * (xd * zd - s[S_GXZ])
    s[S_GWZ] += gf * (wd * zd - s[S_GWZ])
    s[S_GZY] += gf * (vel * zd - s[S_GZY])
    if p[P_OFFSET_ADAPT] > 0.5:
        lf = dt / p[P_OW]
        for i, v_i in enumerate((xd * xd, xd * wd, wd * wd, xd * zd, wd * zd, zd * zd, vel * xd, vel * wd,
                                 vel * zd)):
            s[S_LONG + i] += lf * (v_i - s[S_LONG + i])


@stage
def _null_offset_fit(p, s, omega, v_env, o_hat):
    """The null offset o (v_e0 of eq. 2) = (g o) / g of the 3x3 least squares of y' = g x - (g DZ) w + (g o) z over
    the long window, when z is not (nearly) a combination of x and w; projected onto +-null_offset_max_v."""
    # the Schur complement of z in the normal matrix of (x, -w, z) tells it (both directions of motion in the
    # window). On a steady sine a lower excitation floor than the gain's: at small amplitudes the offset is what
    # the motion depends on most
    dzn = p[P_DZ]  # the declared dead zone
    lxx, lxw, lww, lxz, lwz, lzz, lxy, lwy, lzy = s[S_LONG:S_LONG + 9]
    ldet = lxx * lww - lxw * lxw
    lqq = lxx - 2.0 * dzn * lxw + dzn * dzn * lww
    excited = lqq > p[P_GVMIN] ** 2 or (omega > 0.0 and v_env >= p[P_OVT] and lqq > p[P_OVMIN] ** 2)
    if excited and ldet > 0.02 * lqq * lww:
        res = lzz - (lww * lxz * lxz - 2.0 * lxw * lxz * lwz + lxx * lwz * lwz) / ldet
        if res > 0.02 * lzz:
            g_l, _eta, zeta, det3 = _solve3(lxx, -lxw, lxz, lww, -lwz, lzz, lxy, -lwy, lzy)
            if det3 != 0.0 and g_l > 0.0:
                s[S_OFFSET] = min(max(zeta / g_l, -p[P_OFFSET_MAX]), p[P_OFFSET_MAX])
                o_hat = s[S_OFFSET]
    return o_hat


@stage
def _gain_dead_zone_fit(p, s, dz_hat, o_hat):
    """g and DZ = (g DZ) / g of y' - g o z = g x - (g DZ) w (the offset held), or g alone with DZ and o held;
    projected onto [gain_min, gain_max] and the dead zone's bounds."""
    sxx, sxw, sww, sxy, swy = s[S_GXX], s[S_GXW], s[S_GWW], s[S_GXY], s[S_GWY]
    szz, sxz, swz, szy = s[S_GZZ], s[S_GXZ], s[S_GWZ], s[S_GZY]
    dzn = p[P_DZ]
    det = sxx * sww - sxw * sxw
    # excitation test in the coordinates (x - DZ_n w, w): x alone is nearly collinear with w when the
    # dead zone dominates the command (slow tests); the shear leaves det and the solution unchanged
    sqq = sxx - 2.0 * dzn * sxw + dzn * dzn * sww
    if p[P_DZ_ADAPT] > 0.5 and det > 0.02 * sqq * sww:
        # g and g DZ with the offset held: the velocity less its share g o z, g o = (g at its last value) o
        zeta = s[S_GAIN] * o_hat
        bxy = sxy - zeta * sxz
        bwy = swy - zeta * swz
        g_new = (bxy * sww - sxw * bwy) / det
        eta = (bxy * sxw - sxx * bwy) / det  # g DZ
        if g_new > 0.0:
            s[S_GAIN] = min(max(g_new, p[P_GMIN]), p[P_GMAX])
            s[S_DZ_HAT] = min(max(eta / g_new, p[P_DZ_LO]), p[P_DZ_HI])
    else:  # g alone, with the dead zone and the offset held
        qq = (sxx + dz_hat * dz_hat * sww + o_hat * o_hat * szz - 2.0 * dz_hat * sxw + 2.0 * o_hat * sxz
              - 2.0 * dz_hat * o_hat * swz)
        if qq > 0.0:
            s[S_GAIN] = min(max((sxy - dz_hat * swy + o_hat * szy) / qq, p[P_GMIN]), p[P_GMAX])


@stage
def _valve_estimate(p, s, xd, wd, zd, vel, omega, v_env, dt):
    """The valve's flow gain ratio g, dead zone DZ and null offset o from y' = g (x - DZ w + o z) (x, w, z: the
    nominal valve's velocity, velocity per volt times the opening's sign, velocity per volt, at the command sent
    then), least squares with forgetting; each moves only when the samples tell it apart from the others."""
    if np.isfinite(xd):
        _regression_sums(p, s, xd, wd, zd, vel, dt)
        dz_hat = s[S_DZ_HAT]
        # the mean square of the velocity the valve model predicts, q = x - DZ w + o z: only a valve that opens
        # well past its dead zone tells its gain, dead zone and offset apart from friction and the oil's give
        o_hat = s[S_OFFSET]
        qq = (s[S_GXX] + dz_hat * dz_hat * s[S_GWW] + o_hat * o_hat * s[S_GZZ] - 2.0 * dz_hat * s[S_GXW]
              + 2.0 * o_hat * s[S_GXZ] - 2.0 * dz_hat * o_hat * s[S_GWZ])
        if p[P_OFFSET_ADAPT] > 0.5 and p[P_DZ_ADAPT] > 0.5:
            o_hat = _null_offset_fit(p, s, omega, v_env, o_hat)
        if qq > p[P_GVMIN] ** 2:
            _gain_dead_zone_fit(p, s, dz_hat, o_hat)
    return s[S_GAIN]


@stage
def _target_seen(p, s, r, dt):
    """r(t - L): the target of the reading's latency L ago, from the delay line (the table, not the late reading,
    follows the target); also pushes r and returns the delay lines' new head."""
    head_new = (int(s[S_HEAD]) + 1) % DELAY_LINE
    s[S_LINE_R + head_new] = r
    r_seen = r
    latency = p[P_LAT] / dt  # periods
    if latency > 0.0:
        r_seen = _delayed(s, S_LINE_R, head_new, latency)
    return r_seen, head_new


@stage
def _learned_feedforward(s, v, theta, omega, v_env, nh, fast, nh_fast):
    """v + dv's harmonics: V_env Re sum_k c_k exp(j k theta), harmonics above H weighted by how fast the test is."""
    if omega > 0.0 and nh_fast >= 1:
        c1 = np.cos(theta)
        s1 = np.sin(theta)
        ck, sk = c1, s1
        acc = 0.0
        for k in range(nh_fast):
            a = s[S_C + 2 * k]
            b = s[S_C + 2 * k + 1]
            acc += (1.0 if k < nh else fast) * (a * ck - b * sk)
            ck, sk = ck * c1 - sk * s1, sk * c1 + ck * s1
        v += v_env * acc
    return v


@stage
def _velocity_demand(p, s, rd, rdd, rddd, e, theta, omega, v_env, nh, fast, nh_fast, p_meas, steady, dt):
    """v = r' + tau_v r'' (+ tau_j r''') + K_p (r(t - L) - y_L) + dv + v_c (docs/controller.md, "The law"), and its
    feedback part v_fb = K_p e + c_0: (v, v_fb)."""
    kp = p[P_KP]
    v = rd + p[P_TAU_V] * rdd + kp * e + s[S_C0]
    v_fb = kp * e + s[S_C0]  # the part of v that corrects the position error
    if p[P_JERK_LEAD] > 0.0:  # arbitrary commands: the jerk through the valve's and the column's second-order lag
        v += p[P_JERK_LEAD] * rddd
    v = _learned_feedforward(s, v, theta, omega, v_env, nh, fast, nh_fast)
    if omega > 0.0 and p[P_COMP] > 0.0:
        small = min(max(2.0 - v_env / p[P_CVMAX], 0.0), 1.0) if p[P_CVMAX] > 0.0 else 0.0
        v += fast * small * compression_feedforward(p, s, theta, omega, kp, p_meas, steady, dt)
    return v, v_fb


@stage
def _pressure_feedback_velocity(p, s, p_meas, v_est, dt):
    """-k_pf HP(P_L), the load-pressure feedback as a velocity (first-order high-pass at w_c): a leak that damps
    the oil column and leaves the test's frequencies alone. On a small periodic motion (the target's velocity
    amplitude V_est below half of pressure_feedback_full_velocity_m_per_s) only pressure_feedback_small_share of it:
    there the load pressure swings mostly with the guides' friction, whose flip at each reversal the leak holds
    back, and the table sticks (docs/controller.md, "Small motions and the pressure feedback")."""
    v_pf = 0.0
    if p[P_KPF] > 0.0:
        a_hp = 1.0 / (1.0 + p[P_PF_WC] * dt)
        s[S_PL_HP] = a_hp * (s[S_PL_HP] + p_meas - s[S_PL_PREV])
        share = 1.0
        if p[P_PF_SMALL] < 1.0 and p[P_PF_FULL_V] > 0.0:
            share = p[P_PF_SMALL] + (1.0 - p[P_PF_SMALL]) * min(max(2.0 * v_est / p[P_PF_FULL_V] - 1.0, 0.0), 1.0)
        v_pf = -share * p[P_KPF] * s[S_PL_HP]
    s[S_PL_PREV] = p_meas
    return v_pf


@stage
def _dead_zone_ramp(p, v_est, gain, p_supply):
    """delta = min(dead_zone_ramp_v, max(share A_n V_est / (g K_qn sqrt(P_s)), dead_zone_ramp_min_v)): narrow enough
    that the test's own velocities pass it, never wider than dead_zone_ramp_v (its step rings the oil column)."""
    ramp = p[P_DZ_RAMP]
    if p[P_RAMP_SHARE] > 0.0:
        ramp_fit = p[P_RAMP_SHARE] * p[P_AREA] * v_est / (gain * p[P_KQ] * np.sqrt(max(p_supply, 1.0)))
        ramp = min(max(ramp_fit, p[P_RAMP_MIN]), ramp)
    return ramp


@stage
def _pressure_feedback_command(p, u, v, v_pf, gain, p_load, p_supply):
    """u + u_pf, u_pf = A_n v_pf / (g K_qn R(P_s - sgn(v) P_L)): added after the dead-zone inverse, linearly (it
    moves the open valve, never switches the dead zone's side)."""
    if v_pf != 0.0:
        sgn_v = 1.0 if v >= 0.0 else -1.0
        dp_v = max(supply_share(sgn_v, p[P_AREA_RATIO_B]) * p_supply - sgn_v * p_load, p[P_DP_MIN] * p_supply)
        u += p[P_AREA] * v_pf / (gain * p[P_KQ] * orifice_root(dp_v, p[P_DP_REG]))
    return u


@stage
def _saturate(p, s, u):
    """u clipped to +-command_limit_v: (u, saturated now, saturated the period before)."""
    ulim = p[P_ULIM]
    was_saturated = s[S_SAT] > 0.5
    saturated = abs(u) >= ulim
    if u > ulim:
        u = ulim
    elif u < -ulim:
        u = -ulim
    s[S_SAT] = 1.0 if saturated else 0.0
    return u, saturated, was_saturated


@stage
def _across_underlap(p, u, o_hat, p_load, p_supply):
    """The command whose flow through an underlapped valve (sim.rig.load_flow: both lands open within +-U of null)
    is the flow the critically lapped law gives u: that law's inverse, about half of u round null and the lands'
    leak with P_L cancelled; beyond +-U the opening shifted by U. The valve sees u + o_hat (eq. 2)."""
    lap = p[P_UNDERLAP]
    if lap <= 0.0:
        return u
    dp_min = p[P_DP_MIN] * p_supply
    r_plus = orifice_root(max(p_supply - p_load, dp_min), p[P_DP_REG])
    r_minus = orifice_root(max(p[P_AREA_RATIO_B] * p_supply + p_load, dp_min), p[P_DP_REG])
    x = u + o_hat
    q = x * (r_plus if x >= 0.0 else r_minus)  # what the critically lapped valve passes for x, over K_q
    if q >= 2.0 * lap * r_plus:
        v = q / r_plus - lap
    elif q <= -2.0 * lap * r_minus:
        v = q / r_minus + lap
    else:
        v = (q - lap * (r_plus - r_minus)) / (r_plus + r_minus)
    return v - o_hat


@stage
def _across_play(p, s, u):
    """The command that moves the spool to u through the valve's play (sim.rig.command_after_play inverted): where
    u asks the spool to move, the command leads it by half the play that way; where u holds it, the command keeps
    the side it led on, so a still command stays still. Within the command limit."""
    half = 0.5 * p[P_PLAY]
    if half <= 0.0:
        return u
    held = s[S_PLAY_HELD]
    if u > held:
        s[S_PLAY_SIDE] = 1.0
    elif u < held:
        s[S_PLAY_SIDE] = -1.0
    s[S_PLAY_HELD] = u
    return min(p[P_ULIM], max(-p[P_ULIM], u + half * s[S_PLAY_SIDE]))


@stage
def _integral(p, s, e, ramp, ramp_at, gain, p_supply, was_saturated, dt):
    """c_0 += k_i K_p e dt (time histories), projected onto +-c0_max; on slow motions the dead zone's edge trim
    DZ_edge += k_i K_p e ramp dt A_n / (g K_qn sqrt(P_s)), never above 0 (docs/controller.md, "Time histories at
    rest")."""
    # the constant velocity a null offset asks, integrated: not while the command saturates, nor, on slow motions
    # (the feedback's own dead-zone ramp), while the valve is held inside its dead zone: the table at rest, where
    # the error says nothing about a velocity offset and integrating it would walk the command across the ramp
    kp = p[P_KP]
    slow = p[P_FB_RAMP] > ramp
    valve_open = abs(ramp_at) >= 1.0
    if p[P_INTEGRAL] > 0.0 and not was_saturated and (valve_open or not slow):
        c0max = p[P_C0MAX]
        s[S_C0] = min(max(s[S_C0] + p[P_INTEGRAL] * kp * e * dt, -c0max), c0max)
        if slow and valve_open and p[P_EDGE_TRIM] > 0.5:
            # on slow motions the velocity hinges on the dead zone's edge, and a few millivolts too much of it (the
            # estimate leans high: friction and the oil's give hold the table at its first millivolts of opening)
            # make the table run ahead of the target: with the side locked by the target's motion the feedback
            # then holds it K_p^-1 times that velocity ahead. The error on that side takes the excess off, with
            # the integral's gain (never adds: too little dead zone is a lag the feedback closes, not a relay)
            per_v = p[P_AREA] / (gain * p[P_KQ] * np.sqrt(max(p_supply, 1.0)))
            trim = s[S_EDGE] + p[P_INTEGRAL] * kp * e * ramp_at * dt * per_v
            s[S_EDGE] = min(max(trim, p[P_DZ_LO] - s[S_DZ_HAT]), 0.0)


@stage
def _record_regressors(p, s, u, o_hat, p_load, p_supply, head_new):
    """x = u K_qn R(dp) / A_n, w = sgn(u + o) K_qn R(dp) / A_n, z = K_qn R(dp) / A_n for the command applied, into
    the delay lines (NaN inside the dead zone: no flow, no sample)."""
    xs = np.nan
    ws = np.nan
    zs = np.nan
    opening = u + o_hat
    if abs(opening) > s[S_DZ_HAT]:
        sgn_u = 1.0 if opening > 0.0 else -1.0
        dp = supply_share(sgn_u, p[P_AREA_RATIO_B]) * p_supply - sgn_u * p_load
        if dp < p[P_DP_MIN] * p_supply:
            dp = p[P_DP_MIN] * p_supply
        per_volt = p[P_KQ] * orifice_root(dp, p[P_DP_REG]) / p[P_AREA]
        xs = per_volt * u
        ws = per_volt * sgn_u
        zs = per_volt
    s[S_LINE_X + head_new] = xs
    s[S_LINE_W + head_new] = ws
    s[S_LINE_Z + head_new] = zs
    s[S_HEAD] = head_new


@stage
def _learning_update(p, s, e, theta, omega, v_env, nh, dt):
    """c_k += gamma_k dt / (pi A_eff) e exp(-j k theta) L_k, |c_k| projected (docs/controller.md, "Learning law"),
    and c_0 += gamma K_p e w dt / (2 pi) (the error's mean through the loop's DC gain 1/K_p)."""
    kp = p[P_KP]
    gamma = p[P_GAMMA]
    a_eff = max(v_env / omega, p[P_AFLOOR])
    g = gamma * dt / (np.pi * a_eff)
    c0 = s[S_C0] + gamma * kp * e * omega * dt / (2.0 * np.pi)
    c0max = p[P_C0MAX]
    s[S_C0] = min(max(c0, -c0max), c0max)
    tau = p[P_TAU_L] + p[P_LAT]
    # the bounds widen once the learning has run learned_bound_cycles at its frequency
    widen = p[P_LB_FACTOR] if s[S_LEARNED_S] * omega >= 2.0 * np.pi * p[P_LB_CYCLES] else 1.0
    c1 = np.cos(theta)
    s1 = np.sin(theta)
    cl = np.cos(omega * tau)
    sl = np.sin(omega * tau)
    ck, sk = c1, s1
    cd, sd = cl, sl
    for k in range(nh):
        kw = (k + 1) * omega
        # L_k = (K_p + j k w) exp(j k w tau) (1 - (k w / w_h)^2 + 2 j zeta_h k w / w_h): inverse of the nominal
        # loop from dv to y, the oil column (w_h, damped by the pressure feedback's zeta_h) included
        lr = kp * cd - kw * sd
        li = kp * sd + kw * cd
        xh = kw / p[P_WH]
        hr = 1.0 - xh * xh
        hi = 2.0 * p[P_ZH] * xh
        lr, li = lr * hr - li * hi, lr * hi + li * hr
        # z = e exp(-j k theta) L_k
        zr = e * (ck * lr + sk * li)
        zi = e * (ck * li - sk * lr)
        # harmonics above the loop's bandwidth learn more slowly: their model is the least sure
        gk = g * min(1.0, kp / kw)
        a = s[S_C + 2 * k] + gk * zr
        b = s[S_C + 2 * k + 1] + gk * zi
        bound = (p[P_C1MAX] if k == 0 else p[P_CKMAX]) * widen
        mag = np.sqrt(a * a + b * b)
        if mag > bound:
            a *= bound / mag
            b *= bound / mag
        s[S_C + 2 * k] = a
        s[S_C + 2 * k + 1] = b
        ck, sk = ck * c1 - sk * s1, sk * c1 + ck * s1
        cd, sd = cd * cl - sd * sl, sd * cl + cd * sl


@njit(cache=True, error_model="numpy")
def servo_step(p, s, meas, dt, report):
    """One control period of the learning servo controller (the module docstring, docs/controller.md): the stages
    above in order; each reads and writes the state s, and the order is the law's."""
    r = meas[M_TARGET]
    rd = meas[M_TARGET_RATE]
    y = meas[M_POSITION]
    p_meas = meas[M_LOAD_PRESSURE]
    p_supply = meas[M_SUPPLY_PRESSURE]
    _start(s, r, rd, y, p_meas)
    # reading the target: its frequency, phase theta and velocity amplitude V_env from r' alone
    rd1, rdd, rddd = _target_differences(s, rd, dt)
    omega_est = _frequency_estimate(p, s, rd1, rddd, dt)
    rd_mid = 0.5 * (rd + rd1)
    steady, v_est = _steady_envelope(p, s, rd_mid, rdd, omega_est, dt)
    steady, omega = _learned_frequency(s, steady, omega_est, dt)
    v_env, nh, fast, nh_fast = _harmonic_band(p, omega, rd_mid, rdd, p_supply)
    # the valve estimate (g, DZ, o) from the flow the valve passed for the command sent tau_l + L ago
    xd, wd, zd = _delayed_regressors(p, s, dt)
    vel = _valve_flow_velocity(p, s, y, p_meas, dt)
    gain = _valve_estimate(p, s, xd, wd, zd, vel, omega, v_env, dt)
    # the velocity demand v: feed-forward, position feedback on r(t - L), learned and compression feed-forward
    r_seen, head_new = _target_seen(p, s, r, dt)
    e = r_seen - y
    theta = 0.0
    if omega > 0.0:
        theta = np.arctan2(-rdd / omega, rd_mid) + 0.5 * omega * dt
    v, v_fb = _velocity_demand(p, s, rd, rdd, rddd, e, theta, omega, v_env, nh, fast, nh_fast, p_meas, steady, dt)
    v_pf = _pressure_feedback_velocity(p, s, p_meas, v_est, dt)
    # the command: valve-law inverse u_l, dead-zone inverse and null offset, pressure feedback, limit
    p_load = p[P_PL_SHARE] * p_meas
    ramp = _dead_zone_ramp(p, v_est, gain, p_supply)
    o_hat = s[S_OFFSET]
    # with the integral on (time histories) v_fb ramps in over at least dead_zone_feedback_ramp_v: where the target
    # is slow the dead zone's side follows the target's own motion, and a few micrometres of error at rest no
    # longer throw the spool across the whole dead zone (a relay: a limit cycle of about 20 Hz)
    u_lin, ramp_at = valve_inverse_ramp(v / gain, p_load, p_supply, p[P_AREA], p[P_KQ], ramp, p[P_DP_MIN],
                                        p[P_DP_REG], v_fb / gain, p[P_FB_RAMP], p[P_AREA_RATIO_B])
    dz_c = p[P_DZ_FRAC] * max(s[S_DZ_HAT] + s[S_EDGE], p[P_DZ_LO])  # the estimated dead zone, trimmed
    # where the target is still, the dead zone's side moves slowly with the error instead of switching; under a
    # ringing target with the table's error from the centre of the swings
    still = target_stillness(p, s, r, rd, rdd, dt)
    e_still = e + p[P_STILL_CENTRE] * s[S_RING] * (s[S_CENTRE] - r)
    ramp_at = still_dead_zone_share(p, s, ramp_at, still, e_still, dz_c, dt)
    u = u_lin + dz_c * ramp_at - o_hat
    u = _pressure_feedback_command(p, u, v, v_pf, gain, p_load, p_supply)
    u, saturated, was_saturated = _saturate(p, s, u)
    # what the command teaches: the integral (time histories), the valve estimate's samples, the learning
    _integral(p, s, e, ramp, ramp_at, gain, p_supply, was_saturated, dt)
    _record_regressors(p, s, u, o_hat, p_load, p_supply, head_new)
    if fast >= 1.0:
        nh = nh_fast  # the harmonics of a fast test learn only once it is fully so
    # the learning law holds while the loop is disturbed (sim.loop.hold_learning: a stall's error is not the cycle's)
    held = meas[M_HOLD_LEARNING] > 0.5
    if steady and nh >= 1 and not saturated and not held:  # only on a steady sine, unsaturated, undisturbed
        _learning_update(p, s, e, theta, omega, v_env, nh, dt)
    report[R_MODEL] = r
    report[R_AR] = gain
    report[R_AY] = s[S_DZ_HAT]
    report[R_AS] = omega / (2.0 * np.pi)
    return _across_play(p, s, _across_underlap(p, u, o_hat, p_load, p_supply))  # the spool sees u
