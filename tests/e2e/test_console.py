"""The operator console a lab would trust (issue 17): inputs that cannot be misread, the state always visible and
followed after a reload or from a second browser, Start only when it can succeed, records kept (delete what
never ran, archive and restore with who and why), readable live views in one unit choice. At 1366x768 and
1920x1080, with screenshots in artifacts/e2e/.
"""

from __future__ import annotations

import json
import re
import time

from .harness import (
    FIRST_CHECK_MS,
    OPERATOR,
    WAIT_MS,
    fill_identity,
    poll,
    record_checks,
    settle,
    shots,
    sine_test,
    start_from_form,
    wait_start_enabled,
)


def _checks(page) -> list[dict]:
    """Bodies of the envelope checks the page sent (what the console would ask the service to run)."""
    return page.evaluate("window.__checks || []")


def test_numbers_cannot_be_misread(server, open_page, artifacts):
    """A decimal comma is read as one and said so ("3,5" is 3.5 mm, never 35); an ambiguous "1,000" and text are
    refused with a message; every field shows its unit and range; the unit choice converts the values."""
    page, _ = open_page(server.url + "/", width=1366, height=768, login=OPERATOR)
    record_checks(page)
    fill_identity(page)
    # the amplitude's range names the stroke and this frequency's limit once the first check has answered
    page.wait_for_selector("#envelope[data-state='ok']", timeout=FIRST_CHECK_MS)
    # every numeric field is a text field with a decimal keypad, its unit and its allowed range
    for field in ("supply", "amplitude", "frequency", "vertical_load", "lim_displacement", "lim_force", "lim_velocity",
                  "lim_tracking"):
        assert page.get_attribute(f"#f-{field}", "type") == "text"
        assert page.get_attribute(f"#f-{field}", "inputmode") == "decimal"
    ranges = {k: page.inner_text(f"[data-field='{k}'] .range") for k in
              ("supply", "amplitude", "frequency", "cycles", "vertical_load", "lim_displacement", "lim_force",
               "lim_velocity")}
    assert ranges["supply"] == "10 to 210 bar", ranges
    assert ranges["amplitude"].startswith("up to 150 mm (stroke)"), ranges
    assert ranges["frequency"].startswith("above 0, up to 10 Hz"), ranges
    assert ranges["cycles"] == "1 to 100000", ranges
    assert ranges["vertical_load"].startswith("0 to 850 kN"), ranges
    assert ranges["lim_displacement"] == "above 0, up to 150 mm; empty: 150 mm", ranges
    assert ranges["lim_force"] == "above 0, up to 280.14 kN; empty: 280.14 kN", ranges
    assert ranges["lim_velocity"] == "above 0, up to 391.054 mm/s; empty: 391.054 mm/s", ranges  # Q_pump / A_p
    assert page.inner_text("[data-field='amplitude'] .unit") == "(mm)"

    page.fill("#f-amplitude", "3,5")
    page.fill("#f-frequency", "1")
    page.fill("#f-cycles", "4")
    assert page.inner_text("[data-field='amplitude'] .msg") == "read as 3.5 mm"
    wait_start_enabled(page)
    assert _checks(page)[-1]["profile"]["amplitude_m"] == 0.0035  # never 35 mm
    page.click("#start")
    page.wait_for_selector("#confirm-dialog[open]", timeout=WAIT_MS)
    assert "\u00b13.50 mm" in page.inner_text("#confirm-body")
    page.screenshot(path=str(artifacts / "dashboard_confirm_1366x768.png"))
    page.click("#confirm-cancel")
    # about an offset, the confirmation gives the range the table covers, not a +- peak
    page.fill("#f-offset", "10")
    wait_start_enabled(page)
    page.click("#start")
    page.wait_for_selector("#confirm-dialog[open]", timeout=WAIT_MS)
    confirm = page.inner_text("#confirm-body")
    assert "+6.50 mm to +13.50 mm" in confirm and "\u00b113.50 mm" not in confirm, confirm
    page.click("#confirm-cancel")
    page.fill("#f-offset", "")

    page.fill("#f-amplitude", "1,000")  # a thousand or one? refused, never guessed
    msg = page.inner_text("[data-field='amplitude'] .msg")
    assert "1000" in msg and "1.0" in msg, msg
    assert "invalid" in (page.get_attribute("#f-amplitude", "class") or "")
    page.wait_for_function("document.getElementById('start').disabled")
    assert "valid values (amplitude)" in page.inner_text("#start-why")
    page.screenshot(path=str(artifacts / "dashboard_inputs_1366x768.png"))
    page.fill("#f-amplitude", "3 mm")
    assert "no spaces" in page.inner_text("[data-field='amplitude'] .msg")
    page.fill("#f-amplitude", "abc")
    assert "not a number" in page.inner_text("[data-field='amplitude'] .msg")
    page.fill("#f-cycles", "3,5")
    assert "whole number" in page.inner_text("[data-field='cycles'] .msg")
    # only Cycles is wrong: the taper cycles are not judged against a number that is not there
    assert "invalid" not in (page.get_attribute("#f-taper_cycles", "class") or "")
    assert page.inner_text("[data-field='taper_cycles'] .msg") == ""
    page.fill("#f-cycles", "4")
    page.fill("#f-amplitude", "12.5")
    wait_start_enabled(page)

    # implausible values ask for a tick in the confirmation (a vertical load in N typed where kN is asked)
    page.fill("#f-vertical_load", "0,125")
    assert "wrong unit" in page.inner_text("[data-field='vertical_load'] .msg")
    wait_start_enabled(page)
    page.click("#start")
    page.wait_for_selector("#confirm-dialog[open]", timeout=WAIT_MS)
    assert page.locator("#confirm-body .warning-tick").count() == 1
    assert page.is_disabled("#confirm-ok")
    page.check("#confirm-body .warning-tick")
    assert page.is_enabled("#confirm-ok")
    page.click("#confirm-cancel")
    page.fill("#f-vertical_load", "")

    # one unit choice for every page: SI shows the same values in m, N, MPa (kept per browser)
    page.select_option("#units", "si")
    assert page.input_value("#f-amplitude") == "0.0125"
    assert page.input_value("#f-supply") == "7"
    assert page.inner_text("[data-field='amplitude'] .unit") == "(m)"
    assert page.inner_text("[data-field='supply'] .range") == "1 to 21 MPa"
    poll(lambda: "(m)" in json.dumps(page.evaluate("window.__isorigPlots()")["disp"]), 5, "the plot axes in m")
    assert "N" in page.inner_text("#s-limits")
    page.fill("#f-amplitude", "0,02")
    assert page.inner_text("[data-field='amplitude'] .msg") == "read as 0.02 m"
    page.reload()
    page.wait_for_selector("body[data-ready='1']", timeout=WAIT_MS)
    assert page.input_value("#units") == "si"
    assert page.input_value("#f-amplitude") == "0.02"  # the draft survives a reload, in SI
    page.select_option("#units", "lab")
    assert page.input_value("#f-amplitude") == "20"
    assert page.inner_text("[data-field='amplitude'] .unit") == "(mm)"


