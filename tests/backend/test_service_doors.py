"""The service's doors (issue 21, part 5): the body cap, the bounded pool of token-free heavy work, cross-site
refusals, the Host allow-list, the database file's mode, ids never reused, an abort that answers once the test
has ended. Timings (a 100 MB body, /api/health meanwhile, RSS) are measured by scripts/bench_doors.py."""

from __future__ import annotations

import logging
import os
import sqlite3
import stat
import threading
import time

import aio
import pytest
from conftest import AUTH, TOKEN, make_settings, sine_test, wait_for
from fastapi.routing import APIRoute
from fastapi.testclient import TestClient
from starlette.websockets import WebSocketDisconnect

from backend.app import create_app
from backend.checks import CheckPool
from backend.doors import SAFE_METHODS, ServiceDoors
from backend.errors import ApiError

FOREIGN = "http://evil.example"
SAME = "http://testserver"


# --- the body cap ----------------------------------------------------------------------------------------------
def _scope(headers: dict, method: str = "POST", path: str = "/api/tests/check") -> dict:
    return {"type": "http", "method": method, "path": path, "raw_path": path.encode(), "query_string": b"",
            "headers": [(k.lower().encode(), v.encode()) for k, v in headers.items()], "scheme": "http",
            "server": ("127.0.0.1", 8000), "client": ("127.0.0.1", 5000), "root_path": "", "http_version": "1.1"}


def _drive(doors: ServiceDoors, scope: dict, chunks) -> tuple[list, int]:
    """Run the middleware on ``scope``; the client sends ``chunks`` (an iterator of bytes) as the body. Returns
    what was sent back and how many body messages were taken from the client."""
    sent, taken = [], 0

    async def receive():
        nonlocal taken
        try:
            chunk = next(chunks)
        except StopIteration:
            return {"type": "http.request", "body": b"", "more_body": False}
        taken += 1
        return {"type": "http.request", "body": chunk, "more_body": True}

    async def send(message):
        sent.append(message)

    aio.run(doors(scope, receive, send))
    return sent, taken


def test_a_body_over_the_cap_is_413_before_it_is_read():
    called = []

    async def app(scope, receive, send):
        called.append(scope["path"])

    doors = ServiceDoors(app, max_body_bytes=1024 * 1024, allowed_hosts=["localhost"])
    body = iter(b"x" * 65536 for _ in range(1600))  # 100 MB, if anyone read it
    sent, taken = _drive(doors, _scope({"host": "localhost:8000", "content-type": "application/json",
                                        "content-length": str(100 * 1024 * 1024)}), body)
    assert sent[0]["status"] == 413
    assert b"max_body_bytes" in sent[1]["body"] and b"at most 1048576 bytes" in sent[1]["body"]
    assert called == [] and taken == 0  # the application never ran, not one byte was read


def test_a_chunked_body_is_counted_and_stopped_at_the_cap():
    async def app(scope, receive, send):  # reads the whole body, as FastAPI does before a route
        while (await receive()).get("more_body"):
            pass
        await send({"type": "http.response.start", "status": 200, "headers": []})
        await send({"type": "http.response.body", "body": b"read it all"})

    doors = ServiceDoors(app, max_body_bytes=1024 * 1024, allowed_hosts=["localhost"])
    body = iter(b"x" * 65536 for _ in range(1600))
    sent, taken = _drive(doors, _scope({"host": "localhost", "content-type": "application/json",
                                        "transfer-encoding": "chunked"}), body)
    assert [m.get("status") for m in sent if m["type"] == "http.response.start"] == [413]
    assert b"read it all" not in b"".join(m.get("body", b"") for m in sent)
    assert taken == 1024 * 1024 // 65536 + 1  # stopped at the first chunk past the cap


def test_the_service_answers_413_with_what_is_allowed(tmp_path):
    with TestClient(create_app(make_settings(tmp_path, max_body_bytes=65536))) as client:
        r = client.post("/api/tests/check", content=b"[" + b"0," * 40000 + b"0]",
                        headers={"content-type": "application/json"})
        assert r.status_code == 413, r.text
        assert r.json()["limit"] == "<= 65536 bytes" and "max_body_bytes" in r.json()["detail"]

        def chunks():
            for _ in range(100):
                yield b" " * 4096

        r = client.post("/api/tests/check", content=chunks(), headers={"content-type": "application/json"})
        assert r.status_code == 413, r.text
        assert client.post("/api/tests/check", json=sine_test()).json()["ok"] is True  # a normal body passes


