"""The operator's day in the console (issue 34 item 4): History rows are links; a test page's review hint follows a
login; the live view during a test at 1366x768 shows the loop above the fold and, in SI units, a tracking-error
axis whose ticks are not "0" and "-0"; an interrupted test's header agrees with its stored cycles; a commissioning
asks for the login before its confirmation, which names the operator, its list does not say "running" after the
end, and another console learns of the applied rig file without a reload. Screenshots at 1366x768 and 1920x1080."""

from __future__ import annotations

import re

import pytest

from .harness import OPERATOR, TOKEN, WAIT_MS, Server, log_in_dialog, poll, shots, sine_test

APPROVER = ("e2e-day-approver", "e2e-day-approver-password")


def _start_slowly(srv: Server, body: dict, timeout_s: float = 180.0) -> int:
    """server.start_test with time for a fresh service's first start on a loaded machine (its worker process is
    made then; the harness's 30 s were not always enough)."""
    import json
    import urllib.request

    def post(path: str, data: dict | None) -> dict:
        req = urllib.request.Request(f"{srv.url}{path}", method="POST", data=json.dumps(data or {}).encode(),
                                     headers={"Content-Type": "application/json", "Authorization": f"Bearer {TOKEN}"})
        with urllib.request.urlopen(req, timeout=timeout_s) as r:
            return json.loads(r.read())

    test_id = post("/api/tests", body)["id"]
    post(f"/api/tests/{test_id}/start", None)
    return test_id


def _ended_test(server, **kw) -> int:
    test_id = _start_slowly(server, sine_test(**{"cycles": 2, "speed": 4.0, **kw}))
    assert server.wait_status(test_id, {"completed"}, timeout_s=60)["status"] == "completed"
    return test_id


def test_history_rows_are_links_to_the_tests_page(server, open_page, artifacts):
    test_id = _ended_test(server)
    page, _ = open_page(f"{server.url}/#/history", width=1366, height=768)
    link = page.locator(f"#history-table tr[data-id='{test_id}'] a.test-link")
    link.wait_for(timeout=WAIT_MS)
    assert link.get_attribute("href") == f"#/tests/{test_id}"  # a link: a new tab, the keyboard, a copied address
    shots(page, artifacts, "day_history_links")
    link.focus()
    page.keyboard.press("Enter")
    page.wait_for_selector(f"#t-title:has-text('#{test_id}')", timeout=WAIT_MS)
    assert page.url.endswith(f"#/tests/{test_id}")


def test_the_review_hint_follows_a_login_and_a_logout(server, open_page, artifacts):
    server.add_account(*APPROVER, role="approver")
    test_id = _ended_test(server)  # run by the service account: any approver may review it
    page, _ = open_page(f"{server.url}/#/tests/{test_id}", width=1366, height=768)
    page.wait_for_selector("#t-review-why:has-text('log in as an approver to review')", timeout=WAIT_MS)
    page.click("#account-button")
    log_in_dialog(page, OPERATOR)
    page.wait_for_selector("#t-review-why:has-text('reviewing needs the role approver')", timeout=WAIT_MS)
    assert page.is_disabled("#t-approve")
    page.click("#account-button")  # logs the operator out
    page.wait_for_selector("#account-button:has-text('log in')", timeout=WAIT_MS)
    page.wait_for_selector("#t-review-why:has-text('log in as an approver')", timeout=WAIT_MS)
    page.click("#account-button")
    log_in_dialog(page, APPROVER)
    poll(lambda: page.inner_text("#t-review-why") == "", 10, "the hint gone for an approver",
         shown=lambda: page.inner_text("#t-review-why"))
    assert page.is_enabled("#t-approve") and page.is_enabled("#t-reject")
    shots(page, artifacts, "day_review_hint_approver")


@pytest.mark.parametrize("width,height", [(1366, 768), (1920, 1080)])
def test_the_live_view_during_a_test_in_si_units(server, open_page, artifacts, width, height):
    page, _ = open_page(f"{server.url}/", width=width, height=height)
    page.select_option("#units", "si")
    test_id = _start_slowly(server, sine_test(amplitude_m=0.01, frequency_hz=1.0, cycles=8, speed=1.0, isolator="IUT_a",
                                          supply_bar=100.0))
    try:
        page.wait_for_function(f"window.__isorig.testId === {test_id} && window.__isorig.samples > 1500",
                               timeout=WAIT_MS)
        page.evaluate("window.scrollTo(0, 0)")
        page.wait_for_timeout(500)
        page.screenshot(path=str(artifacts / f"day_live_si_{width}x{height}.png"))
        # the loop is in view without scrolling, whole, during the test
        box = page.locator("#plot-loop").bounding_box()
        assert box is not None and box["height"] > 150, box
        assert box["y"] >= 0 and box["y"] + box["height"] <= height, (box, height)
        # the tracking-error axis in metres: ticks with the digits they need, never "-0", no two alike
        ticks = page.evaluate("window.__isorigPlots().err.yTicks")
        assert len(ticks) >= 2 and len(set(ticks)) == len(ticks), ticks
        assert not any(re.fullmatch(r"-0(\.0*)?", t) for t in ticks), ticks
        assert page.evaluate("window.__isorigPlots().err.y") == "error (m)"
    finally:
        server.call("POST", f"/api/tests/{test_id}/abort", token=True)
        server.wait_status(test_id, {"aborted", "completed"}, timeout_s=60)