def test_state_follows_the_running_test(server, open_page, browser, artifacts):
    """Start enabled only when a start can succeed; the confirmation; the strip, the readouts and the form follow
    the running test, also after a reload and in a second browser; Stop shows STOPPING; a refusal clears when
    its cause is gone; labelled plots; events in words; the banner never covers the header."""
    page, watch = open_page(server.url + "/", width=1920, height=1080, login=OPERATOR)
    page.wait_for_selector("#conn.conn-up", timeout=WAIT_MS)
    assert page.is_disabled("#start")
    assert "a specimen id" in page.inner_text("#start-why")
    assert "operator" not in page.inner_text("#start-why")  # who acts is the logged-in account, never typed
    fill_identity(page, "B-2024-017")
    page.fill("#f-notes", "first run after the seal change")
    page.select_option("#f-isolator", "IUT_b")
    page.fill("#f-amplitude", "30")
    page.fill("#f-frequency", "0.5")
    page.fill("#f-cycles", "30")  # 60 s: the steps below finish before it ends on a loaded machine
    page.fill("#f-speed", "1")
    page.fill("#f-lim_tracking", "20")
    summary = start_from_form(page)
    for what in ("\u00b130.00 mm", "94.2 mm/s", "about", "the service's upper estimate", "1:00", "30 cycles"):
        assert what in summary, summary
    assert re.search(r"tracking error \|y-r\|\s+20 mm\s+valve close", summary), summary  # each limit, its action
    page.wait_for_selector("#rig-status[data-status='running']", timeout=WAIT_MS)
    test_id = page.evaluate("window.__isorig.testId")
    rec = server.call("GET", f"/api/tests/{test_id}")[1]
    assert rec["specimen_id"] == "B-2024-017" and rec["operator_name"] == OPERATOR[0], rec
    assert rec["notes"] == "first run after the seal change" and rec["limits"]["tracking_error_m"] == 0.02, rec

    # the strip, the header, the readouts, the margins, the form (locked) and the buttons
    page.wait_for_selector("#s-rig-cell[data-state='running']", timeout=WAIT_MS)
    # RUNNING comes with the service's state; the header and the strip's set values once the page has the test's
    # record (they are drawn together)
    page.wait_for_function("document.getElementById('l-specimen').textContent === 'B-2024-017'", timeout=WAIT_MS)
    # the setting, with the measured supply pressure once GET /api/rig/state has answered
    supply = page.inner_text("#s-supply")
    assert re.fullmatch(r"70\.0 bar set|\d+\.\d bar \(set 70\.0\)", supply), supply
    assert page.inner_text("#s-vertical") == "125 kN"
    assert "|y-r| 20 mm" in page.inner_text("#s-limits")
    poll(lambda: re.fullmatch(r"[+-]?\d+\.\d\d mm \u00b7 live", page.inner_text("#s-position")), 5,
          "the table position, live")
    poll(lambda: "started" in page.inner_text("#s-event").lower(), 10, "the strip's start event",
         shown=lambda: page.inner_text("#s-event"))
    assert page.inner_text("#l-specimen") == "B-2024-017" and page.inner_text("#l-operator") == OPERATOR[0]
    assert page.inner_text("#l-profile") == "sine 30.00 mm at 0.5 Hz x 30"
    # the readouts with the running test's samples and the current cycle's peak and valley
    page.wait_for_function("['y', 'f', 'v'].every((ch) => /^[+-]?\\d+\\.\\d+ (mm|kN|V)$/.test("
                           "document.getElementById(`r-${ch}`).textContent) && ['max', 'min'].every((k) => "
                           "document.getElementById(`r-${ch}-${k}`).textContent !== '-'))", timeout=WAIT_MS)
    poll(lambda: re.search(r"\|d\|\s+1[12]\d\.\d\d mm left", page.inner_text("#margins")), 10,
         "the displacement margin of a full-amplitude cycle")
    for ch in ("y", "f", "v"):
        assert re.fullmatch(r"[+-]?\d+\.\d+ (mm|kN|V)", page.inner_text(f"#r-{ch}")), page.inner_text(f"#r-{ch}")
        assert page.inner_text(f"#r-{ch}-max") != "-" and page.inner_text(f"#r-{ch}-min") != "-"
    # the margin is over this and the last cycle: it does not jump back to ~150 mm left as a cycle begins
    for _ in range(12):  # 2.4 s, longer than a cycle at 0.5 Hz (one turn at least)
        margins = page.inner_text("#margins")
        assert re.search(r"\|d\|\s+1[12]\d\.\d\d mm left\s+valve close", margins), margins
        time.sleep(0.2)
    assert re.search(r"\|v\|\s+\d+\.\d mm/s left", margins), margins  # |dy/dt| of the streamed displacement
    assert page.get_attribute(".margin[data-limit='tracking_error_m']", "data-max") == "20"  # the test's own limit
    assert page.get_attribute(".margin[data-limit='displacement_m']", "data-max") == "150"
    # the velocity of the current cycle: 2 pi f A = 94.2 mm/s at full amplitude (3rd of 30 cycles and on)
    poll(lambda: 80 < float(page.get_attribute(".margin[data-limit='velocity_m_per_s']", "data-peak")) < 110, 10,
          "the cycle's peak velocity near 94 mm/s")
    assert page.is_disabled("#start") and f"test #{test_id} is running" in page.inner_text("#start-why")
    assert page.is_enabled("#stop")
    assert page.is_disabled("#f-amplitude") and f"test #{test_id}" in page.inner_text("#form-lock")

    # readable plots: labelled axes with units, the target drawn last (on top), thin and dashed
    plots = page.evaluate("window.__isorigPlots()")
    assert plots["disp"]["x"] == "test time (s)" and plots["disp"]["y"] == "displacement (mm)", plots
    assert plots["volt"]["y"] == "command u (V)" and plots["err"]["y"] == "error (mm)", plots
    target = plots["disp"]["series"][-1]
    assert target["label"].startswith("target r") and target["dash"], plots["disp"]
    assert target["width"] < plots["disp"]["series"][0]["width"], plots["disp"]
    assert [p["y"] for p in plots["adapt"]] == ["(-)", "(V)", "(Hz)"], plots["adapt"]  # one axis each (servo)
    assert plots["adapt"][-1]["x"] == "test time (s)"
    assert plots["loop"] == {"x": "displacement y (mm)", "y": "force F (kN)"}
    shots(page, artifacts, "dashboard_live")

    # a reload and a second browser come back to the true state of the running test
    page.reload()
    page.wait_for_selector("body[data-ready='1']", timeout=WAIT_MS)
    page.wait_for_selector("#s-rig-cell[data-state='running']", timeout=WAIT_MS)
    page.wait_for_function("document.getElementById('f-specimen_id').value === 'B-2024-017'", timeout=WAIT_MS)
    assert page.input_value("#f-amplitude") == "30" and page.input_value("#f-lim_tracking") == "20"
    assert page.is_disabled("#start") and page.is_enabled("#stop")
    other, _ = open_page(server.url + "/", width=1366, height=768)
    other.wait_for_selector("#s-rig-cell[data-state='running']", timeout=WAIT_MS)
    other.wait_for_function("document.getElementById('f-specimen_id').value === 'B-2024-017'", timeout=WAIT_MS)
    assert other.is_disabled("#start")

    # Stop: STOPPING here at once and in the other browser, which learns of it from the live stream's event. The
    # other browser's strip is watched as it changes: the ramp-out may be over before a loaded machine looks at it.
    other.evaluate("""() => {
      const cell = document.getElementById('s-rig-cell'), why = document.getElementById('s-rig-why');
      window.__stripSeen = [];
      const start = document.getElementById('start');
      const note = () => window.__stripSeen.push([cell.dataset.state, why.textContent, start.disabled]);
      new MutationObserver(note).observe(cell, {attributes: true, childList: true, subtree: true, characterData: true});
    }""")
    page.click("#stop")
    page.wait_for_selector("#s-rig-cell[data-state='stopping']", timeout=WAIT_MS)
    assert page.is_disabled("#stop")
    other.wait_for_selector(f"#live-events li.operator[data-source='stream']:has-text('Stop requested by "
                            f"{OPERATOR[0]}')", timeout=WAIT_MS)  # learnt live from the stream, not from the record
    other.wait_for_function("window.__stripSeen.some(([s]) => s === 'stopping')", timeout=WAIT_MS)
    seen = other.evaluate("window.__stripSeen")
    assert {(why, disabled) for state, why, disabled in seen if state == "stopping"} == {
        (f"stop requested by {OPERATOR[0]}", True)}, seen  # the reason, and no Start while the table ramps out
    other.screenshot(path=str(artifacts / "dashboard_stopping_1366x768.png"))
    server.wait_status(test_id, {"stopped"}, timeout_s=30)
    page.wait_for_selector("#rig-status[data-status='stopped']", timeout=WAIT_MS)
    page.wait_for_selector("#s-rig-cell[data-state='idle']", timeout=WAIT_MS)
    poll(lambda: re.search(r"\u00b7 end of test \d+", page.inner_text("#s-position")), 5, "where the table stopped")
    poll(lambda: "stopped" in page.inner_text("#s-event").lower(), 10, "the end in the strip's last event",
         shown=lambda: [page.inner_text("#s-event"), page.inner_text("#live-events")])
    assert page.is_enabled("#f-amplitude") and page.is_hidden("#form-lock")
    wait_start_enabled(page)

    # events in words, in order, without internals
    events = [li.inner_text() for li in page.query_selector_all("#live-events li")]
    text = "\n".join(events)
    assert "pid" not in text and "worker" not in text and "{" not in text, text
    order = [k for k, e in enumerate(events) for w in ("created", "started", "Stop requested", "stopped") if w in e]
    assert order == sorted(order) and len(order) >= 4, events

    # the banner sits under the header and the strip, never over them (1366x768)
    page.set_viewport_size({"width": 1366, "height": 768})
    page.evaluate("document.getElementById('alert').classList.remove('hidden')")
    bar = page.locator("#topbar").bounding_box()
    strip = page.locator("#strip").bounding_box()
    alert = page.locator("#alert").bounding_box()
    assert strip["y"] >= bar["y"] + bar["height"] - 1, (bar, strip)
    assert alert["y"] >= strip["y"] + strip["height"] - 1, (strip, alert)
    page.mouse.wheel(0, 600)  # scrolled, the header block stays on top and whole
    page.wait_for_function("window.scrollY > 0", timeout=WAIT_MS)
    settle(page)
    assert page.locator("#topbar").bounding_box()["y"] == 0
    assert page.locator("#alert").bounding_box()["y"] >= page.locator("#strip").bounding_box()["y"] + 10

    # a refusal whose cause goes away is cleared: a test started elsewhere while the dialog was open
    page.mouse.wheel(0, -600)
    page.click("#start")
    page.wait_for_selector("#confirm-dialog[open]", timeout=WAIT_MS)
    other_id = server.start_test(sine_test(cycles=60, speed=2.0))  # 60 s: still running when the page asks
    page.wait_for_selector("#rig-status[data-status='running']", timeout=WAIT_MS)
    page.click("#confirm-ok")
    page.wait_for_function("document.getElementById('setup-message').dataset.cause === 'busy'", timeout=WAIT_MS)
    assert f"test #{other_id} is running" in page.inner_text("#setup-message")
    assert server.call("POST", f"/api/tests/{other_id}/abort", token=True)[0] == 200  # the cause goes away
    page.wait_for_function("document.getElementById('setup-message').textContent === ''", timeout=WAIT_MS)
    assert not watch.unexpected_errors()


