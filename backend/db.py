"""Database engine, sessions and migrations (Alembic, run programmatically at start-up).

A SQLite file is the lab's record and holds no secret, but it is nobody else's business either: the service
creates it owner-only (0600; its -wal and -shm files take the same mode) and a directory it creates for it
owner-only (0700). A directory that already exists is left as it is (it may be shared on purpose, e.g. a group's
data directory); an existing database file readable by group or others is logged as a warning and made 0600.

SQLite gets WAL mode (readers never block the writer), ``synchronous=NORMAL`` (a committed transaction
survives a killed process) and foreign keys. Any other SQLAlchemy URL (PostgreSQL) is used as given; there,
several services (one per rig) may share the database and start together: migrations run under an advisory lock.
"""

from __future__ import annotations

import logging
import os
import stat
from pathlib import Path
from typing import TYPE_CHECKING

from sqlalchemy import Engine, create_engine, event
from sqlalchemy.engine import make_url
from sqlalchemy.orm import Session, sessionmaker

if TYPE_CHECKING:
    from alembic.config import Config

MIGRATIONS_DIR = Path(__file__).resolve().parent / "migrations"
MIGRATION_LOCK = 0x69736F726967  # PostgreSQL advisory lock key held while migrating ("isorig" in ASCII)

log = logging.getLogger("isorig")


def owner_only_dir(path: Path) -> None:
    """Create ``path`` (and missing parents) if it does not exist, the directory itself 0700; an existing one is
    left as it is."""
    if not path.exists():
        path.mkdir(parents=True, exist_ok=True)
        os.chmod(path, 0o700)  # mkdir's mode is subject to the umask; this is not


def owner_only_sqlite_file(path: Path) -> None:
    """The SQLite file owner-only: created 0600 if missing (an empty file is an empty database), made 0600 with
    a warning if it (or its -wal, -shm) is readable or writable by group or others."""
    owner_only_dir(path.parent)
    if not path.exists():
        os.close(os.open(path, os.O_WRONLY | os.O_CREAT, 0o600))
        os.chmod(path, 0o600)
        return
    for p in (path, path.with_name(path.name + "-wal"), path.with_name(path.name + "-shm")):
        try:
            mode = stat.S_IMODE(p.stat().st_mode)
        except FileNotFoundError:
            continue
        if mode & 0o077:
            log.warning("the database file %s had mode %04o (group or others could read it): made 0600", p, mode)
            try:
                os.chmod(p, 0o600)
            except OSError as exc:  # not ours to change: say so, run on
                log.warning("could not make %s owner-only: %s", p, exc)


def make_engine(url: str) -> Engine:
    parsed = make_url(url)
    if parsed.get_backend_name() == "sqlite":
        if parsed.database and parsed.database != ":memory:" and not parsed.database.startswith("file:"):
            owner_only_sqlite_file(Path(parsed.database).expanduser())
        engine = create_engine(url, connect_args={"check_same_thread": False, "timeout": 30})

        @event.listens_for(engine, "connect")
        def _sqlite_pragmas(dbapi_connection, _record):
            cursor = dbapi_connection.cursor()
            cursor.execute("PRAGMA journal_mode=WAL")
            cursor.execute("PRAGMA synchronous=NORMAL")
            cursor.execute("PRAGMA foreign_keys=ON")
            cursor.close()

        return engine
    return create_engine(url, pool_pre_ping=True)


def alembic_config(url: str) -> Config:
    from alembic.config import Config  # imported here: a reader of the store (isorig report) never migrates

    cfg = Config()
    cfg.set_main_option("script_location", str(MIGRATIONS_DIR))
    cfg.set_main_option("sqlalchemy.url", url.replace("%", "%%"))
    return cfg


def upgrade(engine: Engine, revision: str = "head") -> None:
    """Bring the schema to the newest migration (or to ``revision``, a step the migration tests take)."""
    from alembic import command

    cfg = alembic_config(engine.url.render_as_string(hide_password=False))
    sqlite = engine.dialect.name == "sqlite"
    with engine.connect() as connection:
        if sqlite:  # a migration that recreates a table (SQLite's batch mode) must not cascade its drop to the
            connection.exec_driver_sql("PRAGMA foreign_keys=OFF")  # children: enforcement off (outside any
            connection.commit()  # transaction, where SQLite ignores the pragma), checked after, back on
        try:
            with connection.begin():
                if connection.dialect.name == "postgresql":  # several rigs' services may start at once on one
                    connection.exec_driver_sql(f"SELECT pg_advisory_xact_lock({MIGRATION_LOCK})")  # database:
                    # one migrates, the others wait here and then find the schema at head
                cfg.attributes["connection"] = connection
                command.upgrade(cfg, revision)
                if sqlite:
                    broken = connection.exec_driver_sql("PRAGMA foreign_key_check").fetchall()
                    if broken:
                        raise RuntimeError(f"the migration left rows whose parent is missing: {broken[:5]}")
        finally:
            if sqlite:
                connection.exec_driver_sql("PRAGMA foreign_keys=ON")
                connection.commit()


def startup_lock(session: Session) -> None:
    """Hold, until ``session``'s transaction ends, the lock that makes services starting together on one database
    (one per rig) do their start-up writes one at a time: PostgreSQL's advisory lock (as the migrations'), SQLite's
    write lock (taken by a write that changes nothing)."""
    from sqlalchemy import text

    name = session.get_bind().dialect.name
    if name == "postgresql":
        session.execute(text(f"SELECT pg_advisory_xact_lock({MIGRATION_LOCK})"))
    elif name == "sqlite":
        session.execute(text("UPDATE alembic_version SET version_num = version_num"))


def session_factory(engine: Engine) -> sessionmaker[Session]:
    return sessionmaker(engine, expire_on_commit=False)
