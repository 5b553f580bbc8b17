"""Fixtures for the backend tests: a service on a temporary database, the operator token, test helpers."""

from __future__ import annotations

import os
import tempfile
import time
from pathlib import Path

import pytest
from fastapi.testclient import TestClient

from backend.app import create_app
from backend.models import FINAL_STATUSES
from backend.settings import Settings

TOKEN = "test-operator-token"
AUTH = {"Authorization": f"Bearer {TOKEN}"}


def sine_test(**overrides) -> dict:
    """A short, accelerated IUT_a test body (3 cycles at 2 Hz = 1.5 s of test time)."""
    body = {"isolator": "IUT_a", "supply_bar": 100, "controller": "servo", "speed": 20.0,
            "profile": {"kind": "sine", "amplitude_m": 0.01, "frequency_hz": 2.0, "cycles": 3, "taper_cycles": 1}}
    for key, value in overrides.items():
        if key == "profile":
            body["profile"] = {**body["profile"], **value}
        else:
            body[key] = value
    return body


def make_settings(tmp: Path, **overrides) -> Settings:
    # TestClient sends Host: testserver; the service answers only to the names it is told (backend.doors)
    # no report warm-up in the background (seconds of CPU beside the real-time tests): test_report_warm_up.py
    values = {"data_dir": tmp, "operator_token": TOKEN, "viewer": False, "commit_interval_s": 0.2,
              "allowed_hosts": "testserver", "report_warm_up": False}
    values.update(overrides)
    return Settings(**values)


@pytest.fixture(scope="session")
def postgres():
    """A real PostgreSQL server for the session (tests/backend/pg_server.py): ISORIG_TEST_POSTGRES_URL's, else one
    started from the installed binaries (scripts/test.sh installs Debian's postgresql), stopped at the end.
    ``postgres.database()`` gives a fresh database's URL. Skips only where there is no server to be had."""
    try:
        import psycopg  # noqa: F401
    except ImportError:
        pytest.skip("no PostgreSQL driver: pip install 'psycopg[binary]' (in the test extra)")
    from pg_server import ExternalServer, PostgresServer, find_bindir

    url = os.environ.get("ISORIG_TEST_POSTGRES_URL")
    if url:
        server = ExternalServer(url)
    else:
        bindir = find_bindir()
        if bindir is None:
            pytest.skip("no PostgreSQL server binaries (initdb, postgres) found: apt-get install postgresql, or "
                        "set ISORIG_TEST_POSTGRES_URL")
        server = PostgresServer(bindir).start()
    try:
        yield server
    finally:
        server.stop()


_TEMPLATE: dict[str, bytes] = {}


def migrated_database() -> bytes:
    """An empty SQLite store already at the newest migration (the file's bytes), made once per test process from
    this checkout's migrations: a service started on a copy has nothing to migrate (0.1-0.3 s of CPU less)."""
    if "db" not in _TEMPLATE:
        from backend import db

        with tempfile.TemporaryDirectory() as tmp:
            path = Path(tmp) / "isorig.db"
            engine = db.make_engine(f"sqlite:///{path}")
            try:
                db.upgrade(engine)
            finally:
                engine.dispose()  # its last connection closed: the write-ahead log is back in the file
            assert not path.with_name("isorig.db-wal").exists()
            _TEMPLATE["db"] = path.read_bytes()
    return _TEMPLATE["db"]


@pytest.fixture
def settings(tmp_path) -> Settings:
    """The settings of a service on ``tmp_path``, whose store starts as a copy of an empty, migrated one (owner
    only, as the service makes it). The tests of a fresh data directory, of the migrations and of the first start
    use make_settings on a folder of their own, which starts empty."""
    path = tmp_path / "isorig.db"
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
    with os.fdopen(fd, "wb") as f:
        f.write(migrated_database())
    return make_settings(tmp_path)


@pytest.fixture
def client(settings):
    with TestClient(create_app(settings)) as c:
        yield c


def wait_for(client, test_id: int, statuses=FINAL_STATUSES, timeout_s: float = 30.0) -> dict:
    """The record once its status is one of ``statuses``; for a final status, also once the service's rig is no
    longer running it (the worker writes the record's end before it lets the rig go: a start in between is
    refused with "test N is running", seen at load 25)."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        record = client.get(f"/api/tests/{test_id}").json()
        if record["status"] in statuses:
            if record["status"] in FINAL_STATUSES:
                while client.get("/api/health").json().get("rig") == "running" and time.monotonic() < deadline:
                    time.sleep(0.02)
            return record
        time.sleep(0.05)
    raise AssertionError(f"test {test_id} did not reach {statuses} within {timeout_s} s (last: {record['status']})")


def create_and_start(client, **overrides) -> int:
    r = client.post("/api/tests", json=sine_test(**overrides), headers=AUTH)
    assert r.status_code == 201, r.text
    test_id = r.json()["id"]
    r = client.post(f"/api/tests/{test_id}/start", headers=AUTH)
    assert r.status_code == 200, r.text
    return test_id


def zero_table(client, isolator: str = "IUT_a", supply_bar: float = 100) -> dict:
    """Bring the table back to zero (POST /api/rig/zero at 20 mm/s) and wait for the move to end."""
    r = client.post("/api/rig/zero", json={"speed_m_per_s": 0.02, "isolator": isolator, "supply_bar": supply_bar},
                    headers=AUTH)
    assert r.status_code == 201, r.text
    record = wait_for(client, r.json()["id"])
    assert record["status"] == "completed", record["reason"]
    return record
