"""Commissioning through the service (backend.commissioning, backend.api.commissioning, backend.rig_in_force):
the excitation runs as a record of its own on a simulated rig unlike its rig file, the fit after it finds that
rig, the commissioned rig file becomes the service's rig (also after a restart), and every refusal says why."""

from __future__ import annotations

import json
import time

import pytest
from conftest import AUTH, create_and_start, make_settings, wait_for
from fastapi.testclient import TestClient
from pydantic import ValidationError

from backend.app import create_app
from sim.rig import DEFAULT_RIG

#: the simulated rig as it truly is: a heavier table on a softer oil column than the rig file says
PLANT = {"mass_kg": 3000.0, "bulk_modulus_pa": 4.5e8}
PLANT_SET = " ".join(f"{k}={v:g}" for k, v in PLANT.items())
BODY = {"supply_bar": 100, "isolator": "IUT_a", "speed": 20, "operator_name": "C. Ferri"}


def commission(client, **overrides) -> dict:
    r = client.post("/api/commissioning", json={**BODY, **overrides}, headers=AUTH)
    assert r.status_code == 201, r.text
    return r.json()


def wait_result(client, cid: int, timeout_s: float = 120.0) -> dict:
    """The commissioning once its fit has ended (the record's state, never a fixed wait)."""
    deadline = time.monotonic() + timeout_s
    seen = set()
    while time.monotonic() < deadline:
        res = client.get(f"/api/commissioning/{cid}").json()
        seen.add(res["state"])
        if res["state"] not in ("ready", "running", "fitting"):
            res["seen"] = seen
            return res
        time.sleep(0.1)
    raise AssertionError(f"commissioning {cid} still {res['state']} after {timeout_s} s")


