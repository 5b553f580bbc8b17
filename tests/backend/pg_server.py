"""A real PostgreSQL server for the tests: started from the installed binaries in a temporary directory.

``PostgresServer.find()`` looks for ``initdb`` and ``postgres`` (on PATH, ``pg_config --bindir``, Debian's
``/usr/lib/postgresql/<version>/bin``); ``start()`` makes a cluster in a temporary directory (data and unix socket
there, nothing else touched) listening on 127.0.0.1 on a free port with a random password, and ``stop()`` shuts
it down and removes the directory. ``initdb`` and ``postgres`` refuse to run as root: as root they run as the
``postgres`` system user (Debian's package makes it), else ``nobody``. ``database()`` makes a fresh, empty
database and returns its SQLAlchemy URL (``postgresql+psycopg://``), so that tests never share state.

``ISORIG_TEST_POSTGRES_URL`` names an existing server instead (its user must be allowed to create databases).
"""

from __future__ import annotations

import glob
import os
import pwd
import secrets
import shutil
import socket
import subprocess
import tempfile
import time
from pathlib import Path

from sqlalchemy.engine import URL, make_url

START_TIMEOUT_S = 60.0


def _bindir_candidates() -> list[Path]:
    out = []
    found = shutil.which("postgres")
    if found:
        out.append(Path(found).resolve().parent)
    pg_config = shutil.which("pg_config")
    if pg_config:
        try:
            out.append(Path(subprocess.run([pg_config, "--bindir"], capture_output=True, text=True, timeout=10,
                                           check=True).stdout.strip()))
        except (OSError, subprocess.SubprocessError):
            pass
    versions = sorted(glob.glob("/usr/lib/postgresql/*/bin"), key=lambda p: int(Path(p).parent.name)
                      if Path(p).parent.name.isdigit() else 0, reverse=True)
    out += [Path(p) for p in versions]
    return out


def find_bindir() -> Path | None:
    """The directory holding ``initdb`` and ``postgres``, or None if no PostgreSQL server is installed."""
    for d in _bindir_candidates():
        if (d / "initdb").is_file() and (d / "postgres").is_file():
            return d
    return None


def _free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _run_as() -> pwd.struct_passwd | None:
    """The unprivileged user to run the server as when we are root (initdb refuses root), else None."""
    if os.geteuid() != 0:
        return None
    for name in ("postgres", "nobody"):
        try:
            return pwd.getpwnam(name)
        except KeyError:
            continue
    raise RuntimeError("running as root and neither a 'postgres' nor a 'nobody' user exists to run PostgreSQL as")


