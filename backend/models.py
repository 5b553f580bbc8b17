"""Database tables (SQLAlchemy 2): tests, sample chunks, cycles, events (audit log), user isolators.

Several services, one per rig, may share the database: a test and its events carry their rig's name.

Samples are stored in compressed chunks of about one second (see backend.codec), never one row per sample.
Events keep a plain ``test_id`` (no foreign key) so the audit log outlives a deleted test.
"""

from __future__ import annotations

from datetime import UTC, datetime

from sqlalchemy import JSON, DateTime, Float, ForeignKey, Integer, LargeBinary, String, Text
from sqlalchemy.orm import DeclarativeBase, Mapped, mapped_column, relationship

STATUSES = ("ready", "running", "completed", "stopped", "aborted", "interrupted", "failed")
FINAL_STATUSES = ("completed", "stopped", "aborted", "interrupted", "failed")


def utcnow() -> datetime:
    return datetime.now(UTC)


def as_utc(moment: datetime) -> datetime:
    """A stored time as an aware UTC datetime: SQLite gives back naive ones (they were stored as UTC)."""
    return moment if moment.tzinfo is not None else moment.replace(tzinfo=UTC)


class Base(DeclarativeBase):
    pass


class TestRecord(Base):
    __tablename__ = "tests"
    __test__ = False  # not a pytest test class
    # an id is never given again, even after the newest test is deleted (its events keep the id): SQLite
    # AUTOINCREMENT (migration 0006); PostgreSQL's sequences never go back anyway
    __table_args__ = {"sqlite_autoincrement": True}

    id: Mapped[int] = mapped_column(Integer, primary_key=True)
    # the rig it runs on (settings.rig_name): one service per rig, several may share the database
    rig_name: Mapped[str] = mapped_column(String(64), index=True)
    created_at: Mapped[datetime] = mapped_column(DateTime(timezone=True), default=utcnow, index=True)
    started_at: Mapped[datetime | None] = mapped_column(DateTime(timezone=True))
    ended_at: Mapped[datetime | None] = mapped_column(DateTime(timezone=True))
    status: Mapped[str] = mapped_column(String(16), default="ready", index=True)
    reason: Mapped[str | None] = mapped_column(Text)
    label: Mapped[str] = mapped_column(String(200), default="")
    specimen_id: Mapped[str] = mapped_column(String(64), default="")  # the lab's id of the bearing tested
    operator_name: Mapped[str] = mapped_column(String(64), default="")  # who ran the test
    notes: Mapped[str] = mapped_column(Text, default="")
    isolator: Mapped[str] = mapped_column(String(64), index=True)
    supply_bar: Mapped[float] = mapped_column(Float)
    vertical_load_n: Mapped[float | None] = mapped_column(Float)  # None: recorded before it was a condition
    controller: Mapped[str] = mapped_column(String(32))
    speed: Mapped[float] = mapped_column(Float, default=1.0)
    driver: Mapped[str] = mapped_column(String(200), default="simulated")  # simulated | udp://HOST:PORT
    request: Mapped[dict] = mapped_column(JSON)  # the POST body as accepted
    scenario: Mapped[dict] = mapped_column(JSON)  # sim.engine.Scenario.describe()
    limits: Mapped[dict] = mapped_column(JSON)  # safety limits in force
    duration_s: Mapped[float] = mapped_column(Float)
    cycles_total: Mapped[int] = mapped_column(Integer)
    samples_stored: Mapped[int] = mapped_column(Integer, default=0)
    time_s: Mapped[float] = mapped_column(Float, default=0.0)  # last stored sample time
    summary: Mapped[dict | None] = mapped_column(JSON)
    # a test that ran is never erased: it can be archived (hidden from the list) by a named person for a reason,
    # and restored
    archived_at: Mapped[datetime | None] = mapped_column(DateTime(timezone=True))
    archived_by: Mapped[str | None] = mapped_column(String(64))
    archive_reason: Mapped[str | None] = mapped_column(Text)
    # review (backend.review): unreviewed | approved | rejected; an approved record is locked, its SHA-256 kept
    review_state: Mapped[str] = mapped_column(String(16), default="unreviewed", index=True)
    reviewed_by: Mapped[str | None] = mapped_column(String(64))
    reviewed_at: Mapped[datetime | None] = mapped_column(DateTime(timezone=True))
    review_note: Mapped[str | None] = mapped_column(Text)  # the reason of a rejection, a note on an approval
    record_sha256: Mapped[str | None] = mapped_column(String(64))  # of the approved record (backend.review)
    review_events_upto: Mapped[int | None] = mapped_column(Integer)  # the last event the hash covers
    # the PDF rendered at the approval (ApprovedReport) and served from then on: its SHA-256
    report_sha256: Mapped[str | None] = mapped_column(String(64))

    chunks: Mapped[list[SampleChunk]] = relationship(back_populates="test", cascade="all, delete-orphan",
                                                     passive_deletes=True)
    cycles: Mapped[list[CycleRecord]] = relationship(back_populates="test", cascade="all, delete-orphan",
                                                     passive_deletes=True)


