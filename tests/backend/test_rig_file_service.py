"""isorig serve with a lab's rig file (settings.rig_file): what the controller assumes, the envelope and the
limits follow it, the worker's simulated plant is that rig, and the record and report name it."""

from __future__ import annotations

import json

import pytest
from conftest import AUTH, create_and_start, make_settings, sine_test, wait_for
from fastapi.testclient import TestClient
from pydantic import ValidationError

from backend.app import create_app
from sim.rig import DEFAULT_RIG


def write_rig(tmp_path, **values):
    path = tmp_path / "lab-rig.json"
    path.write_text(json.dumps({"name": "Lab B rig", "description": "long hoses, shorter stroke", **values}))
    return path


def test_the_service_runs_the_rig_its_file_describes(tmp_path):
    rig_file = write_rig(tmp_path, stroke_m=0.1, piston_area_m2=0.01, position_latency_s=0.001)
    with TestClient(create_app(make_settings(tmp_path, rig_file=rig_file))) as client:
        rig = client.get("/api/rig").json()
        assert rig["rig_file"]["name"] == "Lab B rig" and rig["rig_file"]["source"] == str(rig_file)
        assert rig["rig_file"]["changed"] == {"stroke_m": 0.1, "piston_area_m2": 0.01, "position_latency_s": 0.001}
        assert rig["envelope"]["stroke_m"] == 0.1 and rig["limits_max"]["displacement_m"] == 0.1
        assert rig["envelope"]["max_force_n"] == pytest.approx(0.01 * DEFAULT_RIG.max_supply_pa)
        # the envelope is this rig's: 0.12 m fits the default stroke (0.15 m), not this one
        r = client.post("/api/tests", json=sine_test(profile={"amplitude_m": 0.12, "frequency_hz": 0.1}),
                        headers=AUTH)
        assert r.status_code == 422 and "[1e-05, 0.1] m" in r.json()["detail"]
        test_id = create_and_start(client)
        rec = wait_for(client, test_id)
        assert rec["status"] == "completed" and rec["rig"] == "Lab B rig"
        assert rec["scenario"]["rig_changes"]["position_latency_s"] == 0.001
        # the simulated plant had the rig file's 1 ms sensor latency: the reading lags the true table
        rows = [r.split(",") for r in client.get(f"/api/tests/{test_id}/data.csv").text.splitlines()[1:]]
        header = client.get(f"/api/tests/{test_id}/data.csv").text.splitlines()[0].split(",")
        y, ym = header.index("displacement_m"), header.index("measured_displacement_m")
        assert float(rows[0][ym]) == 0.0 and max(abs(float(r[y]) - float(r[ym])) for r in rows) > 1e-5
        report = client.get(f"/api/tests/{test_id}/report.json").json()
        assert report["rig"]["name"] == "Lab B rig"
        latency = [s for s in report["rig"]["sensors"] if s["name"] == "position_latency_s"][0]
        assert latency["value"] == 0.001 and latency["changed"]


def test_a_rig_file_that_is_not_a_rig_stops_the_service_with_the_reason(tmp_path):
    with pytest.raises(ValidationError, match="dead_zone_v"):
        make_settings(tmp_path, rig_file=write_rig(tmp_path, dead_zone_v=20.0))
    with pytest.raises(ValidationError, match="cannot read the rig file"):
        make_settings(tmp_path, rig_file=tmp_path / "missing.json")


def test_a_single_rod_rig_file_is_judged_by_what_its_rod_side_pulls(tmp_path):
    """A rig file with the rod side's area: the service's envelope shows the force each way, and a sine the rod side
    cannot pull is refused before it starts (before, it started and stalled at the force limit)."""
    area = DEFAULT_RIG.piston_area_m2
    rig_file = write_rig(tmp_path, piston_area_b_m2=0.5 * area)
    with TestClient(create_app(make_settings(tmp_path, rig_file=rig_file))) as client:
        envelope = client.get("/api/rig").json()["envelope"]
        assert envelope["max_pull_force_n"] == pytest.approx(0.5 * envelope["max_force_n"])
        test = sine_test(isolator="IUT_a", supply_bar=100, profile={"amplitude_m": 0.04, "frequency_hz": 0.5})
        body = client.post("/api/tests/check", json=test).json()
        assert body["ok"] is False and body["field"] == "amplitude_m" and body["limit"].startswith("A_B P_s")
        assert "pull at most A_B P_s" in body["detail"] and "rod side" in body["detail"], body
        assert body["max_pull_force_n"] == pytest.approx(0.5 * area * 100e5)
        assert body["max_amplitude_m"] < 0.04  # what fits: the rod side's force, not the cap side's
        assert client.post("/api/tests", json=test, headers=AUTH).status_code == 422
