"""Database engine, sessions and migrations (Alembic, run programmatically at start-up).

A SQLite file is the lab's record and holds no secret, but it is nobody else's business either: the service
creates it owner-only (0600; its -wal and -shm files take the same mode) and a directory it creates for it
owner-only (0700). A directory that already exists is left as it is (it may be shared on purpose, e.g. a group's
data directory); an existing database file readable by group or others is logged as a warning and made 0600.
Only a missing file is created (whole: a new, empty SQLite database from its first byte on); a file that is empty
(0 bytes) or is not an SQLite database is refused with its path (``DatabaseFileError``), never taken for a new
database (which would have started a second lab record beside the one the user meant, with a new admin).

SQLite gets WAL mode (readers never block the writer), ``synchronous=NORMAL`` (a committed transaction
survives a killed process) and foreign keys. Any other SQLAlchemy URL (PostgreSQL) is used as given.

Several services (one per rig) may share the database and start together on a new one: migrations run one at a
time. PostgreSQL: under an advisory lock (``MIGRATION_LOCK``). SQLite: under an ``fcntl.flock`` on a file beside
the database (``isorig.db-migrations.lock``, 0600; never a rig's lock file, ``isorig.db.<rig>.lock``), since SQLite
runs Alembic's CREATE TABLEs outside any write lock: without it two services both migrated a new database and one
exited on "table tests already exists". The lock ends with the process (kill -9 included); the file stays.
"""

from __future__ import annotations

import contextlib
import logging
import os
import secrets
import sqlite3
import stat
from collections.abc import Iterator
from pathlib import Path
from typing import TYPE_CHECKING

from sqlalchemy import Engine, create_engine, event
from sqlalchemy.engine import make_url
from sqlalchemy.orm import Session, sessionmaker

if TYPE_CHECKING:
    from alembic.config import Config

MIGRATIONS_DIR = Path(__file__).resolve().parent / "migrations"
MIGRATION_LOCK = 0x69736F726967  # PostgreSQL advisory lock key held while migrating ("isorig" in ASCII)
SQLITE_HEADER = b"SQLite format 3\x00"  # the first 16 bytes of every SQLite database file

log = logging.getLogger("isorig")


def owner_only_dir(path: Path) -> None:
    """Create ``path`` (and missing parents) if it does not exist, the directory itself 0700; an existing one is
    left as it is."""
    if not path.exists():
        path.mkdir(parents=True, exist_ok=True)
        os.chmod(path, 0o700)  # mkdir's mode is subject to the umask; this is not


class DatabaseFileError(ValueError):
    """A database file that exists but cannot be the lab's database (empty, not SQLite, not a file): its path and
    what to do. Nothing is written to it."""


def check_sqlite_file(path: Path) -> None:
    """Nothing if ``path`` is missing or an SQLite database file, else a DatabaseFileError naming it."""
    advice = ("isorig creates a database only where no file exists: move the file away, or give the data "
              "directory or --database-url of the lab's database")
    try:
        info = path.stat()
        if not stat.S_ISREG(info.st_mode):
            raise DatabaseFileError(f"the database path {path} is not a file; {advice}")
        if info.st_size == 0:
            raise DatabaseFileError(f"the database file {path} is empty (0 bytes), not an SQLite database; {advice}")
        with open(path, "rb") as f:
            head = f.read(len(SQLITE_HEADER))
    except FileNotFoundError:
        return
    except OSError as exc:
        raise DatabaseFileError(f"the database file {path} cannot be read: {exc.strerror}") from None
    if head != SQLITE_HEADER:
        raise DatabaseFileError(f"the database file {path} is not an SQLite database (it begins {head!r}, not "
                                f"{SQLITE_HEADER!r}); {advice}")


def _create_sqlite_file(path: Path) -> None:
    """A new, empty SQLite database (WAL mode) at ``path``, 0600, made beside it and linked into place whole, so
    that a service starting at the same moment never finds it half made (0 bytes); an existing file is kept."""
    spare = path.with_name(f".{path.name}.{os.getpid()}.{secrets.token_hex(4)}.new")
    os.close(os.open(spare, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600))
    try:
        os.chmod(spare, 0o600)
        connection = sqlite3.connect(spare)
        try:
            connection.execute("PRAGMA journal_mode=WAL")  # writes the database's first page (4 kB)
        finally:
            connection.close()
        try:
            os.link(spare, path)
        except FileExistsError:  # another service made it first: that one is the database
            pass
        except OSError:  # a file system without hard links: create it exclusively and copy the bytes in
            try:
                fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
            except FileExistsError:
                return
            with os.fdopen(fd, "wb") as out:
                out.write(spare.read_bytes())
    finally:
        for p in (spare, spare.with_name(spare.name + "-wal"), spare.with_name(spare.name + "-shm")):
            p.unlink(missing_ok=True)


def owner_only_sqlite_file(path: Path) -> None:
    """The SQLite file owner-only: created 0600 if missing (a new, empty database), made 0600 with a warning if it
    (or its -wal, -shm) is readable or writable by group or others. A file that is empty or not an SQLite database
    is a DatabaseFileError, left as it is."""
    owner_only_dir(path.parent)
    check_sqlite_file(path)
    if not path.exists():
        _create_sqlite_file(path)
        check_sqlite_file(path)
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


def migration_lock_path(database: Path) -> Path:
    """The file whose flock serialises the migrations of the SQLite database file ``database``."""
    path = Path(database).expanduser().resolve()
    return path.with_name(f"{path.name}-migrations.lock")


@contextlib.contextmanager
def _sqlite_migration_lock(engine: Engine) -> Iterator[None]:
    """Held while ``engine``'s SQLite file is migrated: an exclusive flock on its own open file (so threads of one
    process wait for each other too); nothing for an in-memory database or a ``file:`` URI."""
    database = engine.url.database
    if not database or database == ":memory:" or database.startswith("file:"):
        yield
        return
    import fcntl

    path = migration_lock_path(Path(database))
    fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o600)
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            log.info("waiting for another process migrating %s (lock %s)", database, path)
            fcntl.flock(fd, fcntl.LOCK_EX)
        yield
    finally:
        os.close(fd)  # the only descriptor of this open file: its flock ends


def upgrade(engine: Engine, revision: str = "head") -> None:
    """Bring the schema to the newest migration (or to ``revision``, a step the migration tests take), one
    process (or thread) at a time on one database (module docstring)."""
    if engine.dialect.name == "sqlite":
        with _sqlite_migration_lock(engine):
            _upgrade(engine, revision)
    else:
        _upgrade(engine, revision)  # PostgreSQL: under an advisory lock, taken in the migration's transaction


def _upgrade(engine: Engine, revision: str) -> None:
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
