"""Issue 34 item 1: the follow detector as an operator's limit, ``limits.actions.follow`` (``controlled_stop``, the
default, or ``indicate``), and ``--follow stop|indicate`` on ``isorig simulate`` and ``isorig hybrid``."""

from __future__ import annotations

import json

import pytest

from isorig.cli import main
from sim.engine import Scenario, Simulation
from sim.rig import DEFAULT_RIG
from sim.safety import DEFAULT_FOLLOW_ACTION, FOLLOW_ACTIONS, LimitError, SafetyLimits, make_limits

#: the paper's MRAC on IUT_a at 1 Hz, short: the tracking rule finds it 30 % off at 5 s, gaining less than 20 % a
#: cycle (the default stops it there)
MRAC = ["simulate", "--isolator", "IUT_a", "--supply-bar", "100", "--amplitude-m", "0.02", "--frequency-hz", "1",
        "--cycles", "6", "--controller", "mrac"]


def test_the_follow_action_is_a_limit_with_its_default_and_thresholds():
    lim = make_limits(DEFAULT_RIG, None)
    assert lim.action("follow") == DEFAULT_FOLLOW_ACTION == "controlled_stop"
    assert "follow" not in lim.actions  # a record without it is a default one (older records too)
    shown = lim.to_dict()["follow"]
    assert shown["action"] == "controlled_stop" and shown["rms_share"] == 0.01 and shown["oscillation_share"] == 0.02
    told = make_limits(DEFAULT_RIG, {"actions": {"follow": "indicate"}})
    assert told.action("follow") == "indicate" and told.to_dict()["actions"]["follow"] == "indicate"
    assert SafetyLimits.from_dict(told.to_dict()) == told
    assert set(FOLLOW_ACTIONS) == {"controlled_stop", "indicate"}
    with pytest.raises(LimitError, match="not an action of the follow detector; allowed: controlled_stop, indicate"):
        make_limits(DEFAULT_RIG, {"actions": {"follow": "valve_close"}})


def test_by_default_a_tracking_stop_brakes_the_target_under_control():
    s = Scenario.sine("IUT_a", 100.0, 0.02, 1.0, 6, controller="mrac")
    result = Simulation(s).run(follow=True, limits=make_limits(s.rig, None))
    assert result.status == "aborted" and result.trip.detector == "not_following"
    assert result.trip.action == "controlled_stop" and result.trip.values["kind"] == "tracking"
    assert "controlled stop" in result.reason


def test_indicate_records_what_the_detector_saw_and_the_test_runs_to_its_end():
    s = Scenario.sine("IUT_a", 100.0, 0.02, 1.0, 6, controller="mrac")
    result = Simulation(s).run(follow=True, limits=make_limits(s.rig, {"actions": {"follow": "indicate"}}))
    assert result.status == "completed" and result.trip is None
    (seen,) = [i for i in result.indications if i.detector == "not_following"]
    assert seen.action == "indicate" and seen.values["kind"] == "tracking" and seen.time_s == pytest.approx(5.0)
    assert "indicated" in seen.message and "30 %" in seen.message
    summary = result.summary()
    assert summary["follow_action"] == "indicate"
    verdict = summary["tracking_verdict"]
    assert verdict["verdict"] == "did_not_follow" and verdict["follow_action"] == "indicate"
    assert "set to indicate" in verdict["words"]


def test_indicate_without_the_limit_detectors():
    s = Scenario.sine("IUT_a", 100.0, 0.02, 1.0, 6, controller="mrac")
    result = Simulation(s).run(follow=True, follow_action="indicate")
    assert result.status == "completed" and [i.detector for i in result.indications] == ["not_following"]


def test_an_oscillation_and_then_the_tracking_are_each_indicated_once():
    """IUT_b without a taper (the paper's start, beyond the pump) rings at the start (the comb has no cycle yet):
    an oscillation, and the tracking later; each kind once, and the test runs to its end."""
    s = Scenario.sine("IUT_b", 70.0, 0.03, 1.0, 6, controller="mrac", taper_cycles=0)
    result = Simulation(s).run(follow=True, follow_action="indicate")
    assert result.status == "completed"
    assert [i.values["kind"] for i in result.indications] == ["oscillation", "tracking"]


def test_simulate_takes_follow_indicate(tmp_path, capsys):
    assert main([*MRAC, "--out", str(tmp_path / "stop")]) == 1
    summary = json.loads((tmp_path / "stop" / "summary.json").read_text())
    assert summary["status"] == "aborted" and summary["stopped"]["action"] == "controlled_stop"
    assert summary["follow_action"] == "controlled_stop"
    capsys.readouterr()
    # it ran to its end: the exit code is still 1, the table did not follow (the verdict says so)
    assert main([*MRAC, "--follow", "indicate", "--out", str(tmp_path / "go")]) == 1
    out = capsys.readouterr().out
    summary = json.loads((tmp_path / "go" / "summary.json").read_text())
    assert summary["status"] == "completed" and summary["follow_action"] == "indicate"
    assert summary["tracking_verdict"]["verdict"] == "did_not_follow"
    assert [i["detector"] for i in summary["limit_indications"]] == ["not_following"]
    assert "test completed" in out and "follow detector (set to indicate)" in out and "set to indicate" in out


def test_simulate_refuses_an_unknown_follow_action(tmp_path, capsys):
    assert main([*MRAC, "--follow", "valve_close", "--out", str(tmp_path / "x")]) == 2
    assert "choose from 'stop', 'indicate'" in capsys.readouterr().err


def test_hybrid_takes_follow(tmp_path):
    """isorig hybrid runs the service's worker with the follow detector's action of --follow."""
    import numpy as np

    gm = tmp_path / "pulse.csv"
    t = np.arange(0.0, 3.0, 0.005)
    acc = 2.0 * np.sin(2 * np.pi * 1.2 * t) * np.exp(-((t - 1.5) / 0.6) ** 2)
    gm.write_text("time_s,acceleration_m_per_s2\n" + "".join(f"{a:.4f},{b:.6g}\n" for a, b in zip(t, acc, strict=True)))
    code = main(["hybrid", "--structure", "docs/examples/structure_3_storey.json", "--ground-motion", str(gm),
                 "--isolator", "IUT_a", "--follow", "indicate", "--out", str(tmp_path / "o")])
    summary = json.loads((tmp_path / "o" / "summary.json").read_text())
    assert code == 0 and summary["status"] == "completed" and summary["follow_action"] == "indicate"
