"""One test, one verdict: `isorig simulate` of issue 23's case (mrac on IUT_b, 70 bar, 30 mm at 0.5 Hz) ends as the
service ends it: aborted by the pump-flow velocity limit, with the same reason word for word."""

import json

from conftest import AUTH, sine_test, wait_for

from isorig.cli import main

CASE = {"isolator": "IUT_b", "supply_bar": 70, "controller": "mrac", "speed": 20.0,
        "profile": {"amplitude_m": 0.03, "frequency_hz": 0.5, "cycles": 3, "taper_cycles": 1}}
CLI = ["simulate", "--isolator", "IUT_b", "--supply-bar", "70", "--amplitude-m", "0.03", "--frequency-hz", "0.5",
       "--cycles", "3", "--controller", "mrac"]


def test_isorig_simulate_gives_the_services_verdict(client, tmp_path, capsys):
    r = client.post("/api/tests?start=true", json=sine_test(**CASE), headers=AUTH)
    assert r.status_code == 201, r.text
    record = wait_for(client, r.json()["id"])
    assert record["status"] == "aborted" and record["reason"].startswith("velocity limit tripped (valve close)")

    assert main([*CLI, "--out", str(tmp_path / "cli")]) == 1
    summary = json.loads((tmp_path / "cli" / "summary.json").read_text())
    assert (summary["status"], summary["reason"]) == (record["status"], record["reason"])
    assert summary["stopped"]["detector"] == "velocity" and summary["limit_detectors"] is True
    assert f"test aborted: {record['reason']}" in capsys.readouterr().out


def test_the_opt_out_says_what_it_leaves_out(tmp_path, capsys):
    """Without the limit detectors the velocity limit no longer stops it (the follow detector does, later)."""
    assert main([*CLI, "--no-limit-detectors", "--out", str(tmp_path / "free")]) == 1
    summary = json.loads((tmp_path / "free" / "summary.json").read_text())
    assert summary["limit_detectors"] is False and summary["stopped"]["detector"] == "not_following"
    assert "without the limit detectors" in capsys.readouterr().out


def test_the_opt_out_is_refused_on_a_rig(tmp_path):
    assert main([*CLI, "--no-limit-detectors", "--rig", "udp://127.0.0.1:9", "--out", str(tmp_path / "x")]) == 2
    assert not (tmp_path / "x").exists()
