import numpy as np
import pytest

from sim.isolator import PRESETS
from sim.rig import (
    BAR_PA,
    DEFAULT_RIG,
    N_STATES,
    P_SUPPLY,
    X_PL,
    X_V,
    X_Y,
    dead_zone,
    load_flow,
    pack_plant,
    regularised_sqrt,
    rig_derivatives,
    rk4_step,
    rk4_steps,
    valve_command,
)


def plant(iso="IUT_a", bar=40.0):
    return pack_plant(DEFAULT_RIG, PRESETS[iso], bar * BAR_PA)


def test_every_parameter_has_unit_and_origin():
    for row in DEFAULT_RIG.describe():
        assert row["unit"] and row["origin"] in ("paper", "calibrated", "assumed"), row


def test_valve_command_eq2():
    p = plant()
    assert valve_command(0.0, p) == pytest.approx(0.02)
    assert valve_command(2.0, p) == pytest.approx(2.02)
    assert valve_command(-2.0, p) == pytest.approx(-1.98)


def test_dead_zone():
    assert dead_zone(0.5, 0.84) == 0.0
    assert dead_zone(2.84, 0.84) == pytest.approx(2.0)
    assert dead_zone(-1.84, 0.84) == pytest.approx(-1.0)


def test_regularised_orifice_is_continuous_and_defined_below_zero():
    reg = 6.8e5
    assert regularised_sqrt(reg, reg) == pytest.approx(np.sqrt(reg))
    assert regularised_sqrt(reg * (1 - 1e-12), reg) == pytest.approx(np.sqrt(reg), rel=1e-9)
    assert regularised_sqrt(0.0, reg) == 0.0
    assert regularised_sqrt(-reg, reg) == pytest.approx(-np.sqrt(reg))
    p = plant()
    # load pressure above supply: flow reverses instead of becoming NaN
    q = load_flow(5.0, p[P_SUPPLY] * 1.5, p)
    assert np.isfinite(q) and q < 0


def test_step_response_rests_at_static_force_balance():
    p = plant("IUT_a", 40.0)
    x = np.zeros(N_STATES)
    v_c = valve_command(4.0, p)
    for _ in range(int(20.0 / 2e-4)):
        rk4_step(x, v_c, p, 2e-4)
    assert abs(x[X_V]) < 1e-6  # at rest
    iso = PRESETS["IUT_a"]
    f_bw = iso.kd_n_per_m * x[X_Y] + iso.kw_n * x[5]
    # A_p P_L balances F_BW within the static friction band
    assert abs(DEFAULT_RIG.piston_area_m2 * x[X_PL] - f_bw) <= DEFAULT_RIG.friction_force_n * 1.001
    # flow stops only at P_L = P_s (no leakage in eq. 3), so the table rests where the cylinder force A_p P_s
    # balances the isolator force within the static friction band
    cylinder = DEFAULT_RIG.piston_area_m2 * 40 * BAR_PA
    assert x[X_PL] == pytest.approx(40 * BAR_PA, rel=1e-3)
    assert cylinder - DEFAULT_RIG.friction_force_n * 1.001 <= f_bw <= cylinder + DEFAULT_RIG.friction_force_n * 1.001
    assert 0.9 < x[5] <= 1.0  # the Bouc-Wen variable is near saturation after a long monotonic push


def test_derivatives_finite_everywhere_reasonable():
    p = plant()
    dx = np.empty(N_STATES)
    for pl in (-3e7, 0.0, 4e6, 1e7):
        for ve in (-10.0, 0.0, 0.5, 10.0):
            rig_derivatives(np.array([0.01, 0.0, pl, ve, 0.0, 0.5]), 1.0, p, dx)
            assert np.all(np.isfinite(dx))


def textbook_rk4(x, v_c, p, h):
    """One RK4 step written with stage arrays on rig_derivatives: the reference the compiled step must equal."""
    k = [np.empty(N_STATES) for _ in range(4)]
    rig_derivatives(x, v_c, p, k[0])
    rig_derivatives(x + 0.5 * h * k[0], v_c, p, k[1])
    rig_derivatives(x + 0.5 * h * k[1], v_c, p, k[2])
    rig_derivatives(x + h * k[2], v_c, p, k[3])
    return x + h * (k[0] + 2.0 * k[1] + 2.0 * k[2] + k[3]) / 6.0


def test_compiled_rk4_is_the_textbook_rk4_to_the_last_bit():
    """rk4_step/rk4_steps keep the state in local numbers: the same operations in the same order as stage arrays,
    through the dead zone, both flow directions, stick and slip."""
    p = plant("IUT_a", 100.0)
    h = 2e-4
    x = np.zeros(N_STATES)
    ref = x.copy()
    velocities = []
    for i in range(5000):  # 1 s: a 2 Hz valve command of +-3 V, through the +-0.86 V dead zone
        v_c = valve_command(3.0 * np.sin(2 * np.pi * 2.0 * i * h), p)
        rk4_step(x, v_c, p, h)
        ref = textbook_rk4(ref, v_c, p, h)
        np.testing.assert_array_equal(x, ref)
        velocities.append(x[X_V])
    velocities = np.array(velocities)
    assert velocities.max() > 1e-3 and velocities.min() < -1e-3  # slid both ways ...
    assert np.any(np.abs(velocities) < DEFAULT_RIG.stick_velocity_m_per_s)  # ... and went through the stick band
    several = np.zeros(N_STATES)
    rk4_steps(several, valve_command(2.0, p), p, h, 7)
    one_by_one = np.zeros(N_STATES)
    for _ in range(7):
        one_by_one = textbook_rk4(one_by_one, valve_command(2.0, p), p, h)
    np.testing.assert_array_equal(several, one_by_one)
