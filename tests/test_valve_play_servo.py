"""The servo crosses the valve's play (issue 32 item 4): a valve with play (backlash between command and spool)
holds its spool at each reversal until the command has come back across the play, a pause a small motion spends
as tracking error. The commissioned play (sim.commission.flow fits it) goes to the servo with the rig file, and
the servo's command leads the spool by half the play in the way it asks it to move (``_across_play``).

Measured on foreign rigs with play that tracked 0.5 mm at 1 Hz worse than 1 % (scripts in the commit): rig 64
4.1 % (stopped) -> 0.55 %, rig 87 1.96 % (stopped) -> 0.47 %, rig 56 21 % -> 4.6 %; two of twelve worse (91, 109).
"""

import numpy as np
import pytest

from sim.commission import foreign_campaign as fc
from sim.commission.flow import after_play
from sim.controllers import make_controller
from sim.controllers import servo as sv
from sim.rig import DEFAULT_RIG

PLAY_RIG = 64  # a 0.05 V play: 0.5 mm at 1 Hz stopped (4.1 %) without the servo crossing it (rig 87, 1.96 %, was
# this test's rig until its valve's frequency, which moves 17 % with the noise, refused it: tests/test_fit_noise.py)


def test_the_spool_sees_the_command_the_servo_meant():
    play = 0.05
    ctrl = make_controller("servo", rig=DEFAULT_RIG.with_changes(valve_play_v=play))
    p, s = ctrl.params, ctrl.new_state()
    rng = np.random.default_rng(3)
    meant = np.concatenate([np.linspace(0.0, 0.4, 20), np.full(5, 0.4), np.linspace(0.4, -0.3, 30),
                            0.01 * rng.standard_normal(40), np.full(5, -0.2)])
    sent = np.array([sv._across_play(p, s, float(u)) for u in meant])
    np.testing.assert_allclose(after_play(sent, play), meant, atol=1e-12)
    # a held command leaves the command still (no switching across the play)
    assert np.ptp(sent[-4:]) == 0.0 and np.ptp(sent[20:25]) == 0.0
    # without play the command is the one meant
    plain = make_controller("servo", rig=DEFAULT_RIG)
    assert [sv._across_play(plain.params, plain.new_state(), float(u)) for u in meant] == list(meant)


@pytest.mark.slow  # a whole commissioning and two tests: scripts/test.sh --quick leaves it out
def test_small_motion_on_a_valve_with_play_follows_once_the_servo_crosses_it():
    spec, _declared, ident = fc.first_attempt(PLAY_RIG)
    # rig 64's fit sits at a bound: its driver offset is uncertain by +-0.0300 V against the +-0.03 V allowed, so
    # its verdict turns with the last bits of the machine's libm (trusted where this test was written, refused on
    # an AMD EPYC). The servo's crossing of the play is what is tested here: the fitted rig runs as a lab that
    # accepted the fit would run it, and a refusal for anything but a value's uncertainty fails the test.
    assert all("is uncertain by" in problem for problem in ident.problems), ident.problems
    assert ident.rig.valve_play_v == pytest.approx(spec.drawn["valve.spool_play_v"], rel=0.1)
    section = {**fc.commissioning_section(ident, fc.DEFAULT_MAX_VELOCITY_M_PER_S), "trusted": True}
    crossed = fc.tested(spec, ident.rig, 0.5e-3, 1.0, section)
    ignored = fc.tested(spec, ident.rig.with_changes(valve_play_v=0.0), 0.5e-3, 1.0, section)
    assert crossed["stop_kind"] is None and crossed["share"] <= 0.01, crossed
    assert ignored["stop_kind"] is not None or ignored["share"] > 2 * crossed["share"], ignored


def test_through_an_underlapped_valve_the_servo_gets_the_flow_of_the_critically_lapped_law():
    """sim.rig.load_flow of the command _across_underlap sends is what the critically lapped valve passes for the
    command meant (round null about half of it, the lands' leak with P_L cancelled)."""
    from sim.isolator import PRESETS
    from sim.rig import BAR_PA, load_flow, pack_plant

    underlap, offset, supply = 0.2, 0.03, 100 * BAR_PA
    rig = DEFAULT_RIG.with_changes(dead_zone_v=0.0, underlap_v=underlap, driver_offset_v=offset,
                                   piston_area_b_m2=0.6 * DEFAULT_RIG.piston_area_m2)
    ctrl = make_controller("servo", rig=rig)
    underlapped = pack_plant(rig, PRESETS["IUT_a"], supply)
    critical = pack_plant(rig.with_changes(underlap_v=0.0), PRESETS["IUT_a"], supply)
    for meant in np.linspace(-1.0, 1.0, 41):
        for p_load in (-30 * BAR_PA, 0.0, 45 * BAR_PA):
            sent = sv._across_underlap(ctrl.params, float(meant), offset, p_load, supply)
            assert load_flow(sent + offset, p_load, underlapped) == pytest.approx(
                load_flow(meant + offset, p_load, critical), rel=1e-9, abs=1e-15)
    assert abs(sv._across_underlap(ctrl.params, 0.05, offset, 0.0, supply) + offset) < 0.05 + offset  # about half
    plain = make_controller("servo", rig=DEFAULT_RIG)
    assert sv._across_underlap(plain.params, 0.3, offset, 1e6, supply) == 0.3
