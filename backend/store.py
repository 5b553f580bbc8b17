"""All database access in one place: test records, sample chunks, cycles, events, user isolators.

Several services, one per rig, may share the database: a test carries its rig's name (``rig_name``), and what
a service asks of its own rig (tests left running, where its table was left, its last event) is asked per rig.

``load_test_bundle(session, test_id)`` is the contract with reports (docs/architecture.md): the record as
``GET /api/tests/{id}`` returns it, the samples by name (``sim.samples.Samples``), the cycles with their loop
arrays and the events.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from datetime import datetime

import numpy as np
from sqlalchemy import delete, func, or_, select
from sqlalchemy.orm import Session

from sim.samples import N_FIELDS, Samples, check_stored_width

from .codec import ARRAYS_CODEC, SAMPLES_CODEC, decode_arrays, decode_samples, encode_arrays, encode_samples
from .models import CycleRecord, EventRecord, SampleChunk, TestRecord, UserIsolator, as_utc, utcnow


@dataclass
class TestBundle:
    """Everything stored about one test (see docs/architecture.md, "Store bundle")."""

    __test__ = False

    record: dict
    samples: Samples
    cycles: list[dict] = field(default_factory=list)
    events: list[dict] = field(default_factory=list)


def _iso(value: datetime | None) -> str | None:
    """ISO 8601 in UTC (SQLite hands back naive datetimes; they were stored as UTC)."""
    return None if value is None else as_utc(value).isoformat()


def clean_json(value):
    """Replace NaN and infinities by None, recursively (JSON has no NaN)."""
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, dict):
        return {k: clean_json(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [clean_json(v) for v in value]
    if isinstance(value, np.generic):
        return clean_json(value.item())
    return value


# --- tests -----------------------------------------------------------------------------------------------

def create_test(session: Session, *, rig_name: str, **fields) -> TestRecord:
    """A new test (status ``ready``) on the rig ``rig_name`` (a manual move and a commissioning are tests too)."""
    test = TestRecord(rig_name=rig_name, status="ready", samples_stored=0, time_s=0.0, **fields)
    session.add(test)
    session.flush()
    return test


def get_test(session: Session, test_id: int) -> TestRecord | None:
    return session.get(TestRecord, test_id)


def cycles_done(session: Session, test_id: int) -> int:
    return session.scalar(select(func.count()).select_from(CycleRecord).where(CycleRecord.test_id == test_id)) or 0


def test_record(session: Session, test: TestRecord, with_events: bool = True) -> dict:
    """The JSON record of a test (``GET /api/tests/{id}``)."""
    progress = min(1.0, test.time_s / test.duration_s) if test.duration_s > 0 else 0.0
    record = {
        "id": test.id,
        "rig_name": test.rig_name,  # the rig it runs on (the service's --rig-name)
        "status": test.status,
        "reason": test.reason,
        "label": test.label,
        "specimen_id": test.specimen_id or "",
        "operator_name": test.operator_name or "",
        "notes": test.notes or "",
        "created_at": _iso(test.created_at),
        "started_at": _iso(test.started_at),
        "ended_at": _iso(test.ended_at),
        "isolator": test.isolator,
        "supply_bar": test.supply_bar,
        "vertical_load_n": test.vertical_load_n,
        "controller": test.controller,
        "speed": test.speed,
        "driver": test.driver,
        "rig": test.request.get("rig_name"),  # the rig description the service ran with (settings.rig_file)
        # ... its source, what it changes and its commissioning (sim.rigfile.RigDescription.to_dict); None before
        "rig_file": test.request.get("rig_file"),
        "profile": test.request.get("profile"),
        "limits": test.limits,
        "duration_s": test.duration_s,
        "cycles_total": test.cycles_total,
        "cycles_done": cycles_done(session, test.id),
        "time_s": test.time_s,
        "progress": progress,
        "samples_stored": test.samples_stored,
        "scenario": test.scenario,
        "summary": test.summary,
        "archived": None if test.archived_at is None else {"at": _iso(test.archived_at), "by": test.archived_by,
                                                            "reason": test.archive_reason},
        "review": review_fields(test),
    }
    if with_events:
        record["events"] = load_events(session, test.id)
    return clean_json(record)


def review_fields(test: TestRecord) -> dict:
    """The record's review (backend.review): state, who, when, the note or reason, the approved SHA-256 and the
    SHA-256 of the report PDF kept at the approval."""
    return {"state": test.review_state or "unreviewed", "by": test.reviewed_by, "at": _iso(test.reviewed_at),
            "note": test.review_note, "record_sha256": test.record_sha256,
            "report_sha256": test.report_sha256}


def list_tests(session: Session, status: str | None = None, isolator: str | None = None,
               since: datetime | None = None, until: datetime | None = None,
               limit: int = 100, offset: int = 0, archived: bool = False,
               review: str | None = None, rig_name: str | None = None) -> list[TestRecord]:
    """Tests of every rig (or of ``rig_name``) newest first; archived ones only if ``archived`` (then only they);
    ``review`` a review state."""
    query = select(TestRecord).where(TestRecord.archived_at.is_not(None) if archived
                                     else TestRecord.archived_at.is_(None))
    if status:
        query = query.where(TestRecord.status == status)
    if isolator:
        query = query.where(TestRecord.isolator == isolator)
    if review:
        query = query.where(TestRecord.review_state == review)
    if rig_name:
        query = query.where(TestRecord.rig_name == rig_name)
    if since:
        query = query.where(TestRecord.created_at >= since)
    if until:
        query = query.where(TestRecord.created_at <= until)
    query = query.order_by(TestRecord.id.desc()).limit(limit).offset(offset)
    return list(session.scalars(query))


def set_status(session: Session, test: TestRecord, status: str, reason: str | None = None) -> None:
    test.status = status
    if reason is not None:
        test.reason = reason
    if status == "running" and test.started_at is None:
        test.started_at = utcnow()
    if status not in ("ready", "running"):
        test.ended_at = utcnow()


def archive_test(session: Session, test: TestRecord, by: str, reason: str) -> None:
    test.archived_at = utcnow()
    test.archived_by = by
    test.archive_reason = reason


def restore_test(session: Session, test: TestRecord) -> None:
    test.archived_at = test.archived_by = test.archive_reason = None


def delete_test(session: Session, test: TestRecord) -> None:
    """Erase a test that never ran (its record holds no measurement). Tests that ran are archived instead."""
    session.execute(delete(SampleChunk).where(SampleChunk.test_id == test.id))
    session.execute(delete(CycleRecord).where(CycleRecord.test_id == test.id))
    session.delete(test)


def rig_names(session: Session) -> list[str]:
    """The rigs that have tests on record, by name."""
    return list(session.scalars(select(TestRecord.rig_name).distinct().order_by(TestRecord.rig_name)))


def mark_running_interrupted(session: Session, rig_name: str) -> list[int]:
    """On start-up of the service of ``rig_name``: its test left ``running`` (the service died) becomes
    ``interrupted``; its data stay. Another rig's running test is its own service's, and is left alone."""
    ids = []
    for test in session.scalars(select(TestRecord).where(TestRecord.status == "running",
                                                         TestRecord.rig_name == rig_name)):
        set_status(session, test, "interrupted", "the service stopped while the test was running; "
                                                 f"data kept up to t = {test.time_s:.3f} s")
        add_event(session, test.id, "status", f"test {test.id} marked interrupted at service start-up",
                  {"status": "interrupted", "time_s": test.time_s}, time_s=test.time_s)
        ids.append(test.id)
    return ids


# --- samples ---------------------------------------------------------------------------------------------

def append_samples(session: Session, test: TestRecord, rows: np.ndarray | Samples) -> None:
    """Store a block of sample rows (``Samples``, or an array in the ``SAMPLE_FIELDS`` layout) as one chunk."""
    if isinstance(rows, Samples):
        rows = rows.array
    if rows.shape[0] == 0:
        return
    seq = session.scalar(select(func.count()).select_from(SampleChunk).where(SampleChunk.test_id == test.id)) or 0
    session.add(SampleChunk(test_id=test.id, seq=seq, t0_s=float(rows[0, 0]), n_rows=rows.shape[0],
                            n_columns=rows.shape[1], codec=SAMPLES_CODEC, data=encode_samples(rows)))
    test.samples_stored += rows.shape[0]
    test.time_s = float(rows[-1, 0])


def load_samples(session: Session, test_id: int) -> Samples:
    """Every sample of a test by name (sim.samples); fields an older record did not store read as NaN."""
    chunks = session.execute(select(SampleChunk.data, SampleChunk.n_rows, SampleChunk.n_columns)  # no ORM objects
                             .where(SampleChunk.test_id == test_id).order_by(SampleChunk.seq)).all()
    if not chunks:
        return Samples.empty()
    check_stored_width(max(n_columns for _, _, n_columns in chunks))
    rows = np.empty((sum(n_rows for _, n_rows, _ in chunks), N_FIELDS))
    at = 0
    for data, n_rows, n_columns in chunks:  # each chunk decoded in place: one array, no concatenation
        decode_samples(data, n_rows, n_columns, out=rows[at: at + n_rows])
        rows[at: at + n_rows, n_columns:] = np.nan  # fields an older record did not store
        at += n_rows
    return Samples(rows)


def iter_sample_blocks(session: Session, test_id: int):
    """Sample blocks one chunk at a time (for streaming a CSV without holding a long test in memory)."""
    ids = session.scalars(select(SampleChunk.id).where(SampleChunk.test_id == test_id)
                          .order_by(SampleChunk.seq)).all()
    for chunk_id in ids:
        c = session.get(SampleChunk, chunk_id)
        yield Samples.from_stored(decode_samples(c.data, c.n_rows, c.n_columns))
        session.expunge(c)


def storage_bytes(session: Session, test_id: int) -> int:
    return session.scalar(select(func.coalesce(func.sum(func.length(SampleChunk.data)), 0))
                          .where(SampleChunk.test_id == test_id)) or 0


# --- cycles ----------------------------------------------------------------------------------------------

def add_cycle(session: Session, test_id: int, cycle: int, block: int, t_start_s: float, t_end_s: float,
              metrics: dict, displacement_m: np.ndarray, force_n: np.ndarray, phase: str | None = None) -> None:
    session.add(CycleRecord(test_id=test_id, cycle=cycle, block=block, phase=phase, t_start_s=t_start_s,
                            t_end_s=t_end_s,
                            metrics=clean_json(metrics), n_points=len(displacement_m), codec=ARRAYS_CODEC,
                            loop_data=encode_arrays(displacement_m, force_n)))


def load_cycles(session: Session, test_id: int, arrays: bool = True) -> list[dict]:
    """Every stored cycle: number, block, phase (sim.tracking), time span, loop metrics (and the loop)."""
    out = []
    legacy = None
    for c in session.scalars(select(CycleRecord).where(CycleRecord.test_id == test_id).order_by(CycleRecord.cycle)):
        phase = c.phase
        if phase is None:  # stored before phases: the planned profile's phase (a stop's ramp-out is not known)
            if legacy is None:
                legacy = _planned_phases(session, test_id)
            phase = legacy[c.cycle - 1] if c.cycle <= len(legacy) else "steady"
        item = {"cycle": c.cycle, "block": c.block, "phase": phase, "t_start_s": c.t_start_s,
                "t_end_s": c.t_end_s, **c.metrics}
        if arrays:
            d, f = decode_arrays(c.loop_data, c.n_points, 2)
            item["displacement_m"] = d
            item["force_n"] = f
        out.append(item)
    return out


def _planned_phases(session: Session, test_id: int) -> list[str]:
    from sim.profiles import blocks_from_dicts
    from sim.tracking import cycle_phases

    test = get_test(session, test_id)
    blocks = (test.scenario or {}).get("profile") or [] if test is not None else []
    try:
        return cycle_phases(blocks_from_dicts(blocks))
    except (KeyError, TypeError, ValueError):
        return []


# --- events ----------------------------------------------------------------------------------------------

def add_event(session: Session, test_id: int | None, kind: str, message: str, values: dict | None = None,
              actor: str = "system", time_s: float | None = None, rig_name: str | None = None) -> EventRecord:
    """An event of the audit log; ``rig_name`` defaults to the test's rig (None: an event of no rig's)."""
    if rig_name is None and test_id is not None:
        test = session.get(TestRecord, test_id)
        rig_name = test.rig_name if test is not None else None
    ev = EventRecord(test_id=test_id, rig_name=rig_name, kind=kind, message=message,
                     values=clean_json(values or {}), actor=actor, time_s=time_s, created_at=utcnow())
    session.add(ev)
    return ev


def event_dict(ev: EventRecord) -> dict:
    return {"id": ev.id, "test_id": ev.test_id, "rig_name": ev.rig_name, "created_at": _iso(ev.created_at),
            "time_s": ev.time_s, "kind": ev.kind, "actor": ev.actor, "message": ev.message, "values": ev.values}


def load_events(session: Session, test_id: int | None, rig_name: str | None = None,
                limit: int | None = None) -> list[dict]:
    """Events in the order they happened: of one test, or all; of one rig (and of no rig) if ``rig_name``; the
    newest ``limit`` only, if given (selected in the database, not after loading them all)."""
    query = select(EventRecord)
    query = query.where(EventRecord.test_id == test_id) if test_id is not None else query
    if rig_name is not None:
        query = query.where(or_(EventRecord.rig_name == rig_name, EventRecord.rig_name.is_(None)))
    if limit is None:
        return [event_dict(ev) for ev in session.scalars(query.order_by(EventRecord.id))]
    newest = session.scalars(query.order_by(EventRecord.id.desc()).limit(limit)).all()
    return [event_dict(ev) for ev in reversed(newest)]


def last_event(session: Session, rig_name: str) -> dict | None:
    """The newest event of the rig ``rig_name`` or of no rig (a user isolator added), not another rig's."""
    ev = session.scalars(select(EventRecord).where(or_(EventRecord.rig_name == rig_name,
                                                       EventRecord.rig_name.is_(None)))
                         .order_by(EventRecord.id.desc()).limit(1)).first()
    return event_dict(ev) if ev is not None else None


