"""One service per rig: the lock ``isorig serve`` holds on its rig's name for its whole life.

A service takes it before it touches the database (migrations, start-up recovery) and before it binds its port;
a second service of the same rig name on the same database is refused (``RigBusy``, naming the one that runs:
pid, host, port, since when) and changes nothing. So start-up recovery marks ``interrupted`` only tests whose
service is gone. The lock is one the operating system or the database server ends with the process, ``kill -9``
included, so no stale lock is ever left to clear by hand:

- SQLite: ``fcntl.flock`` on a file beside the database (``isorig.db.<rig name>.lock``, 0600), which holds the
  holder's pid, host, port and start time as JSON for the refusal's message. The file stays; only its lock counts.
- PostgreSQL: a session advisory lock (``pg_try_advisory_lock``, keys ``RIG_LOCK_CLASS`` and the CRC-32 of the rig
  name) on a connection of its own, named after the holder (``application_name``) so that a refusal can say who
  holds it (``pg_locks``, ``pg_stat_activity``). The server ends the lock when the connection ends; TCP keepalives
  (set for the session) end it within about 30 s of a host that vanished. A thread checks the connection every
  ``CHECK_INTERVAL_S`` and takes the lock again on a new one if it was lost (a server restart); while it is not held,
  ``held`` is False and no test starts.
"""

from __future__ import annotations

import contextlib
import json
import logging
import os
import socket
import threading
import time
import zlib
from datetime import UTC, datetime
from pathlib import Path

from sqlalchemy import Engine, create_engine, text
from sqlalchemy.pool import NullPool

log = logging.getLogger("isorig")

RIG_LOCK_CLASS = 0x69736F72  # first key of every rig's advisory lock ("isor"); the migrations' lock is one bigint
CHECK_INTERVAL_S = 5.0


class RigBusy(RuntimeError):
    """Another service holds this rig's lock on this database: the message names it and says what to do."""


def _me(rig_name: str, host: str, port: int) -> dict:
    return {"rig_name": rig_name, "pid": os.getpid(), "host": socket.gethostname(), "address": f"{host}:{port}",
            "since": datetime.now(UTC).strftime("%Y-%m-%d %H:%M:%S UTC")}


def _busy(rig_name: str, holder: dict, where: str) -> RigBusy:
    parts = [f"pid {holder['pid']}" if holder.get("pid") else None,
             f"on host {holder['host']}" if holder.get("host") else None,
             f"serving {holder['address']}" if holder.get("address") else None,
             f"since {holder['since']}" if holder.get("since") else None]
    who = ", ".join(p for p in parts if p) or "details not readable"
    return RigBusy(f"the rig {rig_name!r} is already driven by another `isorig serve` on this database ({who}; "
                   f"{where}); nothing was changed. Stop that service first, or give this one another --rig-name")


class RigLock:
    """The lock of one rig name on one database (module docstring); ``take`` returns it held."""

    held = True

    def release(self) -> None:
        """Let the lock go (the service has ended its tests)."""


