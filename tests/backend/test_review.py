"""Review and approval (backend.review): by an approver who did not run the test; an approved record is locked,
its SHA-256 kept, printed in the report and checkable later."""

from __future__ import annotations

import pytest
from conftest import sine_test, wait_for
from sqlalchemy import text
from test_accounts import add, token_of

from backend import store


@pytest.fixture
def lab(client):
    for name, role in (("otto", "operator"), ("anna", "approver"), ("alma", "approver"), ("adam", "admin")):
        add(client, name, role)
    return client, {name: token_of(client, name) for name in ("otto", "anna", "alma", "adam")}


def run_test(client, headers) -> int:
    r = client.post("/api/tests?start=true", json=sine_test(), headers=headers)
    assert r.status_code == 201, r.text
    rec = wait_for(client, r.json()["id"])
    assert rec["status"] == "completed", rec["reason"]
    return rec["id"]


def test_an_approver_who_did_not_run_it_approves_and_the_record_is_locked(lab):
    c, who = lab
    test_id = run_test(c, who["otto"])
    assert c.get(f"/api/tests/{test_id}").json()["review"]["state"] == "unreviewed"
    r = c.post(f"/api/tests/{test_id}/approve", json={}, headers=who["otto"])
    assert r.status_code == 403 and "needs the role approver" in r.json()["detail"]  # an operator cannot approve
    r = c.post(f"/api/tests/{test_id}/approve", json={"note": "loops as expected"}, headers=who["anna"])
    assert r.status_code == 200, r.text
    review = r.json()["review"]
    assert review["state"] == "approved" and review["by"] == "anna" and len(review["record_sha256"]) == 64
    assert review["note"] == "loops as expected"
    events = c.get(f"/api/tests/{test_id}").json()["events"]
    assert events[-1]["kind"] == "review" and events[-1]["actor"] == "anna"
    # locked: no second review, no archive
    for path, body in ((f"/api/tests/{test_id}/approve", {}), (f"/api/tests/{test_id}/reject", {"reason": "late"}),
                       (f"/api/tests/{test_id}/archive", {"reason": "tidy up"})):
        r = c.post(path, json=body, headers=who["adam"])
        assert r.status_code == 409 and "approved" in r.json()["detail"], (path, r.text)
    assert c.get(f"/api/tests/{test_id}/approval").json()["intact"] is True


def test_nobody_approves_a_test_they_ran(lab):
    c, who = lab
    test_id = run_test(c, who["anna"])  # an approver may run tests, but not approve their own
    r = c.post(f"/api/tests/{test_id}/approve", json={}, headers=who["anna"])
    assert r.status_code == 403 and "anna ran test" in r.json()["detail"]
    # nor one started by someone else but created by them
    created = c.post("/api/tests", json=sine_test(), headers=who["alma"]).json()["id"]
    assert c.post(f"/api/tests/{created}/start", headers=who["otto"]).status_code == 200
    wait_for(c, created)
    assert c.post(f"/api/tests/{created}/approve", json={}, headers=who["alma"]).status_code == 403
    assert c.post(f"/api/tests/{created}/approve", json={}, headers=who["anna"]).status_code == 200


def test_only_an_ended_record_is_reviewed(lab):
    c, who = lab
    ready = c.post("/api/tests", json=sine_test(), headers=who["otto"]).json()["id"]
    r = c.post(f"/api/tests/{ready}/approve", json={}, headers=who["anna"])
    assert r.status_code == 409 and "once its test has ended" in r.json()["detail"]


def test_a_rejection_needs_a_reason_and_a_later_approval_may_follow(lab):
    c, who = lab
    test_id = run_test(c, who["otto"])
    assert c.post(f"/api/tests/{test_id}/reject", json={"reason": ""}, headers=who["anna"]).status_code == 422
    r = c.post(f"/api/tests/{test_id}/reject", json={"reason": "wrong specimen id"}, headers=who["anna"])
    assert r.status_code == 200 and r.json()["review"] == {"state": "rejected", "by": "anna",
                                                            "at": r.json()["review"]["at"],
                                                            "note": "wrong specimen id", "record_sha256": None,
                                                            "report_sha256": None}
    assert c.get(f"/api/tests/{test_id}/approval").json()["intact"] is None
    assert c.post(f"/api/tests/{test_id}/approve", json={}, headers=who["alma"]).status_code == 200


