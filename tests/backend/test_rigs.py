"""Several rigs on one database: each service drives the rig it is named for (settings.rig_name), starts only its
rig's tests, and asks the store about its own rig only (tests left running, the table's last position, the last
event, the rig in force); History lists every rig's tests. Two services in this process on one SQLite file."""

from __future__ import annotations

import json

import numpy as np
import pytest
from conftest import AUTH, create_and_start, make_settings, sine_test, wait_for
from fastapi.testclient import TestClient
from pydantic import ValidationError

from backend import rig_in_force, store
from backend.app import create_app
from backend.db import make_engine, session_factory, upgrade
from backend.rig_lock import RigBusy
from backend.settings import DEFAULT_RIG_NAME, Settings, check_rig_name
from isorig.cli import main as isorig_main
from sim.samples import N_FIELDS, SAMPLE_FIELDS


@pytest.mark.parametrize("name", ["rig-1", "A", "hall_2.rig-B", "x" * 64])
def test_allowed_rig_names(name):
    assert check_rig_name(name) == name
    assert Settings(rig_name=name, operator_token="t").rig_name == name


@pytest.mark.parametrize("name", ["", "x" * 65, "rig a", "a/b", "../up", "rig\n", "é", "rig;drop"])
def test_other_rig_names_are_refused_saying_what_is_allowed(name, capsys):
    with pytest.raises(ValidationError) as info:
        Settings(rig_name=name, operator_token="t")
    assert "1-64 characters: letters, digits, '-', '_' and '.'" in str(info.value)
    assert isorig_main(["serve", "--rig-name", name]) == 2  # one clear line, no traceback, nothing served
    err = capsys.readouterr().err
    assert "rig_name" in err and "letters, digits" in err and "Traceback" not in err


def test_the_default_rig_name(monkeypatch):
    monkeypatch.delenv("ISORIG_RIG_NAME", raising=False)
    assert Settings(operator_token="t").rig_name == DEFAULT_RIG_NAME == "rig-1"
    monkeypatch.setenv("ISORIG_RIG_NAME", "hall-b")
    assert Settings(operator_token="t").rig_name == "hall-b"


def _record(session, rig_name: str, status: str, rows: int = 0):
    test = store.create_test(session, rig_name=rig_name, isolator="IUT_a", supply_bar=100.0, controller="pid",
                             speed=1.0, driver="simulated", request={}, scenario={}, limits={}, duration_s=1.0,
                             cycles_total=1, label=f"{rig_name} {status}")
    store.set_status(session, test, status)
    if rows:
        block = np.zeros((rows, N_FIELDS))
        block[:, 0] = np.arange(rows) * 1e-3
        block[:, SAMPLE_FIELDS.index("measured_displacement_m")] = 0.004 if rig_name == "rig-a" else -0.007
        store.append_samples(session, test, block)
    store.add_event(session, test.id, "status", f"{rig_name} test {test.id} {status}")
    return test


def test_the_store_answers_per_rig(tmp_path):
    engine = make_engine(f"sqlite:///{tmp_path / 'r.db'}")
    upgrade(engine)
    with session_factory(engine)() as s:
        a_done = _record(s, "rig-a", "completed", rows=10)
        b_done = _record(s, "rig-b", "completed", rows=10)
        a_running = _record(s, "rig-a", "running", rows=5)
        b_running = _record(s, "rig-b", "running", rows=5)
        store.add_event(s, None, "operator", "user isolator 'X' added")
        s.commit()
        assert store.rig_names(s) == ["rig-a", "rig-b"]
        assert [t.id for t in store.list_tests(s, rig_name="rig-b")] == [b_running.id, b_done.id]
        assert len(store.list_tests(s)) == 4
        # where each rig's table was left is that rig's own newest test
        test, row = store.last_sample(s, "rig-a")
        assert test.id == a_running.id and row["measured_displacement_m"][0] == pytest.approx(0.004)
        assert store.last_sample(s, "rig-c") is None
        # the last event of a rig: its own or one of no rig's, never another rig's
        assert store.last_event(s, "rig-b")["message"] == "user isolator 'X' added"
        store.add_event(s, a_done.id, "operator", "archived")
        s.commit()
        assert store.last_event(s, "rig-b")["message"] == "user isolator 'X' added"
        assert store.last_event(s, "rig-a")["message"] == "archived" and store.last_event(s, "rig-a")["rig_name"] \
            == "rig-a"
        # the audit log of one rig (and of no rig's), the newest first selected, given oldest first
        messages = [e["message"] for e in store.load_events(s, None, rig_name="rig-b")]
        assert messages == [f"rig-b test {b_done.id} completed", f"rig-b test {b_running.id} running",
                            "user isolator 'X' added"]
        assert [e["message"] for e in store.load_events(s, None, rig_name="rig-a", limit=2)] == \
            [f"rig-a test {a_running.id} running", "user isolator 'X' added", "archived"][1:]
        assert len(store.load_events(s, None)) == 6 and store.load_events(s, None, rig_name="rig-c") == \
            [e for e in store.load_events(s, None) if e["rig_name"] is None]
        # a restart of rig-b's service marks its own running test interrupted, and leaves rig-a's running
        assert store.mark_running_interrupted(s, "rig-b") == [b_running.id]
        s.commit()
        assert s.get(type(a_running), a_running.id).status == "running"
        assert s.get(type(b_running), b_running.id).status == "interrupted"
        assert store.mark_running_interrupted(s, "rig-b") == []
        assert b_done.status == "completed"
    engine.dispose()