# --- the bounded pool of token-free heavy work ---------------------------------------------------------------
@pytest.mark.slow  # check workers kept busy and retired: scripts/test.sh --quick leaves it out
def test_the_check_pool_refuses_when_busy_and_retires_a_big_worker():
    import multiprocessing as mp

    context = mp.get_context("forkserver")
    pool = CheckPool(lambda: context, workers=1, queue=0, modules=())
    try:
        first = threading.Thread(target=pool.run, args=("sleep", time.sleep, 1.5))
        first.start()
        deadline = time.monotonic() + 5
        while pool.in_flight == 0 and time.monotonic() < deadline:
            time.sleep(0.01)
        with pytest.raises(ApiError) as refused:
            pool.run("sleep", time.sleep, 0)
        assert refused.value.status == 503 and refused.value.headers == {"Retry-After": "2"}
        assert "at most 1 at a time" in refused.value.detail
        first.join()
        worker = pool.run("pid", os.getpid)
        assert worker != os.getpid() and pool.run("pid", os.getpid) == worker  # small: kept (imports paid once)
    finally:
        pool.shutdown()
    pool = CheckPool(lambda: context, workers=1, queue=0, max_rss_bytes=1, modules=())
    try:  # larger than its limit after a job: retired, its memory goes with it; a fresh worker takes its place
        assert pool.run("pid", os.getpid) != pool.run("pid", os.getpid) and pool.retired == 2
    finally:
        pool.shutdown()


@pytest.mark.slow  # check workers kept busy: scripts/test.sh --quick leaves it out
def test_a_history_check_is_refused_503_while_the_checks_are_busy(tmp_path):
    with TestClient(create_app(make_settings(tmp_path, check_workers=1, check_queue=0))) as client:
        history = {**sine_test(speed=1.0), "profile": {"kind": "history", "ground_motion": "near_field_short",
                                                            "scale": 0.5}}
        busy = threading.Thread(target=client.app.state.checks.run, args=("sleep", time.sleep, 3.0))
        busy.start()
        deadline = time.monotonic() + 5
        while client.app.state.checks.in_flight == 0 and time.monotonic() < deadline:
            time.sleep(0.01)
        r = client.post("/api/tests/check", json=history)
        assert r.status_code == 503, r.text
        assert r.headers["retry-after"] == "2" and "try again" in r.json()["detail"]
        assert client.post("/api/tests/check", json=sine_test()).status_code == 200  # a sine is checked inline
        busy.join()
        r = client.post("/api/tests/check", json=history)
        assert r.status_code == 200 and r.json()["ok"] is True, r.text
        # an input refused in the worker comes back as the same 422-style refusal, naming the field
        history["profile"]["ground_motion"] = {"time_s": [0.0, 0.01, 0.02], "acceleration_m_per_s2": [0.0, 1.0]}
        r = client.post("/api/tests/check", json=history)
        assert r.status_code == 200 and r.json()["ok"] is False and r.json()["field"].startswith("profile"), r.text
        r = client.post("/api/ground-motions/read-at2", json={"filename": "x.AT2", "text": "not a record"})
        assert r.status_code == 422 and "x.AT2" in r.json()["detail"], r.text


def test_a_big_body_is_refused_503_before_it_is_read_while_the_checks_are_full():
    """Four parallel 200 000-sample checks: two are admitted (one checked, one waiting), the others get 503 at once,
    their 6 MB never parsed by the event loop."""
    from backend.checks import BIG_BODY_BYTES, HeavyBodyGate

    class Full:
        workers, capacity = 1, 2

        def admit(self):
            return False

    called = []

    async def app(scope, receive, send):
        called.append(scope["path"])

    gate = HeavyBodyGate(app, Full())
    for path, length in (("/api/tests/check", BIG_BODY_BYTES + 1), ("/api/ground-motions/read-at2", 5_000_000)):
        sent, taken = _drive(gate, _scope({"host": "localhost", "content-type": "application/json",
                                           "content-length": str(length)}, path=path), iter([b"x" * 65536] * 100))
        assert sent[0]["status"] == 503 and (b"retry-after", b"2") in sent[0]["headers"]
        assert b"try again" in sent[1]["body"] and taken == 0 and called == []
    sent, _taken = _drive(gate, _scope({"host": "localhost", "content-type": "application/json",
                                        "content-length": "300"}), iter([]))
    assert called == ["/api/tests/check"]  # a small body (a sine's check) is never held at the gate