class SampleChunk(Base):
    __tablename__ = "sample_chunks"

    id: Mapped[int] = mapped_column(Integer, primary_key=True)
    test_id: Mapped[int] = mapped_column(ForeignKey("tests.id", ondelete="CASCADE"), index=True)
    seq: Mapped[int] = mapped_column(Integer)
    t0_s: Mapped[float] = mapped_column(Float)
    n_rows: Mapped[int] = mapped_column(Integer)
    n_columns: Mapped[int] = mapped_column(Integer)
    codec: Mapped[str] = mapped_column(String(32))
    data: Mapped[bytes] = mapped_column(LargeBinary)

    test: Mapped[TestRecord] = relationship(back_populates="chunks")


class CycleRecord(Base):
    __tablename__ = "cycles"

    id: Mapped[int] = mapped_column(Integer, primary_key=True)
    test_id: Mapped[int] = mapped_column(ForeignKey("tests.id", ondelete="CASCADE"), index=True)
    cycle: Mapped[int] = mapped_column(Integer)  # 1-based
    block: Mapped[int] = mapped_column(Integer, default=0)
    phase: Mapped[str | None] = mapped_column(String(16))  # sim.tracking.PHASES; None: stored before phases
    t_start_s: Mapped[float] = mapped_column(Float)
    t_end_s: Mapped[float] = mapped_column(Float)
    metrics: Mapped[dict] = mapped_column(JSON)
    n_points: Mapped[int] = mapped_column(Integer)
    codec: Mapped[str] = mapped_column(String(32))
    loop_data: Mapped[bytes] = mapped_column(LargeBinary)  # displacement_m and force_n arrays

    test: Mapped[TestRecord] = relationship(back_populates="cycles")


class EventRecord(Base):
    __tablename__ = "events"

    id: Mapped[int] = mapped_column(Integer, primary_key=True)
    test_id: Mapped[int | None] = mapped_column(Integer, index=True)
    rig_name: Mapped[str | None] = mapped_column(String(64), index=True)  # the test's rig; None: not a rig's
    created_at: Mapped[datetime] = mapped_column(DateTime(timezone=True), default=utcnow, index=True)
    time_s: Mapped[float | None] = mapped_column(Float)  # test time, when it concerns a running test
    kind: Mapped[str] = mapped_column(String(32))  # limit_trip | operator | status
    actor: Mapped[str] = mapped_column(String(64), default="system")
    message: Mapped[str] = mapped_column(Text)
    values: Mapped[dict] = mapped_column(JSON, default=dict)


class UserIsolator(Base):
    __tablename__ = "user_isolators"

    name: Mapped[str] = mapped_column(String(64), primary_key=True)
    created_at: Mapped[datetime] = mapped_column(DateTime(timezone=True), default=utcnow)
    definition: Mapped[dict] = mapped_column(JSON)


