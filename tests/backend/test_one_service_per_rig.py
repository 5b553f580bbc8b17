"""One service per rig (issue 33, item 1), with real `isorig serve` processes on SQLite and on PostgreSQL.

Before: a second `serve` of the same rig name and database (another port, or the first's busy port) marked the
first's running test `interrupted` at start-up, before it bound its port, then ran tests on the same rig. Now it
is refused (exit 3) with a message naming the running service and changes nothing; after a `kill -9` of the
first, the next service starts and marks the test it left `interrupted`."""

from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import time

import httpx
import pytest
from conftest import AUTH, sine_test
from served import free_port, serve, stop, wait_up

LONG = sine_test(speed=1.0, profile={"frequency_hz": 0.5, "cycles": 200, "taper_cycles": 1})  # 400 s


@pytest.fixture(params=["sqlite", "postgresql"])
def database(request, tmp_path) -> list[str]:
    """The arguments that put every service of a test on one database (and one data directory)."""
    args = ["--data-dir", str(tmp_path / "data")]
    if request.param == "postgresql":
        args += ["--database-url", request.getfixturevalue("postgres").database()]
    return args


def wait_lock_free(args: list[str], timeout_s: float = 10.0) -> None:
    """PostgreSQL: until the killed service's session (and its advisory lock) is gone; the server ends it as soon
    as it reads the closed socket."""
    if "--database-url" not in args:
        return
    from sqlalchemy import create_engine, text

    engine = create_engine(args[args.index("--database-url") + 1])
    deadline = time.monotonic() + timeout_s
    try:
        with engine.connect() as c:
            while c.execute(text("SELECT count(*) FROM pg_locks WHERE locktype = 'advisory' AND objsubid = 2")
                            ).scalar() and time.monotonic() < deadline:
                time.sleep(0.05)
    finally:
        engine.dispose()


def refused(port: int, args: list[str]) -> tuple[int, str]:
    """A second service of the same rig: its exit code and what it said."""
    second = serve(port, *args)
    try:
        err = second.communicate(timeout=60)[1]
    except subprocess.TimeoutExpired:
        stop(second)
        pytest.fail(f"a second service of rig-1 on port {port} is still running after 60 s")
    return second.returncode, err


@pytest.mark.slow  # real services started and killed: scripts/test.sh --quick leaves it out
def test_a_second_service_of_a_rig_is_refused_and_a_dead_ones_test_is_interrupted(database):
    port = free_port()
    first = serve(port, *database)
    base = f"http://127.0.0.1:{port}"
    later = None
    try:
        wait_up(first, base)
        with httpx.Client(base_url=base, timeout=30) as http:
            test_id = http.post("/api/tests?start=true", json=LONG, headers=AUTH).json()["id"]
            deadline = time.monotonic() + 30
            while http.get(f"/api/tests/{test_id}").json()["samples_stored"] == 0:
                assert time.monotonic() < deadline, "no samples stored"
                time.sleep(0.1)
            before = http.get(f"/api/tests/{test_id}").json()
            for other_port in (free_port(), port):  # another port, and the first's own (busy) port
                code, err = refused(other_port, database)
                assert code == 3, (code, err[-2000:])
                assert "Traceback" not in err, err
                assert "the rig 'rig-1' is already driven by another `isorig serve` on this database" in err, err
                assert f"pid {first.pid}" in err and f"on host {socket.gethostname()}" in err, err
                assert f"serving 127.0.0.1:{port}" in err and " since 20" in err, err
                assert "nothing was changed" in err and "--rig-name" in err, err
            # the first service's test is untouched: still running, on, with no event added by the refused ones
            now = http.get(f"/api/tests/{test_id}").json()
            assert now["status"] == "running" and now["reason"] is None, now["reason"]
            assert now["time_s"] > before["time_s"] and now["samples_stored"] > before["samples_stored"]
            assert now["events"] == before["events"]
            assert http.get("/api/rig").json()["state"]["test_id"] == test_id
        first.send_signal(signal.SIGKILL)  # the service dies with its test running
        first.wait(10)
        wait_lock_free(database)
        later_port = free_port()
        later = serve(later_port, *database)
        wait_up(later, f"http://127.0.0.1:{later_port}")
        with httpx.Client(base_url=f"http://127.0.0.1:{later_port}", timeout=30) as http:
            rec = http.get(f"/api/tests/{test_id}").json()
        assert rec["status"] == "interrupted", rec["status"]
        assert rec["events"][-1]["message"] == f"test {test_id} marked interrupted at service start-up"
    finally:
        stop(first)
        if later is not None:
            stop(later)


