"""Issue 34 item 1 through the service: ``limits.actions.follow`` (controlled_stop, the default, or indicate),
checked with a clear 422; the paper's controller runs to its end within the limits when set to indicate."""

from __future__ import annotations

from conftest import AUTH, create_and_start, sine_test, wait_for

#: the paper's MRAC on IUT_a, 20 mm at 1 Hz: 30 % of the amplitude off at 5 s, where the tracking rule finds it
MRAC = {"controller": "mrac", "speed": 100.0,
        "profile": {"amplitude_m": 0.02, "frequency_hz": 1.0, "cycles": 6, "taper_cycles": 1}}


def test_the_api_refuses_a_follow_action_with_the_allowed_ones(client):
    r = client.post("/api/tests", headers=AUTH, json=sine_test(limits={"actions": {"follow": "valve_close"}}))
    assert r.status_code == 422, r.text
    body = r.json()
    assert body["field"] == "limits.actions.follow" and "controlled_stop, indicate" in body["detail"], body
    r = client.post("/api/tests", headers=AUTH, json=sine_test(limits={"actions": {"follow": "stop"}}))
    assert r.status_code == 422 and "follow detector" in r.json()["detail"]
    assert client.get("/api/tests").json() == []


def test_the_papers_controller_runs_to_its_end_when_the_follow_detector_indicates(client):
    test_id = create_and_start(client, **MRAC, limits={"actions": {"follow": "indicate"}})
    rec = wait_for(client, test_id, timeout_s=60.0)
    assert rec["status"] == "completed", rec["reason"]
    assert rec["limits"]["actions"]["follow"] == "indicate" and rec["limits"]["follow"]["action"] == "indicate"
    (seen,) = [e for e in rec["events"] if e["kind"] == "limit_indicate" and e["values"]["detector"] == "not_following"]
    assert seen["values"]["kind"] == "tracking" and abs(seen["time_s"] - 5.0) < 0.02 and "indicated" in seen["message"]
    assert rec["summary"]["limit_indications"]["follow"] == 1
    assert rec["summary"]["tracking_verdict"]["verdict"] == "did_not_follow"  # still the verdict
    assert not [e for e in rec["events"] if e["kind"] == "limit_trip"]
    report = client.get(f"/api/tests/{test_id}/report.json").json()
    assert report["limit_indications"] == {"follow": 1}


def test_by_default_the_service_stops_it_under_control(client):
    test_id = create_and_start(client, **MRAC)
    rec = wait_for(client, test_id, timeout_s=60.0)
    assert rec["status"] == "aborted" and "does not follow its target" in rec["reason"]
    assert rec["limits"]["follow"]["action"] == "controlled_stop" and "follow" not in rec["limits"]["actions"]
    (trip,) = [e for e in rec["events"] if e["kind"] == "limit_trip"]
    assert trip["values"]["detector"] == "not_following" and trip["values"]["action"] == "controlled_stop"
