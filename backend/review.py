"""Review and approval of a test record (ISO/IEC 17025: a result reviewed by a second person, then locked).

An approver who did not run the test approves it (or rejects it with a reason). Approval locks the record: no
archive, restore or deletion, and nothing of it may change. It keeps the record's SHA-256 at that moment: the
test's fields as stored, every sample chunk and cycle (their bytes' SHA-256) and every event up to the approval.
Anyone can later recompute it (``GET /api/tests/{id}/approval``) and compare it with the one printed in the
report: a record changed after its approval no longer matches.

The report is fixed at the approval: its PDF is rendered then (``render_report``, given by the API: the lab's
header and units as they are at that moment) and stored with its SHA-256 (``ApprovedReport``); the report route
serves those bytes from then on. An approval whose report cannot be made approves nothing.
"""

from __future__ import annotations

import hashlib
import json

from sqlalchemy import func, select
from sqlalchemy.orm import Session

from .models import FINAL_STATUSES, ApprovedReport, CycleRecord, EventRecord, SampleChunk, TestRecord, utcnow
from .store import _iso, add_event, review_fields

STATES = ("unreviewed", "approved", "rejected")
HASHED_FIELDS = ("id", "created_at", "started_at", "ended_at", "status", "reason", "label", "specimen_id",
                 "operator_name", "notes", "isolator", "supply_bar", "vertical_load_n", "controller", "speed",
                 "driver", "request", "scenario", "limits", "duration_s", "cycles_total", "samples_stored", "time_s",
                 "summary")


class ReviewError(Exception):
    """A review the record's state or the reviewer forbids; ``status`` 409 (state) or 403 (who)."""

    def __init__(self, status: int, detail: str):
        super().__init__(detail)
        self.status = status
        self.detail = detail


def sha256_of(data: bytes) -> str:
    """The SHA-256 of bytes, in hex."""
    return hashlib.sha256(data).hexdigest()


_digest = sha256_of


def _value(value):
    return _iso(value) if hasattr(value, "isoformat") else value


def record_sha256(session: Session, test: TestRecord, events_upto: int | None) -> str:
    """SHA-256 of the record as stored: fields, sample chunks, cycles, events with id <= ``events_upto``."""
    h = hashlib.sha256()

    def put(kind: str, item) -> None:
        h.update(json.dumps([kind, item], sort_keys=True, separators=(",", ":"), default=str).encode())
        h.update(b"\n")

    put("test", {name: _value(getattr(test, name)) for name in HASHED_FIELDS})
    for seq, t0, n_rows, n_columns, codec, data in session.execute(
            select(SampleChunk.seq, SampleChunk.t0_s, SampleChunk.n_rows, SampleChunk.n_columns, SampleChunk.codec,
                   SampleChunk.data).where(SampleChunk.test_id == test.id).order_by(SampleChunk.seq)):
        put("chunk", [seq, t0, n_rows, n_columns, codec, _digest(data)])
    for c in session.scalars(select(CycleRecord).where(CycleRecord.test_id == test.id)
                             .order_by(CycleRecord.cycle, CycleRecord.id)):
        put("cycle", [c.cycle, c.block, c.phase, c.t_start_s, c.t_end_s, c.metrics, c.n_points, c.codec,
                      _digest(c.loop_data)])
    if events_upto is not None:
        for e in session.scalars(select(EventRecord).where(EventRecord.test_id == test.id,
                                                           EventRecord.id <= events_upto).order_by(EventRecord.id)):
            put("event", [e.id, _iso(e.created_at), e.time_s, e.kind, e.actor, e.message, e.values])
    return h.hexdigest()


def ran_by(session: Session, test: TestRecord) -> set[str]:
    """The accounts that created or started the test (its operator_name and the actors of those events)."""
    names = {test.operator_name.split(" (through ", 1)[0]} if test.operator_name else set()
    for actor, values in session.execute(select(EventRecord.actor, EventRecord.values)
                                         .where(EventRecord.test_id == test.id, EventRecord.kind == "operator")):
        if (values or {}).get("action") in ("create", "start"):
            names.add(actor)
    return names


def _reviewable(session: Session, test: TestRecord, reviewer: str) -> None:
    if test.status not in FINAL_STATUSES:
        raise ReviewError(409, f"test {test.id} is {test.status}: a record is reviewed once its test has ended")
    if test.review_state == "approved":
        raise ReviewError(409, f"test {test.id} was approved by {test.reviewed_by} at {_iso(test.reviewed_at)}; an "
                               "approved record is locked")
    if reviewer in ran_by(session, test):
        raise ReviewError(403, f"{reviewer} ran test {test.id}: a record is reviewed by an approver who did not "
                               "run it")