def last_sample(session: Session, rig_name: str) -> tuple[TestRecord, Samples] | None:
    """The newest test of the rig ``rig_name`` that stored samples and its last sample (where that rig's table
    was when it ended)."""
    test = session.scalars(select(TestRecord).where(TestRecord.samples_stored > 0, TestRecord.rig_name == rig_name)
                           .order_by(TestRecord.id.desc()).limit(1)).first()
    if test is None:
        return None
    chunk = session.scalars(select(SampleChunk).where(SampleChunk.test_id == test.id)
                            .order_by(SampleChunk.seq.desc()).limit(1)).first()
    if chunk is None:
        return None
    rows = Samples.from_stored(decode_samples(chunk.data, chunk.n_rows, chunk.n_columns))
    return test, rows[len(rows) - 1:]


# --- user isolators --------------------------------------------------------------------------------------

def list_user_isolators(session: Session) -> list[dict]:
    return [u.definition for u in session.scalars(select(UserIsolator).order_by(UserIsolator.name))]


def get_user_isolator(session: Session, name: str) -> dict | None:
    row = session.get(UserIsolator, name)
    return row.definition if row is not None else None


def delete_user_isolator(session: Session, name: str) -> bool:
    """Remove a user isolator (records keep their own copy of its parameters). False if there was none."""
    row = session.get(UserIsolator, name)
    if row is None:
        return False
    session.delete(row)
    return True


def add_user_isolator(session: Session, definition: dict) -> None:
    session.add(UserIsolator(name=definition["name"], definition=definition))


# --- bundle ----------------------------------------------------------------------------------------------

def load_test_bundle(session: Session, test_id: int) -> TestBundle:
    """Record, samples (``sim.samples.Samples``), cycles (metrics + loop arrays) and events of one test. The
    record is ``GET /api/tests/{id}``'s, plus for a history or hybrid test ``earthquake`` (the profile's spec as
    asked, inline arrays included) and ``earthquake_fingerprint``."""
    test = get_test(session, test_id)
    if test is None:
        raise KeyError(f"test {test_id} does not exist")
    record = test_record(session, test)
    job = (test.request or {}).get("job_scenario") or {}
    if job.get("earthquake") is not None:  # a history or hybrid test: the spec as asked (arrays included), so a
        record["earthquake"] = job["earthquake"]  # report rebuilds the ground motion and the reference
        record["earthquake_fingerprint"] = job.get("earthquake_fingerprint")
    return TestBundle(record=record, samples=load_samples(session, test_id),
                      cycles=load_cycles(session, test_id), events=load_events(session, test_id))