def _service(tmp_path, db, rig_name: str, **overrides):
    return TestClient(create_app(make_settings(tmp_path / rig_name, database_url=db, rig_name=rig_name,
                                               **overrides)))


@pytest.mark.slow  # two services, a test on each: scripts/test.sh --quick leaves it out
def test_two_services_share_one_database_each_driving_its_own_rig(tmp_path):
    db = f"sqlite:///{tmp_path / 'shared.db'}"
    with _service(tmp_path, db, "rig-a") as a, _service(tmp_path, db, "rig-b") as b:
        assert a.get("/api/health").json()["rig_name"] == "rig-a"
        assert b.get("/api/rig").json()["rig_name"] == "rig-b"
        # a test runs on rig A for a while (real time); rig B is not blocked by it
        long_a = create_and_start(a, speed=1.0, profile={"frequency_hz": 0.5, "cycles": 4})
        assert a.get(f"/api/tests/{long_a}").json()["rig_name"] == "rig-a"
        b_test = create_and_start(b)
        rec_b = wait_for(b, b_test)
        assert rec_b["status"] == "completed" and rec_b["rig_name"] == "rig-b" and rec_b["samples_stored"] == 1500
        assert a.get(f"/api/tests/{long_a}").json()["status"] == "running"
        # the other rig's tests are refused by name: start, stop, abort, delete
        ready_a = a.post("/api/tests", json=sine_test(), headers=AUTH).json()["id"]
        r = b.post(f"/api/tests/{ready_a}/start", headers=AUTH)
        assert r.status_code == 409
        assert "belongs to the rig 'rig-a'" in r.json()["detail"] and "drives the rig 'rig-b'" in r.json()["detail"]
        for action in ("stop", "abort"):
            r = b.post(f"/api/tests/{long_a}/{action}", headers=AUTH)
            assert r.status_code == 409 and "belongs to the rig 'rig-a'" in r.json()["detail"], r.text
        r = b.delete(f"/api/tests/{ready_a}", headers=AUTH)
        assert r.status_code == 409 and "'rig-a'" in r.json()["detail"]
        assert a.get(f"/api/tests/{ready_a}").json()["status"] == "ready"  # untouched
        # the rig state is each rig's own: A runs, B is idle where its test left the table, B's last event
        state_b = b.get("/api/rig/state").json()
        assert state_b["status"] == "idle" and state_b["rig_name"] == "rig-b"
        assert state_b["position_source"] == f"end of test {b_test} (completed)"
        assert state_b["last_event"]["rig_name"] == "rig-b"
        state_a = a.get("/api/rig/state").json()
        assert state_a["status"] == "running" and state_a["test_id"] == long_a
        # a second service of rig B (a third app on the same database) is refused, and touches nothing of rig
        # A's (test_one_service_per_rig.py: real processes, a restart after the first died)
        with pytest.raises(RigBusy, match="the rig 'rig-b' is already driven by another"):
            _service(tmp_path, db, "rig-b")
        assert a.get(f"/api/tests/{long_a}").json()["status"] == "running"
        # History: every rig's tests, with their rig's name, from either service; filtered by rig
        for client in (a, b):
            listed = {t["id"]: t["rig_name"] for t in client.get("/api/tests").json()}
            assert listed[long_a] == "rig-a" and listed[b_test] == "rig-b" and listed[ready_a] == "rig-a"
            only_b = client.get("/api/tests", params={"rig_name": "rig-b"}).json()
            assert [t["id"] for t in only_b] == [b_test]
            assert client.get("/api/rigs").json()["on_record"] == ["rig-a", "rig-b"]
        assert a.get("/api/tests", params={"rig_name": "x" * 65}).status_code == 422
        events_b = a.get("/api/events", params={"rig_name": "rig-b"}).json()
        assert events_b and {e["rig_name"] for e in events_b} <= {"rig-b", None}
        assert any(e["test_id"] == b_test for e in events_b) and not any(e["test_id"] == long_a for e in events_b)
        assert len(a.get("/api/events", params={"limit": 2}).json()) == 2
        assert a.get("/api/events", params={"rig_name": ""}).status_code == 422
        r = a.post(f"/api/tests/{long_a}/stop", headers=AUTH)
        assert r.status_code == 200
        assert wait_for(a, long_a)["status"] == "stopped"


