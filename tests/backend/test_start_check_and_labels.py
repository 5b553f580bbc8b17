"""Issue 34 item 5 at the service: the set-up check and POST /api/tests refuse an untapered start whose catch-up
is expected to trip a limit (IUT_b, 100 bar, 20 mm at 1.25 Hz: 410 mm/s 20 ms in against the pump's 391 mm/s),
naming taper_cycles; data.csv and the live stream say what the test's controller puts in model_m, ar_hat, ay_hat,
as_hat."""

import csv
import io

from conftest import AUTH, create_and_start, sine_test, wait_for

from sim.controllers import ADAPTED
from sim.records import column_key
from sim.samples import CSV_FIELDS, RECORD_FIELDS

MEASURED = {"isolator": "IUT_b", "supply_bar": 100, "speed": 1.0,
            "profile": {"amplitude_m": 0.02, "frequency_hz": 1.25, "cycles": 10, "taper_cycles": 0}}


def servo_labels(fields):
    declared = {a.column: f"{a.column}: {a.name} ({a.unit})" for a in ADAPTED["servo"]}
    return [declared.get(f, f) for f in fields]


def test_the_measured_start_is_refused_at_set_up(client):
    r = client.post("/api/tests/check", json=sine_test(**MEASURED))
    assert r.status_code == 200, r.text
    answer = r.json()
    assert answer["ok"] is False and answer["field"] == "taper_cycles" and answer["value"] == 0
    assert "taper_cycles >= 1 needed" in answer["detail"] and "157 mm/s from rest" in answer["detail"]
    assert "velocity limit tripped" in answer["detail"] and "limits.actions.velocity_m_per_s" in answer["detail"]
    assert answer["predicted_trip"]["detector"] == "velocity"  # what the rig model showed
    r = client.post("/api/tests", json=sine_test(**MEASURED), headers=AUTH)
    assert r.status_code == 422, r.text
    body = r.json()
    assert body["field"] == "profile.taper_cycles" and "taper_cycles >= 1 needed" in body["detail"]
    assert client.get("/api/tests").json() == []  # nothing kept


def test_a_tapered_start_passes_and_an_indicating_limit_lets_it_run(client):
    tapered = sine_test(**{**MEASURED, "profile": {**MEASURED["profile"], "taper_cycles": 1}})
    answer = client.post("/api/tests/check", json=tapered).json()
    assert answer["ok"] is True and answer["warnings"] == [], answer
    assert client.post("/api/tests", json=tapered, headers=AUTH).status_code == 201
    indicate = sine_test(**MEASURED, limits={"actions": {"velocity_m_per_s": "indicate"}})
    assert client.post("/api/tests/check", json=indicate).json()["ok"] is True


def test_data_csv_and_the_stream_name_the_servos_quantities(client):
    with client.websocket_connect("/ws/live") as ws:
        assert ws.receive_json()["type"] == "hello"
        test_id = create_and_start(client, speed=10.0)
        while True:
            m = ws.receive_json()
            if m["type"] == "samples":
                break
    assert m["columns"] == list(CSV_FIELDS)  # the keys stay
    assert m["labels"] == servo_labels(CSV_FIELDS) and m["labels"] != list(CSV_FIELDS)
    assert wait_for(client, test_id)["status"] == "completed"
    header = next(csv.reader(io.StringIO(client.get(f"/api/tests/{test_id}/data.csv").text)))
    assert header == servo_labels(RECORD_FIELDS)
    assert tuple(column_key(h) for h in header) == RECORD_FIELDS


def test_an_mrac_tests_csv_keeps_ar_hat_ay_hat_as_hat(client):
    test_id = create_and_start(client, controller="mrac")
    wait_for(client, test_id)
    header = next(csv.reader(io.StringIO(client.get(f"/api/tests/{test_id}/data.csv").text)))
    assert tuple(header) == RECORD_FIELDS
