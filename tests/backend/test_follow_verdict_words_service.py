"""The service's tracking verdict says when the follow detector was set to indicate, in the CLI's words
(sim.engine.said_indicate): a verdict read without the events must not suggest the detector could have stopped
the test."""

from __future__ import annotations

from conftest import create_and_start, wait_for

from sim.engine import Scenario, Simulation
from sim.safety import make_limits

#: the paper's MRAC on IUT_a, 20 mm at 1 Hz: the tracking rule finds it at 4 s (test_follow_action_service.py)
MRAC = {"controller": "mrac", "speed": 100.0,
        "profile": {"amplitude_m": 0.02, "frequency_hz": 1.0, "cycles": 6, "taper_cycles": 1}}
SAID = "(follow detector set to indicate: 1 indication, the test was not stopped)"


def test_the_verdict_words_say_the_follow_detector_indicated(client):
    test_id = create_and_start(client, **MRAC, limits={"actions": {"follow": "indicate"}})
    rec = wait_for(client, test_id, timeout_s=60.0)
    assert rec["status"] == "completed", rec["reason"]
    verdict = rec["summary"]["tracking_verdict"]
    assert verdict["verdict"] == "did_not_follow" and verdict["follow_action"] == "indicate"
    assert verdict["words"].startswith("did not follow: ") and verdict["words"].endswith(SAID), verdict["words"]
    # the same words as isorig simulate --controller mrac --follow indicate gives for the same test
    s = Scenario.sine("IUT_a", 100.0, 0.02, 1.0, 6, controller="mrac")
    cli = Simulation(s).run(follow=True, limits=make_limits(s.rig, {"actions": {"follow": "indicate"}})).summary()
    assert cli["tracking_verdict"]["words"].endswith(SAID)


def test_by_default_the_verdict_words_do_not_speak_of_indicate(client):
    test_id = create_and_start(client, **MRAC)
    rec = wait_for(client, test_id, timeout_s=60.0)
    verdict = rec["summary"]["tracking_verdict"]
    assert "indicate" not in verdict["words"] and "follow_action" not in verdict
