"""Issue 34, item 3: an approved record's report is fixed at its approval. The PDF is rendered then and kept
with its SHA-256; renaming the lab or switching its units afterwards changes nothing the report route serves.
The approver's note is printed; an approval whose report cannot be made approves nothing."""

from __future__ import annotations

import hashlib
import shutil
import subprocess

import pytest
from conftest import wait_for
from test_accounts import add, token_of

from backend.models import ApprovedReport

PDFTOTEXT = shutil.which("pdftotext")
NOTE = "Loops as expected; force transducer recalibrated 2026-11-20."


@pytest.fixture
def lab(client):
    for name, role in (("otto", "operator"), ("anna", "approver"), ("adam", "admin")):
        add(client, name, role)
    return client, {name: token_of(client, name) for name in ("otto", "anna", "adam")}


def quick_protocol_test(client, headers) -> int:
    body = {"isolator": "IUT_a", "supply_bar": 100, "controller": "servo", "speed": 40.0,
            "profile": {"kind": "protocol", "name": "quick_check"}}
    r = client.post("/api/tests?start=true", json=body, headers=headers)
    assert r.status_code == 201, r.text
    rec = wait_for(client, r.json()["id"], timeout_s=60)
    assert rec["status"] == "completed", rec["reason"]
    return rec["id"]


def pdf_text(data: bytes, tmp_path) -> str:
    path = tmp_path / "r.pdf"
    path.write_bytes(data)
    return subprocess.run([PDFTOTEXT, "-layout", str(path), "-"], check=True, capture_output=True, text=True,
                          timeout=60).stdout


@pytest.mark.skipif(PDFTOTEXT is None, reason="pdftotext (poppler-utils) is not installed")
def test_the_approved_report_is_kept_and_a_later_lab_change_does_not_touch_it(lab, tmp_path):
    c, who = lab
    assert c.put("/api/lab", json={"name": "Rig Hall A", "units": "lab"}, headers=who["adam"]).status_code == 200
    test_id = quick_protocol_test(c, who["otto"])
    r = c.post(f"/api/tests/{test_id}/approve", json={"note": NOTE}, headers=who["anna"])
    assert r.status_code == 200, r.text
    review = r.json()["review"]
    assert len(review["report_sha256"]) == 64

    first = c.get(f"/api/tests/{test_id}/report.pdf")
    assert first.status_code == 200 and first.headers["x-report-sha256"] == review["report_sha256"]
    assert hashlib.sha256(first.content).hexdigest() == review["report_sha256"]
    text = pdf_text(first.content, tmp_path)
    assert "Rig Hall A" in text and "kN/mm" in text
    assert f"Note of the approver (anna): {NOTE}" in text
    assert review["record_sha256"] in text

    # the lab renames itself and switches to SI units: the approved report stays as it was approved
    assert c.put("/api/lab", json={"name": "Seismic Lab B", "units": "si"}, headers=who["adam"]).status_code == 200
    later = c.get(f"/api/tests/{test_id}/report.pdf")
    assert later.status_code == 200 and later.content == first.content
    assert hashlib.sha256(later.content).hexdigest() == c.get(f"/api/tests/{test_id}").json()["review"][
        "report_sha256"]
    check = c.get(f"/api/tests/{test_id}/approval").json()
    assert check["intact"] is True and check["report_intact"] is True
    assert check["report_sha256_now"] == review["report_sha256"]
    # the zip carries the same PDF
    import io
    import zipfile

    with zipfile.ZipFile(io.BytesIO(c.get(f"/api/tests/{test_id}/bundle.zip").content)) as zf:
        assert zf.read(f"test-{test_id}/report.pdf") == first.content

    # a record not approved is reported as the lab is now
    other = quick_protocol_test(c, who["otto"])
    now = pdf_text(c.get(f"/api/tests/{other}/report.pdf").content, tmp_path)
    assert "Seismic Lab B" in now and "Rig Hall A" not in now


def test_a_kept_report_changed_in_the_database_is_not_served(lab):
    c, who = lab
    test_id = quick_protocol_test(c, who["otto"])
    assert c.post(f"/api/tests/{test_id}/approve", json={}, headers=who["anna"]).status_code == 200
    with c.app.state.sessions() as session:  # someone edits the stored PDF behind the service's back
        kept = session.get(ApprovedReport, test_id)
        kept.pdf = kept.pdf.replace(b"test report", b"test rep0rt", 1)
        session.commit()
    r = c.get(f"/api/tests/{test_id}/report.pdf")
    assert r.status_code == 409 and "no longer matches" in r.json()["detail"]
    check = c.get(f"/api/tests/{test_id}/approval").json()
    assert check["report_intact"] is False and "stored report has changed" in check["words"]


def test_an_approval_whose_report_cannot_be_made_approves_nothing(lab, monkeypatch):
    c, who = lab
    test_id = quick_protocol_test(c, who["otto"])
    events_before = len(c.get(f"/api/tests/{test_id}").json()["events"])
    import backend.reports as reports

    def broken(*args, **kwargs):
        raise RuntimeError("the renderer is out of memory")

    monkeypatch.setattr(reports, "report_pdf_bytes", broken)
    r = c.post(f"/api/tests/{test_id}/approve", json={"note": "fine"}, headers=who["anna"])
    assert r.status_code == 422, r.text
    assert "was not approved" in r.json()["detail"] and "out of memory" in r.json()["detail"]
    rec = c.get(f"/api/tests/{test_id}").json()
    assert rec["review"]["state"] == "unreviewed" and rec["review"]["report_sha256"] is None
    assert len(rec["events"]) == events_before  # no approval event either
    with c.app.state.sessions() as session:
        assert session.get(ApprovedReport, test_id) is None
    monkeypatch.undo()
    assert c.post(f"/api/tests/{test_id}/approve", json={}, headers=who["anna"]).status_code == 200


def test_the_lab_sets_its_tolerances_per_protocol(lab):
    c, who = lab
    test_id = quick_protocol_test(c, who["otto"])
    default = c.get("/api/acceptance/tolerances").json()
    assert default["default"]["k_eff"] == 0.15 and default["default"]["mean"] == 0.10 and default["protocols"] == {}
    acc = c.get(f"/api/tests/{test_id}/acceptance").json()
    assert [lv["verdict"] for lv in acc["design"]["levels"]] == ["PASSED", "PASSED"]
    assert acc["design"]["tolerances"]["k_eff"] == 0.15
    bad = c.put("/api/acceptance/tolerances/quick_check", json={"k_eff": 15, "edc": 0.1, "xi_eff": 0.1, "mean": 0.1},
                headers=who["adam"])
    assert bad.status_code == 422 and "k_eff" in bad.text
    assert c.put("/api/acceptance/tolerances/quick_check", json={"k_eff": 0.2, "edc": 0.2, "xi_eff": 0.2,
                                                                 "mean": 0.05}, headers=who["anna"]).status_code == 403
    r = c.put("/api/acceptance/tolerances/quick_check", json={"k_eff": 0.2, "edc": 0.2, "xi_eff": 0.2,
                                                              "mean": 0.05}, headers=who["adam"])
    assert r.status_code == 200 and r.json()["protocols"]["quick_check"]["updated_by"] == "adam"
    acc = c.get(f"/api/tests/{test_id}/acceptance").json()
    assert acc["design"]["tolerances"] == {"k_eff": 0.2, "edc": 0.2, "xi_eff": 0.2, "mean": 0.05}
    assert "set by the lab" in acc["design"]["source"]
    assert c.delete("/api/acceptance/tolerances/quick_check", headers=who["adam"]).json()["protocols"] == {}
