"""Manual motion: the minimum-jerk move target, POST /api/rig/move and /api/rig/zero, and the rule that a
test starts only with the table at zero."""

from __future__ import annotations

import time

import numpy as np
import pytest
from conftest import AUTH, make_settings, sine_test, wait_for, zero_table
from fastapi.testclient import TestClient

from backend.app import create_app
from sim.motion import HOLD_S, MAX_SPEED_M_PER_S, MotionError, check_move, move_target


def test_the_move_target_starts_and_ends_at_rest_at_the_asked_peak_speed():
    h = move_target(0.0095, -0.002, 0.005)
    assert h.r_m[0] == 0.0095 and h.r_m[-1] == pytest.approx(-0.002, abs=1e-15)
    assert np.max(np.abs(h.r_dot_m_per_s)) == pytest.approx(0.005, rel=1e-4)
    assert h.r_dot_m_per_s[0] == 0.0 and h.r_ddot_m_per_s2[0] == 0.0
    hold = int(HOLD_S / h.dt_s)
    assert np.all(h.r_m[-hold:] == h.r_m[-1]) and np.all(h.r_dot_m_per_s[-hold:] == 0.0)
    # r' and r'' are the derivatives of r (trapezoid rule over one period)
    np.testing.assert_allclose(np.diff(h.r_m), 0.5 * h.dt_s * (h.r_dot_m_per_s[1:] + h.r_dot_m_per_s[:-1]),
                               atol=1e-10)
    assert np.all(np.diff(h.r_m[: -hold]) <= 0)  # monotonic: never overshoots


@pytest.mark.parametrize(("start", "end", "speed", "field"), [
    (0.0, 0.2, 0.005, "position_m"), (0.0, float("nan"), 0.005, "position_m"), (0.3, 0.0, 0.005, "start_m"),
    (0.0, 0.01, 0.0, "speed_m_per_s"), (0.0, 0.01, MAX_SPEED_M_PER_S * 1.01, "speed_m_per_s"),
])
def test_a_move_outside_what_manual_motion_allows_is_refused_with_its_field(start, end, speed, field):
    with pytest.raises(MotionError) as err:
        check_move(start, end, speed, stroke_m=0.15)
    assert err.value.field == field


def move(client, position_m, speed=0.02, **extra):
    body = {"position_m": position_m, "speed_m_per_s": speed, "isolator": "IUT_a", "supply_bar": 100, **extra}
    return client.post("/api/rig/move", json=body, headers=AUTH)


def test_a_test_starts_only_with_the_table_at_zero_and_zero_brings_it_back(tmp_path):
    settings = make_settings(tmp_path)
    with TestClient(create_app(settings)) as client:
        r = move(client, 0.01, operator_name="A. Rossi")
        assert r.status_code == 201, r.text
        moved = wait_for(client, r.json()["id"])
        assert moved["status"] == "completed" and moved["profile"]["kind"] == "move"
        assert moved["label"].startswith("manual move 0.00 mm -> 10.00 mm at 20 mm/s")
        assert moved["cycles_total"] == 0 and moved["operator_name"] == "A. Rossi (through automation)"
        events = client.get(f"/api/tests/{moved['id']}").json()["events"]  # said as a move, not as a test
        start = next(e for e in events if (e["values"] or {}).get("action") == "start")
        assert start["message"] == f"manual move {moved['id']} started by automation"
        assert start["values"]["move"] is True
        assert events[-1]["message"] == f"manual move {moved['id']} completed"
        state = client.get("/api/rig/state").json()
        assert state["table_position_m"] == pytest.approx(0.01, abs=2e-4)
        # where the figure comes from says it was a move (the console's status strip parses this text)
        assert state["position_source"] == state["force_source"] == f"end of move {moved['id']} (completed)"
        at = f"the table is at {state['table_position_m'] * 1e3:.2f} mm"  # where the move left it, near 10 mm
        r = client.post("/api/tests?start=true", json=sine_test(), headers=AUTH)
        assert r.status_code == 409 and at in r.json()["detail"] and "nothing moved" in r.text
        assert [t["id"] for t in client.get("/api/tests").json()] == [moved["id"]]  # nothing left behind
        assert client.get(f"/api/tests/{moved['id']}/report.pdf").status_code == 422  # a move has no report
    with TestClient(create_app(settings)) as client:  # the table is still there after a restart
        assert client.get("/api/rig/state").json()["position_source"] == f"end of move {moved['id']} (completed)"
        r = client.post("/api/tests?start=true", json=sine_test(), headers=AUTH)
        assert r.status_code == 409 and at in r.json()["detail"]
        body = {"speed_m_per_s": 0.02, "isolator": "IUT_a", "supply_bar": 100}
        r = client.post("/api/rig/zero", json=body, headers=AUTH)
        assert r.status_code == 201 and "-> 0.00 mm" in r.json()["label"]
        assert wait_for(client, r.json()["id"])["status"] == "completed"
        assert abs(client.get("/api/rig/state").json()["table_position_m"]) < 2e-4
        zero_id = r.json()["id"]
        assert client.get("/api/rig/state").json()["position_source"] == f"end of move {zero_id} (completed)"
        r = client.post("/api/tests?start=true", json=sine_test(), headers=AUTH)
        assert r.status_code == 201 and wait_for(client, r.json()["id"])["status"] == "completed"
        assert client.get("/api/rig/state").json()["position_source"] == f"end of test {r.json()['id']} (completed)"
        events = client.get(f"/api/tests/{r.json()['id']}").json()["events"]
        started = next(e for e in events if (e["values"] or {}).get("action") == "start")
        assert started["message"] == f"test {r.json()['id']} started by automation" and "move" not in started["values"]
        assert events[-1]["message"] == f"test {r.json()['id']} completed"