def approve(session: Session, test: TestRecord, reviewer: str, note: str = "", render_report=None) -> str:
    """Approve and lock the record; returns its SHA-256. The approval's own event follows the hashed ones.

    ``render_report(test)`` (None: no report is kept) returns ``(pdf_bytes, lab_name, units)`` or None for a
    record that has no report (a manual move); it runs once the approval is in the session, so the PDF prints the
    approver, the note and the hash. If it fails, ReviewError 422 and the caller rolls the session back."""
    _reviewable(session, test, reviewer)
    upto = session.scalar(select(func.max(EventRecord.id)).where(EventRecord.test_id == test.id))
    test.review_state, test.reviewed_by, test.reviewed_at = "approved", reviewer, utcnow()
    test.review_note = note or None
    test.review_events_upto = upto
    test.record_sha256 = record_sha256(session, test, upto)
    add_event(session, test.id, "review", f"test {test.id} approved by {reviewer}",
              {"action": "approve", "record_sha256": test.record_sha256, "note": note}, actor=reviewer)
    if render_report is not None:
        session.flush()
        try:
            made = render_report(test)
        except Exception as exc:  # any failure of the renderer: the approval must not go through without it
            raise ReviewError(422, f"test {test.id} was not approved: its report could not be made "
                                   f"({type(exc).__name__}: {exc}); the record is unchanged") from exc
        if made is not None:
            keep_report(session, test, *made)
    return test.record_sha256


def keep_report(session: Session, test: TestRecord, pdf: bytes, lab_name: str = "", units: str = "lab") -> str:
    """Store the approved report's PDF with its SHA-256 (also on the record: ``report_sha256``)."""
    if not pdf.startswith(b"%PDF"):
        raise ReviewError(422, f"test {test.id} was not approved: the report made is not a PDF")
    digest = _digest(pdf)
    session.merge(ApprovedReport(test_id=test.id, created_at=utcnow(), pdf=pdf, sha256=digest,
                                 lab_name=lab_name or "", units=units or "lab"))
    test.report_sha256 = digest
    return digest


def stored_report(session: Session, test: TestRecord) -> ApprovedReport | None:
    """The PDF kept at the approval, or None (not approved, or approved before reports were kept)."""
    return session.get(ApprovedReport, test.id) if test.report_sha256 else None


def reject(session: Session, test: TestRecord, reviewer: str, reason: str) -> None:
    """The record needs another look (a rejected record may later be approved, after a new review)."""
    _reviewable(session, test, reviewer)
    test.review_state, test.reviewed_by, test.reviewed_at, test.review_note = "rejected", reviewer, utcnow(), reason
    add_event(session, test.id, "review", f"test {test.id} rejected by {reviewer}: {reason}",
              {"action": "reject", "reason": reason}, actor=reviewer)


def check_unlocked(test: TestRecord, action: str) -> None:
    """ReviewError 409 if the record is approved (locked): nothing about it may change."""
    if test.review_state == "approved":
        raise ReviewError(409, f"test {test.id} was approved by {test.reviewed_by}: an approved record is locked "
                               f"and cannot be {action}")


def verify(session: Session, test: TestRecord) -> dict:
    """The approved hash against the record as it is now: ``intact`` True when they agree."""
    out = review_fields(test)
    if test.review_state != "approved":
        return {**out, "sha256_now": None, "intact": None,
                "words": f"test {test.id} is {test.review_state}: only an approved record has a hash to check"}
    now = record_sha256(session, test, test.review_events_upto)
    intact = now == test.record_sha256
    kept = stored_report(session, test)
    report_now = _digest(kept.pdf) if kept is not None else None
    report_intact = None if not test.report_sha256 else report_now == test.report_sha256
    words = ("the record is as it was approved" if intact else
             "the record has changed since its approval: it no longer matches the approved hash")
    if report_intact is False:
        words += "; the stored report has changed since its approval: it no longer matches its hash"
    elif report_intact is None:
        words += "; no report was kept with this approval (approved before reports were kept)"
    return {**out, "sha256_now": now, "intact": intact, "report_sha256_now": report_now,
            "report_intact": report_intact, "words": words}