def test_a_move_and_a_commissioning_carry_the_rig_name(tmp_path):
    db = f"sqlite:///{tmp_path / 'shared.db'}"
    with _service(tmp_path, db, "hall.b_2") as b:
        r = b.post("/api/rig/move", json={"position_m": 0.002, "speed_m_per_s": 0.02, "isolator": "IUT_a",
                                          "supply_bar": 100}, headers=AUTH)
        assert r.status_code == 201, r.text
        assert wait_for(b, r.json()["id"])["rig_name"] == "hall.b_2"
        events = b.get(f"/api/tests/{r.json()['id']}").json()["events"]
        assert events and {e["rig_name"] for e in events} == {"hall.b_2"}
        r = b.post("/api/commissioning", json={"isolator": "IUT_a", "supply_bar": 100, "speed": 20},
                   headers=AUTH)
        assert r.status_code == 201, r.text
        assert r.json()["rig_name"] == "hall.b_2"
        b.post(f"/api/tests/{r.json()['id']}/abort", headers=AUTH)  # its fit is not what is tested here
        record = wait_for(b, r.json()["id"])
        assert record["rig_name"] == "hall.b_2" and {e["rig_name"] for e in record["events"]} == {"hall.b_2"}


def test_the_rig_in_force_is_kept_per_rig(tmp_path):
    rig_file = tmp_path / "old.json"
    rig_file.write_text(json.dumps({"name": "Old lab rig", "stroke_m": 0.1}))
    (tmp_path / "rig-in-force.json").write_text(json.dumps({"path": str(rig_file), "commissioning_id": 4,
                                                            "by": "ann", "at": "2026-11-01T10:00:00+00:00"}))
    # the pointer written before rigs were named is the default rig's, not another rig's sharing the data dir
    described, origin = rig_in_force.rig_in_force(make_settings(tmp_path))
    assert described.name == "Old lab rig" and origin["how"] == "applied"
    described, origin = rig_in_force.rig_in_force(make_settings(tmp_path, rig_name="rig-b"))
    assert origin["how"] == "defaults"
    data = {"name": "rig-b commissioned", "stroke_m": 0.12}
    described, origin = rig_in_force.apply(make_settings(tmp_path, rig_name="rig-b"), data, 9, "bob")
    assert (tmp_path / "rig-in-force.rig-b.json").exists()
    assert rig_in_force.rig_in_force(make_settings(tmp_path, rig_name="rig-b"))[0].name == "rig-b commissioned"
    assert rig_in_force.rig_in_force(make_settings(tmp_path))[0].name == "Old lab rig"
    assert rig_in_force.rig_in_force(make_settings(tmp_path, rig_name="rig-c"))[1]["how"] == "defaults"
    assert sorted(p.name for p in tmp_path.glob("rig-in-force*")) == ["rig-in-force.json",
                                                                     "rig-in-force.rig-b.json"]