def test_a_stopped_move_holds_the_table_where_it_is(client):
    r = move(client, 0.05, speed=0.01)  # 9.4 s of move
    test_id = r.json()["id"]
    deadline = time.monotonic() + 20
    while client.get("/api/rig/state").json().get("table_position_m") in (None, 0.0) or \
            abs(client.get("/api/rig/state").json()["table_position_m"]) < 0.002:
        assert time.monotonic() < deadline
        time.sleep(0.05)
    assert client.post(f"/api/tests/{test_id}/stop", headers=AUTH).status_code == 200
    rec = wait_for(client, test_id)
    assert rec["status"] == "stopped" and rec["time_s"] < 9.0
    rows = [r.split(",") for r in client.get(f"/api/tests/{test_id}/data.csv").text.splitlines()[1:]]
    y = np.array([float(r[3]) for r in rows])
    assert 0.002 < y[-1] < 0.049 and float(rows[-1][4]) == 0.0  # stopped part way, the valve closed
    assert abs(y[-1] - client.get("/api/rig/state").json()["table_position_m"]) < 1e-4


def test_moves_are_refused_while_a_test_runs_and_beyond_the_limits(client):
    r = client.post("/api/tests?start=true", json=sine_test(speed=1.0, profile={"cycles": 6}), headers=AUTH)
    test_id = r.json()["id"]
    r = move(client, 0.01)
    assert r.status_code == 409 and f"test {test_id} is running" in r.json()["detail"]
    client.post(f"/api/tests/{test_id}/abort", headers=AUTH)
    wait_for(client, test_id)
    r = move(client, 0.02, limits={"displacement_m": 0.01})
    assert r.status_code == 422 and r.json()["field"] == "position_m" and "displacement limit" in r.json()["detail"]
    r = move(client, 0.01, speed=0.5)
    assert r.status_code == 422 and r.json()["field"] == "speed_m_per_s" and "50 mm/s" in r.json()["detail"]
    r = client.post("/api/rig/move", json={"position_m": 0.01, "isolator": "IUT_a", "supply_bar": 100})
    assert r.status_code == 401  # the operator token moves the table, nobody else


@pytest.mark.slow  # moves run to a trip: scripts/test.sh --quick leaves it out
def test_a_controlled_stop_trip_during_a_move_holds_the_table_where_it_is(client):
    """A limit whose action is a controlled stop ends a move as the operator's stop does: where the table is,
    never by driving it back to where the move began."""
    limits = {"force_n": 20000.0, "actions": {"force_n": "controlled_stop"}}
    r = move(client, 0.06, speed=0.02, limits=limits)
    assert r.status_code == 201, r.text
    rec = wait_for(client, r.json()["id"])
    assert rec["status"] == "aborted" and "force limit tripped (controlled stop)" in rec["reason"], rec["reason"]
    trip = next(e for e in rec["events"] if e["kind"] == "limit_trip")
    y_trip = trip["values"]["displacement_m"]
    rows = [r.split(",") for r in client.get(f"/api/tests/{rec['id']}/data.csv").text.splitlines()[1:]]
    t = np.array([float(r[0]) for r in rows])
    y = np.array([float(r[3]) for r in rows])
    after = t >= trip["time_s"]
    assert 0.005 < y_trip < 0.055
    assert y[after].min() > y_trip - 0.001 and abs(y[-1] - y_trip) < 0.005  # held there, not back to 0
    assert np.max(np.abs(np.diff(y[after]))) / 1e-3 < 0.05  # never faster than manual motion allows
    assert float(rows[-1][4]) == 0.0
    zero_table(client)


