"""Two valve features the fit met on rigs written from their physics (issue 32): an underlapped valve, whose lands
both stand open round null, and a valve with play (backlash) between its command and its spool.

On foreign rigs 0-599 a valve with play was trusted in 25 of 351 rigs, one without in 63 of 249; an underlapped
valve in 5 of 177. sim.rig now describes both (``underlap_v``, ``valve_play_v``), the flow balance fits them
(sim.commission.flow: a signed lap, a seventh non-linear parameter for the play) and the replay plays them.
"""

import dataclasses

import numpy as np
import pytest

from sim.commission.flow import after_play, land_flow, orifice
from sim.isolator import PRESETS
from sim.rig import BAR_PA, DEFAULT_RIG, P_PLAY_HELD, RigError, load_flow, pack_plant, valve_command

SUPPLY_PA = 100 * BAR_PA


def plant(**changes):
    return pack_plant(DEFAULT_RIG.with_changes(**changes), PRESETS["IUT_a"], SUPPLY_PA)


def test_an_underlapped_valve_flows_through_both_lands_round_null():
    underlap = 0.2
    p = plant(dead_zone_v=0.0, underlap_v=underlap, orifice_regularisation_pa=1.0)
    kq = DEFAULT_RIG.flow_gain_m3_per_s_v_sqrt_pa
    p_load = 20 * BAR_PA
    # at null both lands are open: the flow is the difference of the two sides' orifices, a leak against P_L
    leak = load_flow(0.0, p_load, p)
    assert leak == pytest.approx(kq * underlap * (np.sqrt(SUPPLY_PA - p_load) - np.sqrt(SUPPLY_PA + p_load)))
    assert leak < 0.0
    # round null the small-signal gain is twice the critically lapped valve's (at P_L = 0)
    gain = (load_flow(0.01, 0.0, p) - load_flow(-0.01, 0.0, p)) / 0.02
    assert gain == pytest.approx(2 * kq * np.sqrt(SUPPLY_PA), rel=1e-9)
    # beyond the underlap the land towards -y is shut: the critically lapped law with the opening shifted by U
    assert load_flow(1.0, p_load, p) == pytest.approx(kq * (1.0 + underlap) * np.sqrt(SUPPLY_PA - p_load))
    assert load_flow(-1.0, p_load, p) == pytest.approx(-kq * (1.0 + underlap) * np.sqrt(SUPPLY_PA + p_load))


def test_the_fit_law_is_the_plant_law_for_every_lap():
    """sim.commission.flow.land_flow (the fit's regressor) is sim.rig.load_flow / K_q: overlapped (a dead zone),
    critically lapped and underlapped, single-rod too."""
    v_e = np.linspace(-1.5, 1.5, 61)
    p_load = np.linspace(-40, 40, 61) * BAR_PA
    for lap in (0.3, 0.0, -0.15):
        for ratio_area in (0.0, 0.6 * DEFAULT_RIG.piston_area_m2):
            rig = dict(dead_zone_v=max(lap, 0.0), underlap_v=max(-lap, 0.0), piston_area_b_m2=ratio_area)
            p = plant(**rig)
            kq = DEFAULT_RIG.flow_gain_m3_per_s_v_sqrt_pa
            ratio = DEFAULT_RIG.with_changes(**rig).area_ratio_b
            fit = land_flow(v_e, p_load, np.full_like(v_e, SUPPLY_PA), lap, DEFAULT_RIG.orifice_regularisation_pa,
                            ratio)
            plant_law = np.array([load_flow(v, pl, p) for v, pl in zip(v_e, p_load, strict=True)]) / kq
            np.testing.assert_allclose(fit, plant_law, rtol=1e-12, atol=1e-12 * np.max(np.abs(plant_law)))
    assert orifice(np.array([4.0]), 1.0)[0] == 2.0


def test_a_rig_cannot_have_both_a_dead_zone_and_an_underlap():
    with pytest.raises(RigError) as caught:
        DEFAULT_RIG.with_changes(dead_zone_v=0.5, underlap_v=0.1).check()
    assert caught.value.field == "underlap_v" and "either" in str(caught.value)
    DEFAULT_RIG.with_changes(dead_zone_v=0.0, underlap_v=0.1).check()


def test_the_valve_play_holds_the_spool_until_the_command_comes_back_across_it():
    play = 0.1
    p = plant(valve_play_v=play, driver_offset_v=0.0)
    commands = [0.0, 0.04, 0.3, 0.25, 0.21, 0.19, -0.2, -0.1, -0.16]
    # the command the spool follows: held until u moves half the play away from it, then dragged along
    expected = [0.0, 0.0, 0.25, 0.25, 0.25, 0.24, -0.15, -0.15, -0.15]
    got = [valve_command(u, p) for u in commands]
    np.testing.assert_allclose(got, expected, atol=1e-12)
    assert p[P_PLAY_HELD] == pytest.approx(-0.15)
    # the fit's record-wide play (sim.commission.flow.after_play) is the same law
    np.testing.assert_allclose(after_play(np.array(commands), play), expected, atol=1e-12)
    # and without play the command is eq. (2) itself
    p0 = plant(driver_offset_v=0.0)
    assert [valve_command(u, p0) for u in commands] == commands


def test_the_rig_file_describes_both():
    names = {f.name: f for f in dataclasses.fields(DEFAULT_RIG)}
    for name in ("underlap_v", "valve_play_v"):
        assert names[name].metadata["unit"] == "V" and getattr(DEFAULT_RIG, name) == 0.0


def test_a_commissioned_rig_file_keeps_the_underlap_and_the_play(tmp_path):
    from sim.rigfile import load_rig_file, rig_file_data, write_rig_file

    rig = DEFAULT_RIG.with_changes(dead_zone_v=0.0, underlap_v=0.19, valve_play_v=0.052)
    path = write_rig_file(tmp_path / "commissioned.json", rig_file_data(rig, "rig 87"))
    loaded = load_rig_file(path).parameters
    assert (loaded.dead_zone_v, loaded.underlap_v, loaded.valve_play_v) == (0.0, 0.19, 0.052)