# --- cross-site requests ---------------------------------------------------------------------------------------
def _api_routes(routes):
    for route in routes:
        if isinstance(route, APIRoute):
            yield route
        elif getattr(route, "original_router", None) is not None:  # FastAPI's included router
            yield from _api_routes(route.original_router.routes)
        elif getattr(route, "routes", None):
            yield from _api_routes(route.routes)


def _state_changing_routes(app) -> list[tuple[str, str]]:
    """Every route that changes state, from the app's router (and its OpenAPI schema, in case a router hides
    one from the walk): a route added later is in the list by itself."""
    found = {(m, r.path) for r in _api_routes(app.routes) for m in r.methods - SAFE_METHODS}
    found |= {(m.upper(), path) for path, item in app.openapi()["paths"].items() for m in item
              if m.upper() not in SAFE_METHODS}
    return sorted((m, p.replace("{test_id}", "1").replace("{name}", "x")) for m, p in found)


def test_every_state_changing_route_refuses_a_foreign_origin(client):
    routes = _state_changing_routes(client.app)
    paths = {p for _m, p in routes}
    # the enumeration sees the routes that matter (and any added later)
    assert {"/api/tests/1/abort", "/api/tests/1/stop", "/api/tests/1/start", "/api/tests", "/api/rig/move",
            "/api/rig/zero", "/api/commissioning/1/apply", "/api/tests/check", "/api/isolators/x"} <= paths
    for method, path in routes:
        for origin in (FOREIGN, "null", "http://testserver.evil.example", "http://testserver:8001"):
            r = client.request(method, path, content=b"{}", headers={**AUTH, "Origin": origin,
                                                                     "Content-Type": "application/json"})
            assert r.status_code == 403, (method, path, origin, r.status_code, r.text)
            assert "cross-origin request refused" in r.json()["detail"]
        r = client.request(method, path, content=b"{}", headers={**AUTH, "Sec-Fetch-Site": "cross-site",
                                                                 "Content-Type": "application/json"})
        assert r.status_code == 403, (method, path, r.text)


def test_a_text_plain_abort_does_not_abort(client):
    r = client.post("/api/tests?start=true", json=sine_test(profile={"cycles": 200}, speed=1.0), headers=AUTH)
    assert r.status_code == 201, r.text
    test_id = r.json()["id"]
    for headers in ({"Origin": FOREIGN, "Content-Type": "text/plain"}, {"Content-Type": "text/plain"},
                    {"Origin": SAME, "Content-Type": "text/plain"},
                    {"Content-Type": "application/x-www-form-urlencoded"}, {"Origin": SAME}):
        r = client.post(f"/api/tests/{test_id}/abort", content=b"x" if "Content-Type" in headers else None,
                        headers=headers)
        assert r.status_code in (403, 415), (headers, r.status_code, r.text)
    assert client.get(f"/api/tests/{test_id}").json()["status"] == "running"
    # the console's own page: same Origin and its header (no body), or JSON
    r = client.post(f"/api/tests/{test_id}/abort", headers={"Origin": SAME, "X-Isorig-Client": "console"})
    assert r.status_code == 200, r.text
    assert wait_for(client, test_id)["status"] == "aborted"


def test_same_origin_json_and_clients_without_origin_are_served(client):
    assert client.post("/api/tests/check", json=sine_test(), headers={"Origin": SAME}).status_code == 200
    r = client.post("/api/tests", json=sine_test(), headers={**AUTH, "Origin": SAME})
    assert r.status_code == 201, r.text
    test_id = r.json()["id"]
    # curl -X POST .../start with the token: no Origin, no body (not a browser)
    assert client.post(f"/api/tests/{test_id}/start", headers=AUTH).status_code == 200
    assert client.post(f"/api/tests/{test_id}/abort").status_code == 200  # curl -X POST .../abort, no token
    assert client.get("/api/health", headers={"Origin": FOREIGN}).status_code == 200  # a read is no action