class UserAccount(Base):
    """A person (or a named service account) who may act: their role and their password's argon2 hash."""

    __tablename__ = "users"

    id: Mapped[int] = mapped_column(Integer, primary_key=True)
    name: Mapped[str] = mapped_column(String(64), unique=True)
    role: Mapped[str] = mapped_column(String(16))  # backend.accounts.ROLES
    password_hash: Mapped[str | None] = mapped_column(String(200))  # None: no password login (token only)
    created_at: Mapped[datetime] = mapped_column(DateTime(timezone=True), default=utcnow)
    disabled_at: Mapped[datetime | None] = mapped_column(DateTime(timezone=True))


class Credential(Base):
    """A login session (a browser's cookie) or an API token (scripts), stored as the SHA-256 of the secret."""

    __tablename__ = "credentials"

    id: Mapped[int] = mapped_column(Integer, primary_key=True)
    secret_sha256: Mapped[str] = mapped_column(String(64), unique=True)
    kind: Mapped[str] = mapped_column(String(16))  # session | token
    user_id: Mapped[int] = mapped_column(ForeignKey("users.id", ondelete="CASCADE"), index=True)
    created_at: Mapped[datetime] = mapped_column(DateTime(timezone=True), default=utcnow)
    expires_at: Mapped[datetime | None] = mapped_column(DateTime(timezone=True))  # None: until revoked
    revoked_at: Mapped[datetime | None] = mapped_column(DateTime(timezone=True))

    user: Mapped[UserAccount] = relationship()


class LabSettings(Base):
    """The lab's settings, set in the console by an admin (one row, id 1): its name, address and logo in every
    report, and the units a console shows until a person chooses others (backend.lab)."""

    __tablename__ = "lab_settings"

    id: Mapped[int] = mapped_column(Integer, primary_key=True)
    name: Mapped[str] = mapped_column(String(200), default="")
    address: Mapped[str] = mapped_column(Text, default="")
    units: Mapped[str] = mapped_column(String(8), default="lab")  # lab (mm, kN) | si
    logo: Mapped[bytes | None] = mapped_column(LargeBinary)  # PNG or JPEG as uploaded
    logo_type: Mapped[str | None] = mapped_column(String(32))  # image/png | image/jpeg
    updated_at: Mapped[datetime | None] = mapped_column(DateTime(timezone=True))
    updated_by: Mapped[str | None] = mapped_column(String(64))


class ApprovedReport(Base):
    """The report of an approved record as it was rendered at the approval (backend.review): served from then on,
    so a later change of the lab's name, address, logo or units never changes what was approved."""

    __tablename__ = "approved_reports"

    test_id: Mapped[int] = mapped_column(ForeignKey("tests.id", ondelete="CASCADE"), primary_key=True)
    created_at: Mapped[datetime] = mapped_column(DateTime(timezone=True), default=utcnow)
    pdf: Mapped[bytes] = mapped_column(LargeBinary)
    sha256: Mapped[str] = mapped_column(String(64))
    lab_name: Mapped[str] = mapped_column(String(200), default="")  # the lab and units it was rendered with
    units: Mapped[str] = mapped_column(String(8), default="lab")


class AcceptanceTolerance(Base):
    """The lab's tolerances for a protocol's check against the specimen's design values (backend.reports.design):
    each test cycle and each level's mean, as fractions; no row: EN 15129's type-test tolerances."""

    __tablename__ = "acceptance_tolerances"

    protocol: Mapped[str] = mapped_column(String(64), primary_key=True)
    k_eff_fraction: Mapped[float] = mapped_column(Float)
    edc_fraction: Mapped[float] = mapped_column(Float)
    xi_eff_fraction: Mapped[float] = mapped_column(Float)
    mean_fraction: Mapped[float] = mapped_column(Float)
    updated_at: Mapped[datetime | None] = mapped_column(DateTime(timezone=True))
    updated_by: Mapped[str | None] = mapped_column(String(64))
