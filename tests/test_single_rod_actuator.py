"""A single-rod actuator (issue 32 item 3): its valve law written from its two chambers, the rig file's
``piston_area_b_m2``, and a commissioning that knows the actuator's sides fits the valve's own k_en instead of
the area ratio."""

import math

import numpy as np
import pytest
from scipy import optimize

from sim.commission.foreign_campaign import start_rig_file_data
from sim.commission.identify import Conditions, excitation_scenario, identify
from sim.controllers.servo import valve_inverse
from sim.engine import Scenario, Simulation
from sim.isolator import PRESETS
from sim.rig import BAR_PA, DEFAULT_RIG, P_DPREG, P_DZ, P_KQ, RigError, load_flow, pack_plant

SUPPLY_PA = 100 * BAR_PA
LAND_FLOW = 3e-7  # m3/s per V sqrt(Pa): one metering land


def chamber_velocity(opening_v: float, p_load_pa: float, alpha: float, area_a: float) -> float:
    """The table's steady velocity from the two chambers and two lands (tank at 0), found numerically:
    towards +y, Q_in = k x sqrt(P_s - P_A) = A_A v and Q_out = k x sqrt(P_B) = alpha A_A v; towards -y the
    other pair of lands; with P_L = P_A - alpha P_B. Nothing of sim.rig's law is used here."""
    k, x = LAND_FLOW, abs(opening_v)

    def mismatch(p_a):  # P_B from P_L, then the two lands' flows must move the piston alike
        p_b = (p_a - p_load_pa) / alpha
        if opening_v > 0:
            return math.sqrt(max(SUPPLY_PA - p_a, 0.0)) - math.sqrt(max(p_b, 0.0)) / alpha
        return math.sqrt(max(p_a, 0.0)) - math.sqrt(max(SUPPLY_PA - p_b, 0.0)) / alpha

    # P_A where both lands' drops are >= 0 (a chamber below 0 is allowed: the algebra, not cavitation, is checked)
    lo, hi = (p_load_pa, SUPPLY_PA) if opening_v > 0 else (0.0, p_load_pa + alpha * SUPPLY_PA)
    p_a = optimize.brentq(mismatch, lo, hi, xtol=1e-6)
    speed = k * x * math.sqrt(SUPPLY_PA - p_a) / area_a if opening_v > 0 else k * x * math.sqrt(p_a) / area_a
    return math.copysign(speed, opening_v)


@pytest.mark.parametrize("alpha", [1.0, 0.55, 1.6])
def test_the_valve_law_is_what_the_two_chambers_give(alpha):
    rig = DEFAULT_RIG.with_changes(piston_area_b_m2=alpha * DEFAULT_RIG.piston_area_m2 if alpha != 1.0 else 0.0,
                                   dead_zone_v=0.0)
    p = pack_plant(rig, PRESETS["IUT_a"], SUPPLY_PA)
    p[P_KQ] = LAND_FLOW / math.sqrt(1.0 + alpha ** 3)  # one K_q both ways (sim.rig's docstring)
    p[P_DPREG] = 1.0  # the plain square root
    assert p[P_DZ] == 0.0
    area = rig.piston_area_m2
    for opening in (2.0, -2.0, 0.3, -0.3):
        for p_load in (-0.3 * SUPPLY_PA, 0.0, 0.2 * SUPPLY_PA):
            expected = area * chamber_velocity(opening, p_load, alpha, area)
            assert load_flow(opening, p_load, p) == pytest.approx(expected, rel=1e-5), (opening, p_load)


def test_a_double_rod_rig_keeps_the_papers_law():
    assert DEFAULT_RIG.piston_area_b_m2 == 0.0 and DEFAULT_RIG.area_ratio_b == 1.0
    same = DEFAULT_RIG.with_changes(piston_area_b_m2=DEFAULT_RIG.piston_area_m2)
    assert same.area_ratio_b == pytest.approx(1.0)
    p = pack_plant(DEFAULT_RIG, PRESETS["IUT_a"], SUPPLY_PA)
    rig = DEFAULT_RIG
    kq, dz, reg = rig.flow_gain_m3_per_s_v_sqrt_pa, rig.dead_zone_v, rig.orifice_regularisation_pa
    for v_e, p_load in ((3.0, 2e6), (-3.0, 2e6), (-2.0, -4e6)):
        drop = SUPPLY_PA - math.copysign(1.0, v_e) * p_load
        law = kq * (v_e - math.copysign(dz, v_e)) * (math.sqrt(drop) if drop >= reg else drop / math.sqrt(reg))
        assert load_flow(v_e, p_load, p) == pytest.approx(law, rel=1e-12)