@pytest.fixture
def own_server(tmp_path):
    srv = Server(tmp_path / "serve-day").start()
    yield srv
    srv.stop()


def test_an_interrupted_tests_header_agrees_with_its_cycles(own_server, open_page, artifacts):
    srv = own_server
    page, watch = open_page(f"{srv.url}/", width=1366, height=768)
    watch.allowed_patterns.append(r"WebSocket connection to 'ws://127\.0\.0\.1:\d+/ws/live' failed")
    watch.allowed_patterns.append(r"^Failed to load resource: net::ERR_CONNECTION_REFUSED$")
    test_id = _start_slowly(srv, sine_test(amplitude_m=0.01, frequency_hz=2.0, cycles=30, speed=1.0, isolator="IUT_a",
                                       supply_bar=100.0))
    poll(lambda: srv.call("GET", f"/api/tests/{test_id}")[1]["cycles_done"] >= 5, 60, "five cycles done")
    srv.stop()  # Ctrl-C in the middle of the test: the service brings the table back, then exits
    srv.start()
    rec = srv.wait_status(test_id, {"interrupted", "aborted"}, timeout_s=30)
    page.wait_for_selector(f"#rig-status[data-status='{rec['status']}']", timeout=WAIT_MS)
    # the ended test's stored loops are drawn: the note's default text ("current cycle bold, ...") says bold too
    page.wait_for_selector("#plot-loop[data-bold-cycle]", state="attached", timeout=WAIT_MS)
    page.wait_for_selector("#loop-note:has-text('bold: the last steady cycle')", timeout=WAIT_MS)
    done, total = rec["cycles_done"], rec["cycles_total"]
    poll(lambda: page.inner_text("#l-cycle") == f"{done} / {total}", 10, f"the header saying {done} / {total}",
         shown=lambda: page.inner_text("#l-cycle"))
    bold = int(page.get_attribute("#plot-loop", "data-bold-cycle"))
    assert bold <= done, (bold, done)
    steady = rec["summary"]["steady_cycles"]
    assert f"mean of {steady} steady cycle" in page.inner_text("#l-keff-label") and steady <= done
    shots(page, artifacts, "day_interrupted_header")


def test_a_commissioning_asks_for_the_login_first_and_every_console_follows_it(own_server, open_page, artifacts):
    srv = own_server
    other, _ = open_page(f"{srv.url}/", width=1366, height=768)  # another console, on the live view
    first_rig = other.get_attribute("body", "data-rig-file")
    assert first_rig, "the page names the rig file in force"
    page, _ = open_page(f"{srv.url}/?viewer=off#/commission", width=1366, height=768)  # nobody logged in here
    page.fill("#c-speed", "10")
    page.fill("#c-stroke", "2")
    page.wait_for_selector("#c-start:not([disabled])", timeout=120000)
    page.click("#c-start")
    # the login comes first, then the confirmation, which names the account that will run it
    page.wait_for_selector("#login-dialog[open]", timeout=WAIT_MS)
    assert not page.is_visible("#confirm-dialog")
    log_in_dialog(page, OPERATOR)
    page.wait_for_selector("#confirm-dialog[open]", timeout=WAIT_MS)
    operator_row = page.locator("#confirm-body tr", has_text="operator").first.inner_text()
    assert operator_row.split("\t")[-1].strip() == OPERATOR[0], operator_row  # it said "-" when nobody was in
    shots(page, artifacts, "day_commissioning_confirm")
    page.click("#confirm-ok")
    said = poll(lambda: re.match(r"Commissioning #(\d+) started|Not started", page.inner_text("#c-message")), 120,
                "the start's answer", shown=lambda: page.inner_text("#c-message"))
    assert said.group(1), page.inner_text("#c-message")
    cid = int(said.group(1))
    item = page.locator("#c-earlier li", has=page.locator(f"a[href='#/commission/{cid}']"))
    item.wait_for(timeout=WAIT_MS)
    # the run and its fit end; the list follows without leaving the page
    poll(lambda: srv.call("GET", f"/api/commissioning/{cid}")[1]["state"] not in ("ready", "running", "fitting"),
         180, "the commissioning and its fit to end")
    res = srv.call("GET", f"/api/commissioning/{cid}")[1]
    ended = f"{res['status']} \u00b7 {res['state'].replace('_', ' ')}"  # "completed · trusted"
    poll(lambda: item.inner_text().endswith(ended), 15, f"the list saying {ended!r}", shown=item.inner_text)
    shots(page, artifacts, "day_commissioning_ended")
    assert res["state"] == "trusted", res.get("words")
    # applied here: the other console learns of it without a reload
    page.wait_for_selector("#c-apply:not([disabled])", timeout=WAIT_MS)
    page.click("#c-apply")
    page.wait_for_selector("#confirm-dialog[open]", timeout=WAIT_MS)
    page.click("#confirm-ok")
    name = res["rig_file"]["name"]
    poll(lambda: other.get_attribute("body", "data-rig-file") == name, 15, "the other console's rig file",
         shown=lambda: other.get_attribute("body", "data-rig-file"))
    assert name != first_rig
    other.wait_for_selector(f"#s-rigfile:has-text('{name}')", timeout=WAIT_MS)
    shots(other, artifacts, "day_other_console_rig_file")