class _FileLock(RigLock):
    def __init__(self, path: Path, me: dict):
        self.path, self.me, self.file = path, me, None

    def take(self) -> _FileLock:
        import fcntl

        # a file object, not a bare descriptor: a lock whose app is dropped unreleased ends when it is collected
        file = os.fdopen(os.open(self.path, os.O_RDWR | os.O_CREAT, 0o600), "r+b", buffering=0)
        try:
            fcntl.flock(file.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            holder = self._holder(file)
            file.close()
            raise _busy(self.me["rig_name"], holder, f"lock file {self.path}") from None
        except BaseException:
            file.close()
            raise
        file.truncate(0)
        file.write(json.dumps(self.me).encode())
        self.file = file
        return self

    @staticmethod
    def _holder(file) -> dict:
        for _ in range(20):  # the holder writes who it is just after it takes the lock
            raw = os.pread(file.fileno(), 4096, 0)
            if raw:
                with contextlib.suppress(ValueError):
                    return json.loads(raw)
            time.sleep(0.05)
        return {}

    def release(self) -> None:
        if self.file is not None:
            with contextlib.suppress(OSError):
                self.file.truncate(0)
            self.file.close()  # closing the only descriptor ends the flock
            self.file = None


class _AdvisoryLock(RigLock):
    def __init__(self, engine: Engine, me: dict):
        self.me = me
        self.keys = {"c": RIG_LOCK_CLASS, "k": zlib.crc32(me["rig_name"].encode()) & 0x7FFFFFFF}
        name = f"isorig pid={me['pid']} {me['address']} host={me['host']}"[:63]  # NAMEDATALEN - 1
        self.engine = create_engine(engine.url, poolclass=NullPool, connect_args={"application_name": name})
        self.connection = None
        self.held = False
        self._stop = threading.Event()

    def _connect_and_lock(self) -> bool:
        connection = self.engine.connect().execution_options(isolation_level="AUTOCOMMIT")
        try:
            for setting in ("tcp_keepalives_idle = 10", "tcp_keepalives_interval = 5", "tcp_keepalives_count = 3",
                            "idle_session_timeout = 0"):  # gone hosts found by the server; this idle session kept
                with contextlib.suppress(Exception):
                    connection.exec_driver_sql(f"SET {setting}")
            got = connection.execute(text("SELECT pg_try_advisory_lock(:c, :k)"), self.keys).scalar()
            if got:
                self.connection, self.held = connection, True
                return True
            holder = self._holder(connection)
        except BaseException:
            connection.close()
            raise
        connection.close()
        raise _busy(self.me["rig_name"], holder, "PostgreSQL advisory lock")

    def _holder(self, connection) -> dict:
        row = connection.execute(text(
            "SELECT a.application_name, a.client_addr, a.backend_start FROM pg_locks l "
            "LEFT JOIN pg_stat_activity a ON a.pid = l.pid WHERE l.locktype = 'advisory' AND l.granted "
            "AND l.classid::bigint = :c AND l.objid::bigint = :k AND l.objsubid = 2 "
            "AND l.database = (SELECT oid FROM pg_database WHERE datname = current_database())"), self.keys).first()
        if row is None or not row.application_name:  # another role's session: PostgreSQL hides its details
            return {}
        words = dict(w.split("=", 1) for w in row.application_name.split() if w.count("=") == 1)
        address = next((w for w in row.application_name.split()[1:] if "=" not in w), None)
        since = row.backend_start.astimezone(UTC).strftime("%Y-%m-%d %H:%M:%S UTC") if row.backend_start else None
        return {"pid": words.get("pid"), "host": words.get("host") or row.client_addr, "address": address,
                "since": since}

    def take(self) -> _AdvisoryLock:
        self._connect_and_lock()
        threading.Thread(target=self._watch, daemon=True, name="isorig-rig-lock").start()
        return self

    def _watch(self) -> None:
        """Every CHECK_INTERVAL_S: the lock's connection still answers, else the lock taken again."""
        while not self._stop.wait(CHECK_INTERVAL_S):
            try:
                self.connection.exec_driver_sql("SELECT 1")
                continue
            except Exception:
                if self._stop.is_set():
                    return
                self.held = False
                with contextlib.suppress(Exception):
                    self.connection.close()
            try:
                self._connect_and_lock()
                log.warning("the lock of rig %r was lost with its database connection and is held again",
                            self.me["rig_name"])
            except Exception as exc:  # noqa: BLE001 - said, tried again; no test starts meanwhile
                log.error("the lock of rig %r is lost (%s): no test starts until it is held again",
                          self.me["rig_name"], str(exc).splitlines()[0] if str(exc) else type(exc).__name__)

    def release(self) -> None:
        self._stop.set()
        if self.connection is not None:
            with contextlib.suppress(Exception):
                self.connection.close()  # the session ends, and its advisory lock with it
            self.connection = None
        self.held = False
        self.engine.dispose()


def lock_file(database: str, rig_name: str) -> Path:
    """The lock file of ``rig_name`` beside the SQLite database file ``database``."""
    path = Path(database).expanduser().resolve()
    return path.with_name(f"{path.name}.{rig_name}.lock")


def take(engine: Engine, rig_name: str, host: str, port: int) -> RigLock:
    """This service's lock of ``rig_name`` on ``engine``'s database, held; RigBusy if another service holds it.
    An in-memory SQLite database is this process's alone (nothing to lock); another kind of database is said and
    run without a lock."""
    me = _me(rig_name, host, port)
    url = engine.url
    if url.get_backend_name() == "sqlite":
        if not url.database or url.database == ":memory:" or url.database.startswith("file:"):
            return RigLock()
        return _FileLock(lock_file(url.database, rig_name), me).take()
    if url.get_backend_name() == "postgresql":
        return _AdvisoryLock(engine, me).take()
    log.warning("no rig lock on a %s database: run one service per rig name by hand", url.get_backend_name())
    return RigLock()