def test_records_delete_archive_restore(server, open_page, artifacts):
    """History lists who and what; a test that never ran is deleted, one that ran archived with who and why and
    restored, each after a confirmation, with the result said."""
    page, _ = open_page(server.url + "/#/history", width=1366, height=768, login=OPERATOR)
    body = {**sine_test(cycles=2, speed=10.0), "specimen_id": "REC-1", "operator_name": "Rec Operator",
            "vertical_load_n": 2e5}
    status, ready = server.call("POST", "/api/tests", body, token=True)  # created, never started
    assert status == 201, ready
    ran = server.start_test({**body, "specimen_id": "REC-2"})
    server.wait_status(ran, {"completed"}, timeout_s=30)
    page.click("#history-filter button[type='submit']")
    # the list may already show the run as it started (the history follows the live stream): wait for its end
    row = page.wait_for_selector(f"#history-table tr[data-id='{ran}'][data-status='completed']", timeout=WAIT_MS)
    for what in ("REC-2", "Rec Operator", "200 kN", "completed"):
        assert what in row.inner_text(), row.inner_text()
    assert page.locator(f"#history-table tr[data-id='{ready['id']}'] button[data-action='delete']").count() == 1
    assert page.locator(f"#history-table tr[data-id='{ran}'] button[data-action='delete']").count() == 0
    shots(page, artifacts, "dashboard_history")

    # delete what never ran
    page.click(f"#history-table tr[data-id='{ready['id']}'] button[data-action='delete']")
    page.wait_for_selector("#confirm-dialog[open]", timeout=WAIT_MS)
    assert "never ran" in page.inner_text("#confirm-title")
    page.click("#confirm-ok")
    page.wait_for_selector(f"#history-table tr[data-id='{ready['id']}']", state="detached", timeout=WAIT_MS)
    assert f"Test #{ready['id']} deleted." in page.inner_text("#history-message")
    assert server.call("GET", f"/api/tests/{ready['id']}")[0] == 404

    # archive what ran: who and why are required
    page.click(f"#history-table tr[data-id='{ran}'] button[data-action='archive']")
    page.wait_for_selector("#confirm-dialog[open]", timeout=WAIT_MS)
    assert page.is_disabled("#confirm-ok")  # no reason yet
    page.fill("#confirm-reason", "duplicate of an earlier run")
    page.screenshot(path=str(artifacts / "dashboard_archive_1366x768.png"))
    page.click("#confirm-ok")
    page.wait_for_selector(f"#history-table tr[data-id='{ran}']", state="detached", timeout=WAIT_MS)
    assert f"archived by {OPERATOR[0]}: duplicate of an earlier run" in page.inner_text("#history-message")
    rec = server.call("GET", f"/api/tests/{ran}")[1]
    assert rec["archived"]["by"] == OPERATOR[0] and rec["status"] == "completed", rec

    # the archived ones on their own, restorable
    page.check("#h-archived")
    row = page.wait_for_selector(f"#history-table tr[data-id='{ran}']", timeout=WAIT_MS)
    assert f"archived by {OPERATOR[0]}" in row.inner_text()
    page.click(f"#history-table tr[data-id='{ran}'] button[data-action='restore']")
    page.wait_for_selector("#confirm-dialog[open]", timeout=WAIT_MS)
    assert page.locator("#confirm-by").count() == 0  # who restores is the logged-in account
    page.fill("#confirm-reason", "archived by mistake")
    page.click("#confirm-ok")
    page.wait_for_selector(f"#history-table tr[data-id='{ran}']", state="detached", timeout=WAIT_MS)
    assert "restored" in page.inner_text("#history-message")
    page.uncheck("#h-archived")
    page.wait_for_selector(f"#history-table tr[data-id='{ran}']", timeout=WAIT_MS)

    # the test page: who and what, the action, digits that fit the measurement
    page.click(f"#history-table tr[data-id='{ran}']")
    page.wait_for_selector("#t-cycles tbody tr", timeout=WAIT_MS)
    summary = page.inner_text("#t-summary")
    assert "REC-2" in summary and "Rec Operator" in summary and "200 kN" in summary, summary
    assert page.get_attribute("#t-action", "data-action") == "archive"
    assert not re.search(r"\d\.\d{5,}", summary), summary  # no absurd precision
    assert "SI units" in page.inner_text("#t-csv")
    shots(page, artifacts, "dashboard_test_page", full_page=True)