def test_websockets_refuse_a_foreign_origin(client):
    for path in ("/ws/live", "/ws/tests/1"):
        with pytest.raises(WebSocketDisconnect) as refused:
            with client.websocket_connect(path, headers={"Origin": FOREIGN}) as ws:
                ws.receive_json()
        assert refused.value.code == 1008
    with client.websocket_connect("/ws/live", headers={"Origin": SAME}) as ws:
        assert ws.receive_json()["type"] == "hello"


# --- the Host allow-list ---------------------------------------------------------------------------------------
def test_a_host_not_on_the_allow_list_is_400(client):
    r = client.get("/api/health", headers={"Host": "evil.example"})
    assert r.status_code == 400, r.text
    assert "ISORIG_ALLOWED_HOSTS" in r.json()["detail"] and "--allowed-host" in r.json()["detail"]
    assert client.get("/api/tests", headers={"Host": "evil.example:8000"}).status_code == 400
    with pytest.raises(WebSocketDisconnect):
        with client.websocket_connect("/ws/live", headers={"Host": "evil.example"}) as ws:
            ws.receive_json()
    for host in ("localhost:8000", "127.0.0.1:8000", "[::1]:8000", "LOCALHOST", "testserver"):
        assert client.get("/api/health", headers={"Host": host}).status_code == 200, host


def test_the_default_allow_list_is_the_loopback_names_and_the_bound_address(tmp_path):
    settings = make_settings(tmp_path, allowed_hosts="", host="192.168.1.20")
    assert settings.host_allow_list() == ["localhost", "127.0.0.1", "::1", "192.168.1.20"]
    assert make_settings(tmp_path, allowed_hosts="", host="0.0.0.0").host_allow_list() == [
        "localhost", "127.0.0.1", "::1"]
    assert "rig.lab" in make_settings(tmp_path, allowed_hosts="rig.lab, [fe80::1]").host_allow_list()
    with TestClient(create_app(make_settings(tmp_path, allowed_hosts=""))) as client:  # testserver: not allowed
        assert client.get("/api/health").status_code == 400
        assert client.get("/api/health", headers={"Host": "localhost:8000"}).status_code == 200


# --- the database file -------------------------------------------------------------------------------------------
def test_the_database_is_owner_only(tmp_path, caplog):
    data = tmp_path / "new" / "data"
    with TestClient(create_app(make_settings(data))):
        pass
    db = data / "isorig.db"
    assert stat.S_IMODE(db.stat().st_mode) == 0o600
    assert stat.S_IMODE(data.stat().st_mode) == 0o700  # a directory the service made
    assert not any(stat.S_IMODE(p.stat().st_mode) & 0o077 for p in data.iterdir())

    shared = tmp_path / "shared"
    shared.mkdir(mode=0o755)
    os.chmod(shared, 0o755)
    sqlite3.connect(shared / "isorig.db").execute("PRAGMA journal_mode=WAL").connection.close()  # an existing
    # database (an empty file is refused: test_input_at_the_door.py)
    os.chmod(shared / "isorig.db", 0o644)
    with caplog.at_level(logging.WARNING, logger="isorig"):
        with TestClient(create_app(make_settings(shared))):
            pass
    assert stat.S_IMODE((shared / "isorig.db").stat().st_mode) == 0o600
    assert stat.S_IMODE(shared.stat().st_mode) == 0o755  # a directory the user gave is left as it is
    assert any("mode 0644" in r.getMessage() and "made 0600" in r.getMessage() for r in caplog.records)


# --- ids -----------------------------------------------------------------------------------------------------------
def test_a_deleted_tests_id_is_never_given_again(tmp_path):
    settings = make_settings(tmp_path)
    with TestClient(create_app(settings)) as client:
        first = client.post("/api/tests", json=sine_test(), headers=AUTH).json()["id"]
        newest = client.post("/api/tests", json=sine_test(), headers=AUTH).json()["id"]
        assert client.delete(f"/api/tests/{newest}", headers=AUTH).status_code == 204
        again = client.post("/api/tests", json=sine_test(), headers=AUTH).json()["id"]
        assert again == newest + 1 and first < newest
        assert client.delete(f"/api/tests/{again}", headers=AUTH).status_code == 204
    with TestClient(create_app(settings)) as client:  # nor after a restart
        assert client.post("/api/tests", json=sine_test(), headers=AUTH).json()["id"] == again + 1