@pytest.mark.slow  # real services: scripts/test.sh --quick leaves it out
def test_services_of_other_rigs_share_the_database(database):
    """The lock is per rig name: a second rig's service on the same database starts beside the first (one after
    the other: two services creating one new SQLite database at the same moment can both migrate it)."""
    servers = []
    try:
        for name in ("rig-a", "rig-b"):
            port = free_port()
            servers.append(serve(port, *database, "--rig-name", name))
            wait_up(servers[-1], f"http://127.0.0.1:{port}")
        for server in servers:
            assert server.poll() is None
    finally:
        for server in servers:
            stop(server)


def test_the_sqlite_lock_file_names_its_holder_and_is_let_go(tmp_path):
    from backend import rig_lock
    from backend.db import make_engine

    engine = make_engine(f"sqlite:///{tmp_path / 'isorig.db'}")
    held = rig_lock.take(engine, "rig-1", "127.0.0.1", 8000)
    path = tmp_path / "isorig.db.rig-1.lock"
    assert json.loads(path.read_text())["pid"] == os.getpid() and oct(path.stat().st_mode & 0o777) == "0o600"
    with pytest.raises(rig_lock.RigBusy, match=rf"pid {os.getpid()}, on host .*, serving 127.0.0.1:8000, since"):
        rig_lock.take(engine, "rig-1", "127.0.0.1", 8001)
    rig_lock.take(engine, "rig-2", "127.0.0.1", 8001).release()  # another rig's lock is its own
    held.release()
    rig_lock.take(engine, "rig-1", "127.0.0.1", 8001).release()
    engine.dispose()


def test_a_lost_postgresql_lock_is_taken_again(postgres, monkeypatch):
    """The lock's connection ended by the server (a restart, an administrator): the watch thread finds it, takes
    the lock again on a new connection; while another session holds it, ``held`` is False."""
    from sqlalchemy import create_engine, text

    from backend import rig_lock

    monkeypatch.setattr(rig_lock, "CHECK_INTERVAL_S", 0.1)
    engine = create_engine(postgres.database())
    lock = rig_lock.take(engine, "rig-1", "127.0.0.1", 8000)

    def holder_pids(c) -> list[int]:
        return c.execute(text("SELECT pid FROM pg_locks WHERE locktype = 'advisory' AND objsubid = 2 AND granted")
                         ).scalars().all()

    def until(condition, timeout_s: float = 10.0) -> None:
        deadline = time.monotonic() + timeout_s
        while not condition():
            assert time.monotonic() < deadline, "not in time"
            time.sleep(0.05)

    try:
        with engine.connect().execution_options(isolation_level="AUTOCOMMIT") as c:
            first = holder_pids(c)
            assert len(first) == 1 and lock.held
            c.execute(text("SELECT pg_terminate_backend(:p)"), {"p": first[0]})
            until(lambda: holder_pids(c) not in ([], first))  # held again, by a new session
            assert lock.held
            # another session takes it while this one's connection is gone: not held, said, tried again
            c.execute(text("SELECT pg_terminate_backend(:p), pg_advisory_lock(:c, :k)"),  # waits in the lock's
                      {"p": holder_pids(c)[0], **lock.keys})  # queue: first once the ended session lets go
            until(lambda: not lock.held)
            c.execute(text("SELECT pg_advisory_unlock(:c, :k)"), lock.keys)
            until(lambda: lock.held)
    finally:
        lock.release()
        engine.dispose()


def test_no_test_starts_while_the_lock_is_not_held(client):
    client.app.state.rig_lock.held = False  # as while a lost PostgreSQL lock is taken again
    r = client.post("/api/tests?start=true", json=sine_test(), headers=AUTH)
    assert r.status_code == 409 and "lost the lock of the rig 'rig-1'" in r.json()["detail"], r.text
    client.app.state.rig_lock.held = True
    r = client.post("/api/tests?start=true", json=sine_test(), headers=AUTH)
    assert r.status_code == 201, r.text
