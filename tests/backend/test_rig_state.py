"""GET /api/rig/state (the status strip), GET /api/protocols, and the motion a check answers with."""

from __future__ import annotations

import math
import time

import pytest
from conftest import AUTH, create_and_start, make_settings, sine_test, wait_for
from fastapi.testclient import TestClient

from backend.app import create_app


def test_the_state_follows_a_test_from_idle_to_its_end(client):
    idle = client.get("/api/rig/state").json()
    assert idle["status"] == "idle" and idle["test_id"] is None and idle["armed"] is False
    assert idle["table_position_m"] is None and idle["position_source"] == "unknown" and idle["last_event"] is None
    # no test has run: no force to show, and no test drives the valve
    assert idle["force_n"] is None and idle["force_source"].startswith("no reading: no test has run")
    assert idle["command_v"] == 0.0 and "valve is closed" in idle["command_source"]
    test_id = create_and_start(client, speed=1.0, vertical_load_n=2e5,
                               limits={"force_n": 1e5, "actions": {"force_n": "indicate"}})
    deadline = time.monotonic() + 10
    while time.monotonic() < deadline:
        state = client.get("/api/rig/state").json()
        if state["status"] == "running" and state["table_position_m"] is not None:
            break
        time.sleep(0.05)
    assert state["test_id"] == test_id and state["armed"] and state["position_source"] == "live"
    assert state["force_source"] == state["command_source"] == "live"
    assert state["force_n"] is not None and state["command_v"] is not None
    assert state["vertical_load_n"] == 2e5 and state["limits"]["actions"]["force_n"] == "indicate"
    assert abs(state["table_position_m"]) <= 0.0101 and state["supply_pressure_pa"] == pytest.approx(100e5, rel=0.05)
    assert state["last_event"]["kind"] == "operator" and "started" in state["last_event"]["message"]
    assert client.post(f"/api/tests/{test_id}/stop", headers=AUTH).status_code == 200
    stopping = client.get("/api/rig/state").json()
    assert stopping["status"] in ("stopping", "idle")  # idle if the ramp-out already ended
    if stopping["status"] == "stopping":
        assert "stop requested" in stopping["stopping_reason"]
    rec = wait_for(client, test_id)
    after = client.get("/api/rig/state").json()
    assert after["status"] == "idle" and after["limits"] is None
    assert after["position_source"] == f"end of test {test_id} ({rec['status']})"
    assert abs(after["table_position_m"]) < 1e-3  # a stop ramps the table back to zero
    # the force where the test left the rig (its last sample, stored), the valve closed: not the last command
    rows = client.get(f"/api/tests/{test_id}/data.csv").text.strip().splitlines()
    last = dict(zip(rows[0].split(","), (float(v) for v in rows[-1].split(",")), strict=True))
    assert after["force_source"] == after["position_source"]
    assert after["force_n"] == pytest.approx(last["force_n"], rel=1e-6, abs=1e-3)  # the CSV keeps 7 digits
    assert after["command_v"] == 0.0 and after["command_source"] == "no test runs: the valve is closed (0 V)"
    assert after["last_event"]["kind"] == "status"


def test_after_a_restart_the_table_is_where_the_last_test_left_it(tmp_path):
    settings = make_settings(tmp_path)
    with TestClient(create_app(settings)) as client:
        test_id = create_and_start(client, limits={"force_n": 2000.0})  # trips: the table stops off zero
        assert wait_for(client, test_id)["status"] == "aborted"
        before = client.get("/api/rig/state").json()
    with TestClient(create_app(settings)) as client:
        after = client.get("/api/rig/state").json()
    assert after["position_source"] == f"end of test {test_id} (aborted)"
    assert after["table_position_m"] == pytest.approx(before["table_position_m"], abs=1e-7)  # as stored
    assert after["force_source"] == f"end of test {test_id} (aborted)"
    assert after["force_n"] == pytest.approx(before["force_n"], abs=1e-3) and after["force_n"] != 0.0
    assert before["command_v"] == after["command_v"] == 0.0  # the trip closed the valve; no test drives it
    assert abs(after["table_position_m"]) > 1e-4


def test_protocols_are_listed_with_their_motion(client):
    protocols = {p["name"]: p for p in client.get("/api/protocols").json()}
    assert {"en15129_type_test", "quick_check"} <= set(protocols)
    p = protocols["en15129_type_test"]
    assert [lv["amplitude_m"] for lv in p["levels"]] == pytest.approx([0.005, 0.01, 0.0134, 0.02])
    assert p["peak_displacement_m"] == pytest.approx(0.02)
    assert p["peak_velocity_m_per_s"] == pytest.approx(2 * math.pi * 0.5 * 0.02)
    assert p["cycles_total"] == 20 and p["duration_s"] == pytest.approx(40.0)
    assert p["title"] and p["acceptance"]


def test_a_check_says_what_the_motion_asks_of_the_rig(client):
    out = client.post("/api/tests/check", json=sine_test()).json()
    assert out["ok"] is True
    assert out["peak_displacement_m"] == pytest.approx(0.01)
    assert out["peak_velocity_m_per_s"] == pytest.approx(2 * math.pi * 2.0 * 0.01)
    assert out["duration_s"] == pytest.approx(1.5) and out["cycles_total"] == 3
    assert 0 < out["peak_force_n"] < out["max_force_n"]
    heavier = client.post("/api/tests/check", json=sine_test(vertical_load_n=8e5)).json()
    assert heavier["peak_force_n"] > out["peak_force_n"]  # guide friction grows with the vertical load (eq. 1)
    body = {**sine_test(), "profile": {"kind": "protocol", "name": "quick_check"}}
    protocol = client.post("/api/tests/check", json=body).json()
    assert protocol["ok"] is True and protocol["peak_displacement_m"] == pytest.approx(0.02)
    refused = client.post("/api/tests/check", json=sine_test(profile={"amplitude_m": 0.5})).json()
    assert refused["ok"] is False and refused.get("peak_force_n") is None