@pytest.mark.slow  # a move and a whole test: scripts/test.sh --quick leaves it out
def test_a_sine_can_run_about_where_the_table_rests(client):
    """The console's offset from the table position: start_m = offset_m = where the table is. The test starts
    there (not from zero), runs about it and ends there; the start check compares with start_m."""
    assert wait_for(client, move(client, 0.012).json()["id"])["status"] == "completed"
    at = client.get("/api/rig/state").json()["table_position_m"]
    assert abs(at - 0.012) < 2e-4
    here = {"offset_m": at, "start_m": at}
    check = client.post("/api/tests/check", json=sine_test(profile=here)).json()
    assert check["ok"] and check["start_position_m"] == pytest.approx(at)
    assert check["peak_displacement_m"] == pytest.approx(at + 0.01)
    r = client.post("/api/tests?start=true", json=sine_test(), headers=AUTH)  # from zero: refused, with what to do
    assert r.status_code == 409 and "move the table to zero first" in r.json()["detail"]
    r = client.post("/api/tests?start=true", json=sine_test(profile=here), headers=AUTH)
    assert r.status_code == 201, r.text
    rec = wait_for(client, r.json()["id"])
    assert rec["status"] == "completed" and rec["profile"]["start_m"] == pytest.approx(at)
    rows = [r.split(",") for r in client.get(f"/api/tests/{rec['id']}/data.csv").text.splitlines()[1:]]
    target = np.array([float(r[1]) for r in rows])
    assert target[0] == pytest.approx(at, abs=1e-8) and target.min() == pytest.approx(at - 0.01, abs=2e-4)
    assert abs(client.get("/api/rig/state").json()["table_position_m"] - at) < 5e-4  # ends where it began
    zero_table(client)
    r = client.post("/api/tests?start=true", json=sine_test(profile=here), headers=AUTH)
    assert r.status_code == 409 and f"move the table to {at * 1e3:.2f} mm first" in r.json()["detail"]
    r = client.post("/api/tests?start=true", json=sine_test(profile={"start_m": 0.2}), headers=AUTH)
    assert r.status_code == 422 and r.json()["field"].endswith("start_m")


def test_the_move_guard_trips_where_the_measured_velocity_first_passes_twice_the_speed_plus_5_mm_s():
    """sim.motion.MoveGuard over a move's blocks: the velocity spans the blocks (5 ms of readings), the trip is the
    first period beyond 2 x speed + 5 mm/s and closes the valve at once; a stop's open-loop rows are not judged."""
    from sim.measurement import FLAG_OPEN_LOOP
    from sim.motion import MOVE_GUARD, MoveGuard, move_guard_m_per_s
    from sim.safety import measured_velocity
    from sim.samples import Samples

    assert move_guard_m_per_s(0.005) == pytest.approx(0.015) and move_guard_m_per_s(0.02) == pytest.approx(0.045)
    n, dt = 60, 1e-3
    v = np.linspace(0.0, 0.03, n)  # a table that runs away: 0 to 30 mm/s in 60 ms
    y = 0.001 + np.concatenate([[0.0], np.cumsum(v[1:] * dt)])
    rows = Samples.empty(n)
    rows.array[:, :] = 0.0
    for name, values in (("time_s", np.arange(n) * dt), ("measured_displacement_m", y), ("target_m", y)):
        rows.array[:, rows.fields.index(name)] = values
    expected = int(np.flatnonzero(np.abs(measured_velocity(y)) > 0.015)[0])
    found = {}
    for flags in (0, FLAG_OPEN_LOOP):
        rows.array[:, rows.fields.index("flags")] = flags
        guard = MoveGuard(0.005)
        for k in range(0, n, 10):  # the worker's blocks of 10 periods
            trip = guard.check(Samples(rows.array[k: k + 10]))
            if trip is not None:
                found[flags] = (k + trip.index, trip)
                break
    assert list(found) == [0]  # the open-loop rows of a stop: not judged
    k, trip = found[0]
    assert k == expected and trip.detector == MOVE_GUARD and trip.close_at_once and trip.action == "valve_close"
    assert trip.values["velocity_m_per_s"] > 0.015 and "commission it" in trip.message
