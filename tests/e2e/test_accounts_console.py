"""Accounts in the console (issue 22): the login dialog and the account button, a wrong password said in the
dialog, a viewer who may read but not start, and an approver who approves a record on its page (locked, its
SHA-256 shown and checked), History filtered by review state. Screenshots at 1366x768 and 1920x1080."""

from __future__ import annotations

from .harness import WAIT_MS, hold_back_answer, shots, sine_test

APPROVER = ("e2e-approver", "e2e-approver-password")
VIEWER = ("e2e-viewer", "e2e-viewer-password")


def test_an_approver_logs_in_and_approves_a_record(server, open_page, artifacts):
    server.add_account(*APPROVER, role="approver")
    test_id = server.start_test(sine_test(cycles=2, speed=4.0))  # run by the service account 'automation'
    assert server.wait_status(test_id, {"completed"}, timeout_s=60)["status"] == "completed"

    page, watch = open_page(f"{server.url}/#/tests/{test_id}", width=1366, height=768)
    # the wrong password's answer is a 401, which the browser logs: expected here, nothing else is
    watch.allowed_patterns.append(r"^Failed to load resource: the server responded with a status of 401 ")
    page.wait_for_selector("#t-review-state:has-text('not reviewed')", timeout=WAIT_MS)
    assert page.inner_text("#account-button") == "log in"
    page.click("#t-approve")  # nobody logged in: the console asks first
    page.wait_for_selector("#login-dialog[open]", timeout=WAIT_MS)
    page.fill("#login-name", APPROVER[0])
    page.fill("#login-password", "not the password")
    page.click("#login-ok")
    page.wait_for_selector("#login-reason:has-text('wrong name or password')", timeout=WAIT_MS)
    assert page.is_visible("#login-dialog")  # stays open, the password cleared
    assert page.input_value("#login-password") == ""
    shots(page, artifacts, "accounts_login_refused")
    page.fill("#login-password", APPROVER[1])
    page.click("#login-ok")
    page.wait_for_selector("#confirm-dialog[open]", timeout=WAIT_MS)
    assert f"Approved by {APPROVER[0]}" in page.inner_text("#confirm-body")
    page.fill("#confirm-body textarea", "loops as expected")
    page.click("#confirm-ok")
    page.wait_for_selector("#t-review-state:has-text('approved')", timeout=WAIT_MS)
    assert page.inner_text("#account-button .acct-name") == APPROVER[0]
    assert page.inner_text("#account-button .acct-role") == "approver"
    rec = server.call("GET", f"/api/tests/{test_id}")[1]
    assert rec["review"]["by"] == APPROVER[0] and rec["review"]["note"] == "loops as expected"
    assert rec["review"]["record_sha256"] in page.inner_text("#t-review-hash")
    # the report PDF kept at the approval: its SHA-256 beside the record's, and checked with it
    assert len(rec["review"]["report_sha256"]) == 64
    assert f"report PDF SHA-256 {rec['review']['report_sha256']}" in page.inner_text("#t-review-hash")
    assert "locked" in page.inner_text("#t-review-words")
    assert not page.is_visible("#t-action")  # no archive of an approved record
    page.click("#t-verify")
    page.wait_for_selector("#t-verify-result:has-text('intact')", timeout=WAIT_MS)
    assert "and so is its report PDF" in page.inner_text("#t-verify-result")
    shots(page, artifacts, "accounts_approved_record")

    # History filtered by review state. The unfiltered list that opening History asks for is made to answer
    # after the filtered one (as it may on a loaded service): the table must keep the filtered list
    hold_back_answer(page, "/api/tests?")
    page.goto(f"{server.url}/#/history")  # the same page: only its hash changes
    # the filter is asked for once the unfiltered list has been: asked earlier, History rightly never sends the
    # unfiltered one (its rig list was still loading), and there is no late answer to keep out (a loaded CI run)
    page.wait_for_function("window.__heldBackAsked", timeout=WAIT_MS)
    page.select_option("#h-review", "approved")
    page.click("#history-filter button[type=submit]")
    page.wait_for_selector("#history-table[data-query='review=approved']", timeout=WAIT_MS)
    page.wait_for_function("window.__heldBackAnswered", timeout=WAIT_MS)
    page.wait_for_selector(f"#history-table tr[data-id='{test_id}'] .review-approved", timeout=WAIT_MS)
    assert page.get_attribute("#history-table", "data-query") == "review=approved"
    ids = page.eval_on_selector_all("#history-table tbody tr[data-id]", "rows => rows.map(r => r.dataset.id)")
    assert ids == [str(test_id)], ids
    shots(page, artifacts, "accounts_history_approved")

    page.click("#account-button")  # logs out, on the server too
    page.wait_for_selector("#account-button:has-text('log in')", timeout=WAIT_MS)
    who = page.evaluate("fetch('/api/session').then(r => r.json())")
    assert who["name"] is None, who


