"""On a rig isorig commissioned, the servo's flow-gain estimate stays within 0.8-1.25 of the commissioned gain (issue
32 item 4; docs/controller.md, "On a commissioned rig the flow-gain estimate stays near the commissioned gain").

The 0.25-6 band is for a rig file nobody measured. On commissioned foreign rigs whose guides stick or whose valve
works near its lap the estimate ran to its bound and the table fell behind by a third of the amplitude in one cycle;
on the issue's 131 commissioned rigs the band took 2 mm at 1 Hz within 0.5 % from 90 to 95 and 0.5 mm within 1 %
from 97 to 101.
"""

import dataclasses

import pytest

from sim.commission import foreign_campaign as fc
from sim.controllers.servo import COMMISSIONED_MODE, HISTORY_MODE
from sim.engine import Scenario, Simulation
from sim.isolator import load_isolator
from sim.samples import FIELD_INDEX

SECTION = {"trusted": True, "max_velocity_m_per_s": 0.02,
           "estimates": {"position_latency_s": {"value": 1e-3, "std": 1e-4}}}


def test_the_commissioned_mode_is_the_servos_on_a_trusted_commissioning_only_and_the_test_may_override_it():
    s = Scenario.sine("IUT_a", 100.0, 0.002, 1.0, 4)
    assert "gain_max" not in s.effective_controller_options()  # nobody commissioned the rig: 0.25-6
    s.rig_commissioning = SECTION
    assert s.effective_controller_options() == COMMISSIONED_MODE
    assert Simulation(s).controller.options["gain_max"] == 1.25 and Simulation(s).controller.options["gain_min"] == 0.8
    s.rig_commissioning = dict(SECTION, trusted=False)  # a fit isorig did not trust is no commissioning
    assert s.effective_controller_options() == {}
    s.rig_commissioning = SECTION
    s.controller_options = {"gain_max": 3.0}  # what the test asks comes first
    assert s.effective_controller_options() == {"gain_min": 0.8, "gain_max": 3.0}
    s.controller = "pid"
    assert s.effective_controller_options() == {"gain_max": 3.0}  # the servo's mode is the servo's
    s.controller, s.controller_options = "servo", {}
    history = dataclasses.replace(s, history=object())  # only whether there is a time history counts here
    assert history.effective_controller_options() == {**COMMISSIONED_MODE, **HISTORY_MODE}


@pytest.mark.slow  # a commissioning and two runs: scripts/test.sh --quick leaves it out
def test_a_commissioned_foreign_rig_follows_2_mm_with_the_gain_estimate_kept_near_its_commissioned_gain():
    """Foreign rig 88 (commissioned at the first attempt): 2 mm at 1 Hz with the 0.25-6 band is stopped for
    tracking (measured 1.24 %, at 4 s); with the commissioned band it runs to its end within 0.5 % (0.145 %)."""
    lab = fc.commission_as_a_lab(fc.ForeignRun(88))
    assert lab.last.trusted, lab.last.problems
    section = fc.commissioning_section(lab.last, lab.max_velocity_m_per_s)
    wide = fc.tested(lab.spec, lab.last.rig, 0.002, 1.0, section, {"gain_min": 0.25, "gain_max": 6.0})
    assert wide["stop_kind"] == "tracking" and wide["share"] > 0.005, wide
    banded = fc.tested(lab.spec, lab.last.rig, 0.002, 1.0, section)
    assert banded["stopped_s"] is None and banded["share"] <= 0.005, banded
    scenario = Scenario.sine(load_isolator(fc.CONTROLLER_ISOLATOR), fc.SUPPLY_PA / 1e5, 0.002, 1.0, fc.TEST_CYCLES,
                             rig=lab.last.rig, vertical_load_n=float(lab.spec.drawn["table.vertical_load_n"]),
                             foreign_rig=lab.spec, rig_commissioning=section)
    gain = Simulation(scenario, validate=False).run(follow=False).samples.array[:, FIELD_INDEX["ar_hat"]]
    assert 0.8 <= gain.min() and gain.max() <= 1.25