def test_the_migration_keeps_the_records_and_burns_deleted_ids(tmp_path):
    """An old database (schema 0005, no AUTOINCREMENT): test 1 with samples and a cycle, test 2, test 3 deleted
    (only its events remain). After the upgrade everything is there and the next id is 4."""
    from alembic import command
    from sqlalchemy import create_engine

    from backend import db

    path = tmp_path / "isorig.db"
    url = f"sqlite:///{path}"
    engine = create_engine(url)
    cfg = db.alembic_config(url)
    with engine.begin() as connection:
        cfg.attributes["connection"] = connection
        command.upgrade(cfg, "0005")
    engine.dispose()
    con = sqlite3.connect(path)
    row = ("2026-11-20 10:00:00", "completed", "", "IUT_a", 100.0, "servo", 1.0, "simulated", "{}", "{}", "{}",
           1.0, 1, 10, 1.0)
    for test_id in (1, 2, 3):
        con.execute("INSERT INTO tests (id, created_at, status, label, isolator, supply_bar, controller, speed, "
                    "driver, request, scenario, limits, duration_s, cycles_total, samples_stored, time_s) VALUES "
                    "(?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?)", (test_id, *row))
        con.execute("INSERT INTO events (test_id, created_at, kind, actor, message, \"values\") VALUES "
                    "(?, '2026-11-20', 'operator', 'operator', 'created', '{}')", (test_id,))
    con.execute("INSERT INTO sample_chunks (test_id, seq, t0_s, n_rows, n_columns, codec, data) VALUES "
                "(1, 0, 0.0, 10, 3, 'x', x'00')")
    con.execute("INSERT INTO cycles (test_id, cycle, block, t_start_s, t_end_s, metrics, n_points, codec, "
                "loop_data) VALUES (1, 1, 0, 0.0, 0.5, '{}', 2, 'x', x'00')")
    con.execute("DELETE FROM tests WHERE id = 3")
    con.commit()
    con.close()

    db.upgrade(db.make_engine(url))
    con = sqlite3.connect(path)
    assert con.execute("SELECT count(*) FROM sample_chunks WHERE test_id = 1").fetchone()[0] == 1
    assert con.execute("SELECT count(*) FROM cycles WHERE test_id = 1").fetchone()[0] == 1
    assert [r[0] for r in con.execute("SELECT id FROM tests ORDER BY id")] == [1, 2]
    assert "AUTOINCREMENT" in con.execute("SELECT sql FROM sqlite_master WHERE name = 'tests'").fetchone()[0]
    assert con.execute("PRAGMA foreign_key_check").fetchall() == []
    con.close()
    with TestClient(create_app(make_settings(tmp_path))) as client:
        assert client.post("/api/tests", json=sine_test(), headers=AUTH).json()["id"] == 4


# --- abort ---------------------------------------------------------------------------------------------------------
def test_abort_answers_once_the_test_has_ended_and_the_next_starts_at_once(client):
    # 1 mm: wherever the abort finds the table, it is within the start tolerance (2 mm) of the next test's zero,
    # so a 409 could only be 'test N is running' (a 10 mm sine aborted late on a loaded machine was 2.19 mm off)
    slow = sine_test(profile={"cycles": 200, "amplitude_m": 0.001, "frequency_hz": 0.5}, speed=1.0)
    for _ in range(10):
        r = client.post("/api/tests?start=true", json=slow, headers=AUTH)
        assert r.status_code == 201, r.text
        r = client.post(f"/api/tests/{r.json()['id']}/abort")
        assert r.status_code == 200 and r.json()["status"] == "aborted", r.text
        assert client.get("/api/rig/state").json()["status"] != "running"
    r = client.post("/api/tests?start=true", json=sine_test(), headers=AUTH)
    assert r.status_code == 201, r.text  # never 409 "test N is running"
    assert wait_for(client, r.json()["id"])["status"] == "completed"


def test_an_abort_that_has_not_ended_in_time_is_202_with_where_to_look(tmp_path):
    with TestClient(create_app(make_settings(tmp_path, abort_wait_s=0.0))) as client:
        r = client.post("/api/tests?start=true", json=sine_test(profile={"cycles": 200}, speed=1.0), headers=AUTH)
        test_id = r.json()["id"]
        r = client.post(f"/api/tests/{test_id}/abort", headers={"Authorization": f"Bearer {TOKEN}"})
        assert r.status_code == 202 and r.headers["location"] == f"/api/tests/{test_id}", r.text
        assert wait_for(client, test_id)["status"] == "aborted"