def test_a_viewer_reads_but_may_not_start(server, open_page, artifacts):
    server.add_account(*VIEWER, role="viewer")
    page, watch = open_page(server.url + "/", width=1920, height=1080, login=VIEWER)
    watch.allowed_patterns.append(r"^Failed to load resource: the server responded with a status of 403 ")  # Start
    page.wait_for_selector("#account-button[data-role='viewer']", timeout=WAIT_MS)
    assert page.input_value("#f-operator_name") == VIEWER[0]  # who acts is the account, not typed
    assert page.get_attribute("#f-operator_name", "readonly") is not None
    page.fill("#f-specimen_id", "VIEWER-1")
    page.fill("#f-cycles", "2")
    page.wait_for_selector("#start:not([disabled])", timeout=WAIT_MS)
    before = len(server.call("GET", "/api/tests")[1])
    page.click("#start")
    page.wait_for_selector("#confirm-dialog[open]", timeout=WAIT_MS)
    page.click("#confirm-ok")
    page.wait_for_selector("#setup-message:has-text('needs the role operator')", timeout=WAIT_MS)
    assert len(server.call("GET", "/api/tests")[1]) == before  # nothing was created
    shots(page, artifacts, "accounts_viewer_refused")


def test_a_late_answer_for_the_test_page_left_behind_never_lands_on_the_next(server, open_page):
    """Opening test A, then test B before A's record has come: A's late answer is dropped. B's page shows B
    alone, and its buttons act on B (before the fix A's rows were appended under "Test #B" and the review and
    archive buttons were bound to A)."""
    first, second = 0, 0
    for name in ("PAGE-A", "PAGE-B"):
        first, second = second, server.start_test({**sine_test(cycles=2, speed=4.0), "specimen_id": name})
        assert server.wait_status(second, {"completed"}, timeout_s=60)["status"] == "completed"
    page, _ = open_page(f"{server.url}/#/history", width=1366, height=768)
    page.wait_for_selector(f"#history-table tr[data-id='{second}']", timeout=WAIT_MS)
    hold_back_answer(page, f"/api/tests/{first}")
    page.goto(f"{server.url}/#/tests/{first}")
    page.goto(f"{server.url}/#/tests/{second}")
    page.wait_for_selector("#t-summary .kv", timeout=WAIT_MS)
    page.wait_for_function("window.__heldBackAnswered", timeout=WAIT_MS)
    page.wait_for_timeout(300)  # whatever the late answer would draw has been drawn
    assert page.inner_text("#t-title") == f"Test #{second}"
    summary = page.inner_text("#t-summary")
    assert "PAGE-B" in summary and "PAGE-A" not in summary, summary
    assert page.locator("#t-summary .kv span", has_text="specimen").count() == 1
    assert page.get_attribute("#t-csv", "href") == f"/api/tests/{second}/data.csv"
    page.click("#t-action")  # archive: the dialog names the test on the page
    page.wait_for_selector("#confirm-dialog[open]", timeout=WAIT_MS)
    assert page.inner_text("#confirm-title") == f"Archive test #{second}?"
    page.click("#confirm-cancel")