@pytest.mark.parametrize("area_b", [0.1 * DEFAULT_RIG.piston_area_m2, 6.0 * DEFAULT_RIG.piston_area_m2, -1e-3])
def test_an_impossible_other_side_is_refused_with_what_is_allowed(area_b):
    with pytest.raises(RigError) as info:
        DEFAULT_RIG.with_changes(piston_area_b_m2=area_b).check()
    assert info.value.field == "piston_area_b_m2"
    assert "piston_area_b_m2" in str(info.value)


def test_a_labs_start_file_names_the_other_side_only_when_it_differs():
    lab = {"piston_area_m2": 0.02, "half_volume_m3": 3e-3, "stroke_m": 0.2, "pump_max_flow_m3_per_s": 4e-3,
           "max_supply_pa": 2.1e7, "command_limit_v": 10.0}
    assert "piston_area_b_m2" not in start_rig_file_data({**lab, "rod_side_area_m2": 0.02})
    assert start_rig_file_data({**lab, "rod_side_area_m2": 0.0125})["piston_area_b_m2"] == 0.0125


@pytest.mark.slow  # two commissionings of a simulated rig: scripts/test.sh --quick leaves it out
def test_a_commissioning_told_the_sides_fits_the_valves_own_negative_gain():
    alpha = 0.6
    single_rod = {"piston_area_b_m2": alpha * DEFAULT_RIG.piston_area_m2}
    isolator = PRESETS["IUT_a"]
    c = Conditions("simulated", SUPPLY_PA, 1.25e5, isolator.name, 0.0, 0.002, 0.02)
    told = DEFAULT_RIG.with_changes(**single_rod)
    samples = Simulation(excitation_scenario(isolator, c, told, single_rod), validate=False).run().samples
    knowing = identify(samples, told, c)
    blind = identify(samples, DEFAULT_RIG, c)
    k_known = knowing.fit.estimates["driver_gain_negative"]
    k_blind = blind.fit.estimates["driver_gain_negative"]
    # the rig's valve has k_en = 1: told the sides, the fit finds it; not told, it takes the area ratio for the
    # valve's (about sqrt(alpha) where P_L is small against P_s)
    assert abs(k_known.value - DEFAULT_RIG.driver_gain_negative) < max(3 * k_known.std, 0.03)
    assert k_blind.value < 0.9 and abs(k_blind.value - math.sqrt(alpha)) < 0.1
    assert knowing.fit.flow_r2 >= blind.fit.flow_r2 - 1e-4
    assert knowing.rig is not None and knowing.rig.piston_area_b_m2 == pytest.approx(alpha * DEFAULT_RIG.piston_area_m2)
    assert np.isfinite(knowing.response.velocity_nrmse) and knowing.response.velocity_nrmse < 0.1


def test_the_servos_inverse_is_the_plants_law_both_ways():
    alpha = 0.5
    rig = DEFAULT_RIG.with_changes(piston_area_b_m2=alpha * DEFAULT_RIG.piston_area_m2, dead_zone_v=0.0)
    p = pack_plant(rig, PRESETS["IUT_a"], SUPPLY_PA)
    for v in (0.02, -0.02, -0.1):
        for p_load in (-2e6, 0.0, 3e6):
            u = valve_inverse(v, p_load, SUPPLY_PA, rig.piston_area_m2, rig.flow_gain_m3_per_s_v_sqrt_pa, 0.0, 0.1,
                              0.05, rig.orifice_regularisation_pa, rig.area_ratio_b)
            assert load_flow(u, p_load, p) == pytest.approx(rig.piston_area_m2 * v, rel=1e-9), (v, p_load)


@pytest.mark.parametrize("alpha", [0.5])
def test_a_single_rod_rig_is_followed_as_well_as_a_double_rod_one(alpha):
    """20 mm at 0.5 Hz on a rig whose other side is half the area, the servo told the rig: within the 0.1 %
    target (0.116 % when the inverse took the double-rod law, 0.017 % with the rig's own)."""
    rig = DEFAULT_RIG.with_changes(piston_area_b_m2=alpha * DEFAULT_RIG.piston_area_m2, position_latency_s=1e-3)
    result = Simulation(Scenario.sine("IUT_a", 100.0, 0.02, 0.5, 12, rig=rig), validate=False).run(follow=True)
    verdict = result.summary()["tracking_verdict"]
    assert result.trip is None
    assert verdict["rms_share"] < 0.0005