class PostgresServer:
    """A throwaway PostgreSQL cluster (see the module's docstring)."""

    def __init__(self, bindir: Path):
        self.bindir = bindir
        self.dir: Path | None = None
        self.process: subprocess.Popen | None = None
        self.port: int | None = None
        self.user = "isorig"
        self.password = secrets.token_urlsafe(18)
        self._dbs = 0

    def _popen_kwargs(self) -> dict:
        who = _run_as()
        if who is None:
            return {}
        return {"user": who.pw_uid, "group": who.pw_gid, "extra_groups": []}

    def start(self) -> PostgresServer:
        self.dir = Path(tempfile.mkdtemp(prefix="isorig-pg-"))
        who = _run_as()
        if who is not None:
            os.chown(self.dir, who.pw_uid, who.pw_gid)  # the directory stays 0700: only that user (and root)
        data = self.dir / "data"
        pwfile = self.dir / "pw"
        pwfile.write_text(self.password + "\n")
        if who is not None:
            os.chown(pwfile, who.pw_uid, who.pw_gid)
        os.chmod(pwfile, 0o600)
        env = {**os.environ, "LC_ALL": "C", "LANG": "C"}
        init = subprocess.run([str(self.bindir / "initdb"), "-D", str(data), "-U", self.user, "-E", "UTF8",
                               "--no-sync", "--auth-local=scram-sha-256", "--auth-host=scram-sha-256",
                               f"--pwfile={pwfile}"],
                              capture_output=True, text=True, env=env, cwd=self.dir, timeout=120,
                              **self._popen_kwargs())
        pwfile.unlink()
        if init.returncode != 0:
            raise RuntimeError(f"initdb failed ({init.returncode}): {init.stderr.strip()[-2000:]}")
        last_error = ""
        for _attempt in range(3):  # a free port can be taken between the probe and the bind: try another
            self.port = _free_port()
            log = open(self.dir / "postgres.log", "ab")  # noqa: SIM115 (the server's, closed in stop())
            self.process = subprocess.Popen(
                [str(self.bindir / "postgres"), "-D", str(data), "-p", str(self.port), "-k", str(self.dir),
                 "-c", "listen_addresses=127.0.0.1", "-c", "fsync=off", "-c", "synchronous_commit=off",
                 "-c", "full_page_writes=off", "-c", "max_connections=100"],
                stdout=log, stderr=subprocess.STDOUT, env=env, cwd=self.dir, **self._popen_kwargs())
            log.close()
            last_error = self._wait_ready()
            if not last_error:
                return self
            self._terminate()
        log_tail = (self.dir / "postgres.log").read_text(errors="replace")[-2000:]
        self.stop()
        raise RuntimeError(f"PostgreSQL did not start: {last_error}\n{log_tail}")

    def _wait_ready(self) -> str:
        import psycopg

        deadline = time.monotonic() + START_TIMEOUT_S
        error = "timed out"
        while time.monotonic() < deadline:
            if self.process.poll() is not None:
                return f"the server exited with code {self.process.returncode}"
            try:
                with psycopg.connect(host="127.0.0.1", port=self.port, user=self.user, password=self.password,
                                     dbname="postgres", connect_timeout=2):
                    return ""
            except psycopg.OperationalError as exc:
                error = str(exc).strip()
                time.sleep(0.1)
        return error

    def url(self, database: str = "postgres") -> str:
        return URL.create("postgresql+psycopg", username=self.user, password=self.password, host="127.0.0.1",
                          port=self.port, database=database).render_as_string(hide_password=False)

    def database(self) -> str:
        """A new, empty database on the server; its SQLAlchemy URL."""
        import psycopg

        self._dbs += 1
        name = f"isorig_test_{os.getpid()}_{self._dbs}"
        with psycopg.connect(host="127.0.0.1", port=self.port, user=self.user, password=self.password,
                             dbname="postgres", autocommit=True) as conn:
            conn.execute(f'CREATE DATABASE "{name}"')
        return self.url(name)

    def _terminate(self) -> None:
        if self.process is not None and self.process.poll() is None:
            self.process.send_signal(2)  # SIGINT: PostgreSQL's fast shutdown
            try:
                self.process.wait(20)
            except subprocess.TimeoutExpired:
                self.process.kill()
                self.process.wait(5)
        self.process = None

    def stop(self) -> None:
        self._terminate()
        if self.dir is not None:
            shutil.rmtree(self.dir, ignore_errors=True)
            self.dir = None


class ExternalServer:
    """``ISORIG_TEST_POSTGRES_URL``: a server someone else runs; fresh databases are made on it."""

    def __init__(self, url: str):
        self.base = make_url(url)
        self._dbs = 0

    def url(self, database: str | None = None) -> str:
        return self.base.set(database=database or self.base.database).render_as_string(hide_password=False)

    def database(self) -> str:
        import psycopg

        self._dbs += 1
        name = f"isorig_test_{os.getpid()}_{secrets.token_hex(3)}_{self._dbs}"
        b = self.base
        with psycopg.connect(host=b.host, port=b.port, user=b.username, password=b.password, dbname=b.database,
                             autocommit=True) as conn:
            conn.execute(f'CREATE DATABASE "{name}"')
        return self.url(name)

    def stop(self) -> None:
        pass