@pytest.mark.slow  # a whole commissioning and its fit: scripts/test.sh --quick leaves it out
def test_a_rig_unlike_its_file_is_commissioned_trusted_and_becomes_the_services_rig(tmp_path):
    settings = make_settings(tmp_path, plant_set=PLANT_SET)
    with TestClient(create_app(settings)) as client:
        rig = client.get("/api/rig").json()
        assert rig["rig"]["plant_changes"] == PLANT and "unlike the rig file" in rig["rig"]["detail"]
        assert rig["rig_file"]["in_force"]["how"] == "defaults"
        rec = commission(client)
        cid = rec["id"]
        assert rec["profile"]["kind"] == "commissioning" and rec["controller"] == "excitation"
        assert rec["operator_name"] == "C. Ferri (through automation)"
        assert rec["limits"]["displacement_m"] == pytest.approx(0.002)
        assert "at most +-2 mm about where it rests" in rec["profile"]["what"]
        res = wait_result(client, cid)
        assert res["state"] == "trusted", res["words"]
        assert "fitting" in res["seen"]  # the state between the run's end and the result
        assert res["status"] == "completed" and res["plant_changes"] == PLANT
        est = res["identification"]["fit"]["estimates"]
        assert est["mass_kg"]["value"] == pytest.approx(3000.0, rel=0.05) and est["mass_kg"]["unit"] == "kg"
        assert est["bulk_modulus_pa"]["value"] == pytest.approx(4.5e8, rel=0.05)
        assert res["declared"]["mass_kg"] == DEFAULT_RIG.mass_kg
        response = res["identification"]["response"]
        assert len(response["frequency_hz"]) >= 20
        assert len(response["velocity_per_volt"]["measured"]["magnitude"]) == len(response["frequency_hz"])
        # the record is a run like any other: its samples, its events, the verdict in words
        record = client.get(f"/api/tests/{cid}").json()
        assert record["samples_stored"] > 15000
        verdict = [e for e in record["events"] if e["kind"] == "commissioning"]
        assert len(verdict) == 1 and verdict[0]["values"]["trusted"] and "trusted" in verdict[0]["message"]
        assert client.get(f"/api/tests/{cid}/report.pdf").status_code == 422  # its result is this page's
        # the rig file, downloaded
        r = client.get(f"/api/commissioning/{cid}/rig.json")
        assert r.status_code == 200 and "attachment" in r.headers["content-disposition"]
        data = r.json()
        assert data["mass_kg"] == pytest.approx(3000.0, rel=0.05) and data["commissioning"]["trusted"]
        # applied: /api/rig, the strip's state and the next tests use it
        assert client.post(f"/api/commissioning/{cid}/apply").status_code == 401
        r = client.post(f"/api/commissioning/{cid}/apply", json={"operator_name": "C. Ferri"}, headers=AUTH)
        assert r.status_code == 200, r.text
        assert r.json()["in_force"]["how"] == "applied" and "note" not in r.json()["in_force"]
        rig = client.get("/api/rig").json()
        assert rig["rig_file"]["name"] == data["name"]
        assert rig["rig_file"]["in_force"]["by"] == "C. Ferri (through automation)"
        assert rig["rig_file"]["commissioning"]["trusted"] is True
        mass = next(p for p in rig["parameters"] if p["name"] == "mass_kg")
        assert mass["value"] == pytest.approx(3000.0, rel=0.05)
        brief = client.get("/api/rig/state").json()["rig_file"]
        assert brief["name"] == data["name"] and brief["commissioned"] and brief["commissioning_id"] == cid
        applied = [e for e in client.get(f"/api/tests/{cid}").json()["events"]
                   if (e["values"] or {}).get("action") == "apply_rig"]
        assert applied and "made the service's rig by C. Ferri (through automation)" in applied[0]["message"]
        # the console's manual motion takes the rig in force: it settles within 0.05 mm, there and back
        for position_m in (0.001, 0.0):
            body = {"position_m": position_m, "speed_m_per_s": 0.005, "isolator": "IUT_a", "supply_bar": 100}
            r = client.post("/api/rig/move", json=body, headers=AUTH)
            assert r.status_code == 201, r.text
            assert wait_for(client, r.json()["id"])["status"] == "completed"
            assert client.get("/api/rig/state").json()["table_position_m"] == pytest.approx(position_m, abs=5e-5)
        test_id = create_and_start(client)
        rec = wait_for(client, test_id)
        assert rec["status"] == "completed" and rec["rig"] == data["name"]
        assert rec["scenario"]["rig_changes"]["mass_kg"] == pytest.approx(3000.0, rel=0.05)
        assert rec["scenario"]["plant_changes"] == PLANT  # the record says the plant was not its rig file
        assert rec["summary"]["tracking_verdict"]["words"]
        # judged with the commissioned latency's uncertainty (the job carries the rig file's commissioning facts)
        assert rec["summary"]["tracking_verdict"]["latency_std_s"] > 0
    # a restart without --rig-file keeps the applied rig; with --rig-file that file wins
    with TestClient(create_app(make_settings(tmp_path, plant_set=PLANT_SET))) as client:
        rig = client.get("/api/rig").json()
        assert rig["rig_file"]["name"] == data["name"] and rig["rig_file"]["in_force"]["how"] == "applied"
    other = tmp_path / "other.json"
    other.write_text(json.dumps({"name": "Lab B rig", "mass_kg": 900.0}))
    with TestClient(create_app(make_settings(tmp_path, rig_file=other))) as client:
        rig = client.get("/api/rig").json()
        assert rig["rig_file"]["name"] == "Lab B rig" and rig["rig_file"]["in_force"]["how"] == "rig_file"
        r = client.post(f"/api/commissioning/{cid}/apply", headers=AUTH)
        assert r.status_code == 200 and "--rig-file" in r.json()["in_force"]["note"]


