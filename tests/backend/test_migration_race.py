"""Services of two rigs started at the same moment on a brand-new SQLite database (issue 33, item 1's tests).

Before: both migrated it at once (SQLite runs Alembic's CREATE TABLEs outside any write lock), and one exited 2
with "table tests already exists" (or "alembic_version already exists"). Now ``backend.db.upgrade`` holds an
``fcntl.flock`` on a file beside the database while it migrates (PostgreSQL: an advisory lock): one migrates, the
other waits and finds the schema at head.

The two are real ``isorig serve`` processes. Their imports take seconds and vary by as much as the migration
lasts, so each is started through a small launcher that imports first and then waits for one file to appear, and
both are released at the same moment: the migrations then overlap every time, not by chance."""

from __future__ import annotations

import os
import subprocess
import sys
import threading
import time

import pytest
from served import ENV, free_port, stop, wait_up
from sqlalchemy import text

from backend.db import make_engine, migration_lock_path, upgrade

# imports done, wait for the go file, then `isorig serve ARGS` in this process (isorig's own entry point)
LAUNCHER = """
import os, sys, time
import alembic.command, backend.app, isorig.commands.serve, isorig.cli  # the seconds that would spread the starts
go, ready = sys.argv[1], sys.argv[2]
open(ready, "w").close()
while not os.path.exists(go):
    time.sleep(0.001)
sys.exit(isorig.cli.main(["serve", *sys.argv[3:]]))
"""

ROUNDS = 2  # today's code failed in the first round in 4 of 4 tries (3 at load 4-11): a second round for a rarer loss


def launch(go: str, ready: str, port: int, *args: str) -> subprocess.Popen:
    cmd = [sys.executable, "-c", LAUNCHER, go, ready, "--port", str(port), "--log-level", "warning", *args]
    return subprocess.Popen(cmd, env={**os.environ, **ENV}, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                            text=True, start_new_session=True)


@pytest.mark.slow  # real services, two rounds: scripts/test.sh --quick leaves it out
def test_two_rigs_services_started_together_on_a_new_sqlite_database_both_start(tmp_path):
    for n in range(ROUNDS):
        data = tmp_path / f"round-{n}"
        go = tmp_path / f"go-{n}"
        ports = [free_port(), free_port()]
        servers = []
        try:
            for i, (port, rig) in enumerate(zip(ports, ("rig-a", "rig-b"), strict=True)):
                servers.append(launch(str(go), str(tmp_path / f"ready-{n}-{i}"), port, "--data-dir", str(data),
                                      "--rig-name", rig))
            deadline = time.monotonic() + 120
            while not all((tmp_path / f"ready-{n}-{i}").exists() for i in range(2)):
                assert all(s.poll() is None for s in servers), [s.stderr.read()[-2000:] for s in servers
                                                                if s.poll() is not None]
                assert time.monotonic() < deadline, "the launchers did not finish their imports"
                time.sleep(0.01)
            assert not (data / "isorig.db").exists()  # a brand-new database: neither has touched it yet
            go.touch()  # both at once
            for server, port in zip(servers, ports, strict=True):
                wait_up(server, f"http://127.0.0.1:{port}")  # fails with the service's stderr if it exited
            engine = make_engine(f"sqlite:///{data / 'isorig.db'}")
            with engine.connect() as conn:
                assert conn.execute(text("SELECT count(*) FROM alembic_version")).scalar() == 1
            engine.dispose()
        finally:
            for server in servers:
                stop(server)


def test_upgrades_in_threads_of_one_process_at_the_same_moment_migrate_once(tmp_path):
    """The lock is an flock on its own open file each time: threads of one process are serialised too (and the
    lock file is made beside the database, owner-only)."""
    url = f"sqlite:///{tmp_path / 'new.db'}"
    errors: list[BaseException] = []
    go = threading.Barrier(4)

    def start() -> None:
        engine = make_engine(url)
        try:
            go.wait()
            upgrade(engine)
        except BaseException as exc:  # noqa: BLE001 (asserted below)
            errors.append(exc)
        finally:
            engine.dispose()

    threads = [threading.Thread(target=start) for _ in range(4)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(120)
    assert errors == []
    lock = migration_lock_path(tmp_path / "new.db")
    assert lock == tmp_path / "new.db-migrations.lock" and lock.exists()
    assert lock.stat().st_mode & 0o777 == 0o600


@pytest.mark.parametrize("rig", ["migrations", "x"])
def test_the_migration_lock_file_is_never_a_rig_lock_file(tmp_path, rig):
    from backend.rig_lock import lock_file

    assert migration_lock_path(tmp_path / "isorig.db") != lock_file(str(tmp_path / "isorig.db"), rig)
