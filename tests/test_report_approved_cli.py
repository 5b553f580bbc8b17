"""`isorig report TEST_ID` of an approved record writes the PDF kept at its approval, byte for byte, and prints
its SHA-256 (the service serves the same bytes: docs/reports.md); a record without a kept PDF is drawn as before,
and a kept PDF changed in the database is not written."""

from __future__ import annotations

import hashlib
import zipfile

import pytest
from test_reports import _store_test

from isorig.cli import main

#: stands for the PDF rendered at the approval: the command must write these bytes, never draw its own
KEPT = b"%PDF-1.7\n% the report as approved by anna\n%%EOF\n"


def approve(url: str, test_id: int, pdf: bytes = KEPT) -> str:
    from backend import db, review, store

    engine = db.make_engine(url)
    with db.session_factory(engine)() as session:
        test = store.get_test(session, test_id)
        review.approve(session, test, "anna", "as expected", render_report=lambda _t: (pdf, "Rig Hall A", "lab"))
        session.commit()
        digest = test.report_sha256
    engine.dispose()
    return digest


@pytest.fixture
def stored(tmp_path):
    pytest.importorskip("backend.store")
    url = f"sqlite:///{tmp_path / 'store.db'}"
    return url, _store_test(url)


def test_an_approved_record_gets_the_pdf_kept_at_its_approval(stored, tmp_path, capsys):
    url, test_id = stored
    digest = approve(url, test_id)
    assert digest == hashlib.sha256(KEPT).hexdigest()
    out = tmp_path / "approved.pdf"
    assert main(["report", str(test_id), "--out", str(out), "--database-url", url, "--units", "si",
                 "--bundle", str(tmp_path / "b.zip"), "--no-identify"]) == 0
    assert out.read_bytes() == KEPT
    printed = capsys.readouterr()
    assert f"SHA-256 {digest}" in printed.out and "approved (by anna" in printed.out
    assert "the report kept at its approval, not drawn again" in printed.out
    assert "--units do not change it" in printed.err
    with zipfile.ZipFile(tmp_path / "b.zip") as zf:  # the zip's report.pdf is the kept one too, as the service's
        assert zf.read(f"test-{test_id}/report.pdf") == KEPT


def test_a_record_not_approved_is_drawn_as_before(stored, tmp_path, capsys):
    url, test_id = stored
    out = tmp_path / "fresh.pdf"
    assert main(["report", str(test_id), "--out", str(out), "--database-url", url, "--no-identify", "--serial"]) == 0
    assert out.read_bytes()[:5] == b"%PDF-" and out.read_bytes() != KEPT
    printed = capsys.readouterr().out
    assert "SHA-256" not in printed and "acceptance" in printed


def test_a_kept_pdf_changed_in_the_database_is_not_written(stored, tmp_path, capsys):
    from sqlalchemy import update

    from backend import db
    from backend.models import ApprovedReport

    url, test_id = stored
    approve(url, test_id)
    engine = db.make_engine(url)
    with db.session_factory(engine)() as session:
        session.execute(update(ApprovedReport).where(ApprovedReport.test_id == test_id)
                        .values(pdf=KEPT.replace(b"anna", b"otto")))
        session.commit()
    engine.dispose()
    out = tmp_path / "changed.pdf"
    assert main(["report", str(test_id), "--out", str(out), "--database-url", url]) == 2
    assert "no longer matches its SHA-256" in capsys.readouterr().err and not out.exists()