def test_refusals_say_what_is_wrong_and_nothing_moves(tmp_path):
    with TestClient(create_app(make_settings(tmp_path))) as client:
        assert client.post("/api/commissioning", json=BODY).status_code == 401
        for field, value, limit in (("max_stroke_m", 0.5, "[0.0002, 0.01] m"),
                                    ("max_velocity_m_per_s", 0.001, "[0.01, 0.1] m/s")):
            r = client.post("/api/commissioning", json={**BODY, field: value}, headers=AUTH)
            assert r.status_code == 422, r.text
            assert (r.json()["field"], r.json()["value"], r.json()["limit"]) == (field, value, limit)
        r = client.post("/api/commissioning", json={**BODY, "supply_bar": 500}, headers=AUTH)
        assert r.status_code == 422 and r.json()["field"] == "supply_bar"
        r = client.post("/api/commissioning", json={**BODY, "isolator": "nope"}, headers=AUTH)
        assert r.status_code == 422 and r.json()["field"] == "isolator"
        r = client.post("/api/commissioning", json={**BODY, "speed": 1000}, headers=AUTH)
        assert r.status_code == 422 and r.json()["field"] == "speed"
        assert client.get("/api/tests").json() == []  # nothing created by a refusal
        test_id = create_and_start(client, speed=1.0, profile={"cycles": 40})
        r = client.post("/api/commissioning", json=BODY, headers=AUTH)
        assert r.status_code == 409 and f"test {test_id} is running" in r.json()["detail"]
        assert client.post(f"/api/tests/{test_id}/abort").status_code == 200
        wait_for(client, test_id)
        assert [t["id"] for t in client.get("/api/tests").json()] == [test_id]
        assert client.get(f"/api/commissioning/{test_id}").status_code == 404  # a test, not a commissioning
        assert client.get("/api/commissioning/999").status_code == 404
    with pytest.raises(ValidationError, match="simulated rig only"):
        make_settings(tmp_path, rig="udp://127.0.0.1:5555", plant_set="mass_kg=3000")
    with pytest.raises(ValidationError, match="mas_kg"):
        make_settings(tmp_path, plant_set="mas_kg=3000")


def test_a_stopped_commissioning_is_not_trusted_and_cannot_be_applied(tmp_path):
    with TestClient(create_app(make_settings(tmp_path))) as client:
        cid = commission(client, speed=1)["id"]
        deadline = time.monotonic() + 30
        while client.get(f"/api/tests/{cid}").json()["time_s"] < 0.5 and time.monotonic() < deadline:
            time.sleep(0.05)
        assert client.post(f"/api/tests/{cid}/stop").status_code == 200  # stoppable, as a test
        res = wait_result(client, cid)
        assert res["status"] == "stopped" and res["state"] == "not_trusted"
        problems = res["identification"]["problems"]
        assert problems[0].startswith("the run ended stopped") and "did not run to its end" in problems[1]
        r = client.post(f"/api/commissioning/{cid}/apply", headers=AUTH)
        assert r.status_code == 409 and "not trusted" in r.json()["detail"] and "did not run to its end" in \
            r.json()["detail"]
        assert client.get(f"/api/commissioning/{cid}/rig.json").status_code == 409
        assert client.get("/api/rig").json()["rig_file"]["in_force"]["how"] == "defaults"


def test_a_fit_that_fails_keeps_the_record_and_is_done_again_after_a_restart(tmp_path, monkeypatch):
    import sim.commission.identify as commission_module

    def broken(*_args, **_kwargs):
        raise RuntimeError("the fit broke on purpose")

    settings = make_settings(tmp_path)
    monkeypatch.setattr(commission_module, "identify", broken)
    with TestClient(create_app(settings)) as client:
        cid = commission(client, speed=1)["id"]
        while client.get(f"/api/tests/{cid}").json()["time_s"] < 0.3:
            time.sleep(0.05)
        assert client.post(f"/api/tests/{cid}/abort").status_code == 200  # abortable, as a test
        res = wait_result(client, cid)
        assert res["status"] == "aborted" and res["state"] == "fit_failed"
        assert "RuntimeError: the fit broke on purpose" in res["error"] and "keeps every sample" in res["words"]
        csv = client.get(f"/api/tests/{cid}/data.csv").text.splitlines()
        assert len(csv) > 100  # every sample kept
        events = client.get(f"/api/tests/{cid}").json()["events"]
        assert any(e["kind"] == "commissioning" and e["values"]["state"] == "fit_failed" for e in events)
    # a fit the service did not finish (the summary still says fitting) is done again at the next start
    from backend import db, store

    engine = db.make_engine(settings.resolved_database_url)
    with db.session_factory(engine)() as session:
        test = store.get_test(session, cid)
        test.summary = {**test.summary, "commissioning": {"state": "fitting"}}
        session.commit()
    engine.dispose()
    monkeypatch.undo()
    with TestClient(create_app(settings)) as client:
        res = wait_result(client, cid)
        assert res["state"] == "not_trusted" and "did not run to its end" in res["words"]
        assert "second attempt" not in res["words"]  # other bounds cannot cure a run that never ended