def test_a_record_changed_after_its_approval_no_longer_matches(lab):
    c, who = lab
    test_id = run_test(c, who["otto"])
    approved = c.post(f"/api/tests/{test_id}/approve", json={}, headers=who["anna"]).json()["review"]["record_sha256"]
    # the approval's own event comes after the hashed ones: the record still matches
    assert c.get(f"/api/tests/{test_id}/approval").json()["sha256_now"] == approved
    with c.app.state.sessions() as session:  # someone edits the database behind the service's back
        session.execute(text("UPDATE cycles SET metrics = :m WHERE test_id = :t AND cycle = 1"),
                        {"m": '{"k_eff_n_per_m": 1.0}', "t": test_id})
        session.commit()
    check = c.get(f"/api/tests/{test_id}/approval").json()
    assert check["intact"] is False and check["sha256_now"] != approved and "has changed" in check["words"]


@pytest.mark.parametrize("part", ["sample", "field", "event"])
def test_the_hash_covers_samples_fields_and_events(lab, part):
    c, who = lab
    test_id = run_test(c, who["otto"])
    c.post(f"/api/tests/{test_id}/approve", json={}, headers=who["anna"])
    with c.app.state.sessions() as session:
        if part == "sample":
            chunk = session.execute(text("SELECT id, data FROM sample_chunks WHERE test_id = :t ORDER BY seq"),
                                    {"t": test_id}).first()
            data = bytearray(chunk.data)
            data[-1] ^= 1
            session.execute(text("UPDATE sample_chunks SET data = :d WHERE id = :i"), {"d": bytes(data), "i": chunk.id})
        elif part == "field":
            session.execute(text("UPDATE tests SET notes = 'edited' WHERE id = :t"), {"t": test_id})
        else:
            session.execute(text("UPDATE events SET actor = 'mallory' WHERE test_id = :t AND kind = 'operator'"),
                            {"t": test_id})
        session.commit()
    assert c.get(f"/api/tests/{test_id}/approval").json()["intact"] is False


def test_history_filters_by_review_state_and_the_report_names_both(lab):
    c, who = lab
    approved, rejected, open_ = (run_test(c, who["otto"]) for _ in range(3))
    c.post(f"/api/tests/{approved}/approve", json={}, headers=who["anna"])
    c.post(f"/api/tests/{rejected}/reject", json={"reason": "noisy force"}, headers=who["anna"])
    for state, expected in (("approved", approved), ("rejected", rejected), ("unreviewed", open_)):
        listed = [t["id"] for t in c.get(f"/api/tests?review={state}").json()]
        assert listed == [expected], (state, listed)
    assert c.get("/api/tests?review=maybe").status_code == 422
    report = c.get(f"/api/tests/{approved}/report.json").json()["approval"]
    rec = c.get(f"/api/tests/{approved}").json()
    assert report["tested_by"] == "otto" and report["tested_at"] == rec["started_at"]
    assert report["approved_by"] == "anna" and report["approved_at"] == rec["review"]["at"]
    assert report["record_sha256"] == rec["review"]["record_sha256"]
    assert c.get(f"/api/tests/{open_}/report.json").json()["approval"]["approved_by"] is None


def test_the_store_keeps_the_review_with_the_record(lab):
    c, who = lab
    test_id = run_test(c, who["otto"])
    c.post(f"/api/tests/{test_id}/approve", json={}, headers=who["anna"])
    with c.app.state.sessions() as session:
        record = store.test_record(session, store.get_test(session, test_id))
    assert record["review"]["state"] == "approved"
