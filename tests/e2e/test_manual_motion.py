"""Manual motion in the console (issue 17, item 4): Zero and Move to a position at a safe speed when no test
runs, each after a confirmation, with the set-up's limits; the move followed like a test (strip, form lock,
progress) and its end said; refusals at the field and by the service; a sine's offset taken from where the
table rests. The service: POST /api/rig/zero and /api/rig/move (docs/backend.md).
"""

from __future__ import annotations

import re

from .harness import (
    OPERATOR,
    VIEWPORTS,
    WAIT_MS,
    fill_identity,
    poll,
    record_checks,
    shots,
    sine_test,
    wait_start_enabled,
)


def _ids(server) -> set[int]:
    return {t["id"] for t in server.call("GET", "/api/tests")[1]}


def _new_record(server, known: set[int]) -> dict:
    new = poll(lambda: _ids(server) - known, 15, "the move's record")
    return server.call("GET", f"/api/tests/{max(new)}")[1]


def _table(server) -> float:
    return server.call("GET", "/api/rig/state")[1]["table_position_m"]


def test_zero_and_move_from_the_console(server, open_page, artifacts):
    """A trip leaves the table beyond 20 mm: Start is disabled and the warning offers Zero; Cancel sends nothing;
    Zero brings the table back (the record is a move with the form's isolator, limits and operator); Move to
    "12,5" mm at the default 5 mm/s runs with the form locked and its progress shown, and leaves the table
    there, where no test may start."""
    body = sine_test(amplitude_m=0.03, frequency_hz=0.5, cycles=10, speed=2.0)
    body["limits"] = {"displacement_m": 0.02}  # valve close (the default action) beyond 20 mm
    tripped = server.start_test(body)
    rec = server.wait_status(tripped, {"aborted"}, timeout_s=30)
    assert rec["reason"].startswith("displacement limit tripped"), rec["reason"]
    rest = _table(server)
    assert abs(rest) > 0.015, rest  # the valve closed beyond the limit: the table stays there
    at = f"{rest * 1e3:+.2f} mm"

    page, watch = open_page(server.url + "/", width=1366, height=768, login=OPERATOR)
    fill_identity(page, "MM-1")
    page.wait_for_selector("#rig-warning[data-state='off-zero']", timeout=WAIT_MS)
    warning = page.inner_text("#rig-warning")
    assert f"The table rests at {at} (where test {tripped} left it)" in warning, warning
    assert page.is_disabled("#start") and "the table at zero" in page.inner_text("#start-why")
    assert page.inner_text("#mm-position") == f"{at} \u00b7 where test {tripped} left it"
    # the field's unit and range: the stroke and the displacement limit in force; the speed the service allows
    assert page.inner_text("[data-field='mm_target'] .unit") == "(mm)"
    assert page.inner_text("[data-field='mm_target'] .range").startswith("-150 to 150 mm")
    assert page.inner_text("[data-field='mm_speed'] .range") == "1 mm/s to 50 mm/s"
    assert page.input_value("#f-mm_speed") == "5"  # the service's default speed
    assert page.is_enabled("#warning-zero") and page.is_enabled("#mm-zero")
    assert page.is_disabled("#mm-move") and "Move needs: a position to move to" in page.inner_text("#mm-why")
    page.locator("#manual-motion").scroll_into_view_if_needed()
    shots(page, artifacts, "dashboard_off_zero")

    # the confirmation says what will move; Cancel sends nothing
    page.fill("#f-mm_speed", "50")
    known = _ids(server)
    page.click("#warning-zero")
    page.wait_for_selector("#confirm-dialog[open]", timeout=WAIT_MS)
    assert page.inner_text("#confirm-title").startswith("Return the table to zero?")
    confirm = page.inner_text("#confirm-body")
    for what in (at, "0.00 mm", "50 mm/s", "minimum-jerk", "s moving, then 0.5 s holding", "IUT_b",
                 OPERATOR[0]):
        assert what in confirm, (what, confirm)
    assert re.search(r"displacement \|d\|\s+150 mm\s+valve close", confirm), confirm  # the limits that apply
    assert "the move ends aborted" in confirm and "the test ends" not in confirm, confirm
    page.screenshot(path=str(artifacts / "dashboard_zero_confirm_1366x768.png"))
    page.click("#confirm-cancel")
    assert page.inner_text("#mm-status") == "Zero cancelled: nothing was sent to the rig."
    assert not [u for u in watch.requests if "/api/rig/" in u and ("/zero" in u or "/move" in u)], watch.requests
    assert _ids(server) == known

    # Zero (the manual-motion block's own button): a move record with the form's conditions and limits
    page.fill("#f-lim_tracking", "30")
    page.click("#mm-zero")
    page.wait_for_selector("#confirm-dialog[open]", timeout=WAIT_MS)
    page.click("#confirm-ok")
    move = _new_record(server, known)
    assert move["profile"]["kind"] == "move" and move["profile"]["end_m"] == 0.0, move["profile"]
    assert abs(move["profile"]["start_m"] - rest) < 1e-6 and move["profile"]["speed_m_per_s"] == 0.05, move
    assert move["isolator"] == "IUT_b" and move["operator_name"] == OPERATOR[0], move
    assert move["limits"]["tracking_error_m"] == 0.03 and move["limits"]["actions"]["force_n"] == "valve_close"
    server.wait_status(move["id"], {"completed"}, timeout_s=30)
    page.wait_for_selector("#mm-status[data-kind='ok']:has-text('completed')", timeout=WAIT_MS)
    assert page.inner_text("#mm-status").startswith(f"Move #{move['id']} completed ({at} to 0.00 mm at 50 mm/s)")
    assert abs(_table(server)) < 0.0005
    page.wait_for_selector("#rig-warning[data-state='ok']", state="attached", timeout=WAIT_MS)
    assert page.is_hidden("#rig-warning")
    wait_start_enabled(page)  # the table at zero: a test may start
    assert page.inner_text("#alert-text") == f"Manual move {move['id']} completed"
    poll(lambda: page.inner_text("#l-cycle") == "none (a manual move)", 10, "the header's cycle",
         shown=lambda: page.inner_text("#l-cycle"))
    # the move's events say it was a move, not a test
    poll(lambda: page.inner_text("#s-event").endswith("Manual move completed"), 10, "the strip's last event")
    page.goto(f"{server.url}/?viewer=off#/tests/{move['id']}")
    page.wait_for_selector("#t-events li", timeout=WAIT_MS)
    events = page.inner_text("#t-events")
    assert "Move started: the valve opens" in events and "Manual move completed" in events, events
    assert "Test started" not in events and "Test completed" not in events, events
    page.goto(f"{server.url}/?viewer=off#/live")
    fill_identity(page, "MM-1")

    # Move to "12,5" mm at 1 mm/s: the decimal comma is read as one; the form is locked meanwhile (24 s: the move
    # still runs while a loaded machine's page shows its progress; at 5 mm/s it had ended before)
    page.fill("#f-mm_speed", "1")
    page.fill("#f-mm_target", "12,5")
    assert page.inner_text("[data-field='mm_target'] .msg") == "read as 12.5 mm"
    known = _ids(server)
    rest_m = _table(server)  # the zero's end: within the still valve's band (30 um) of 0, not exactly there
    page.click("#mm-move")
    page.wait_for_selector("#confirm-dialog[open]", timeout=WAIT_MS)
    assert page.inner_text("#confirm-title").startswith("Move the table to +12.50 mm?")
    confirm = page.inner_text("#confirm-body")
    assert "12.50 mm" in confirm and "1 mm/s" in confirm, confirm
    shown_s = float(re.search(r"duration\s+([\d.]+) s", confirm).group(1))
    assert abs(shown_s - (1.875 * abs(0.0125 - rest_m) / 1e-3 + 0.5)) < 0.11, confirm  # 1.875 d / v + 0.5 s
    page.click("#confirm-ok")
    move = _new_record(server, known)
    assert move["profile"]["end_m"] == 0.0125 and move["profile"]["speed_m_per_s"] == 0.001, move["profile"]
    page.wait_for_selector("#s-rig-cell[data-state='running']", timeout=WAIT_MS)
    # the strip names the move once the page has its record (RUNNING comes first, with the service's state)
    poll(lambda: page.inner_text("#s-rig-why") == f"manual move #{move['id']}", 10, "the strip naming the move",
         shown=lambda: page.inner_text("#s-rig-why"))
    page.wait_for_selector("#mm-status[data-kind='running']", timeout=WAIT_MS)
    poll(lambda: re.search(r"now \+\d+\.\d\d mm \(\d+ % of the way\)", page.inner_text("#mm-status")), 5,
          "the move's progress")
    assert re.match(rf"Moving \(manual move #{move['id']}\) [+-]?\d+\.\d\d mm to \+12\.50 mm at 1 mm/s",
                    page.inner_text("#mm-status")), page.inner_text("#mm-status")
    assert page.is_disabled("#mm-zero") and page.is_disabled("#mm-move") and page.is_disabled("#start")
    assert f"manual move #{move['id']} is running" in page.inner_text("#start-why")
    assert f"Manual move #{move['id']} is running" in page.inner_text("#form-lock")
    assert page.is_enabled("#stop")  # a stop holds the table where it is
    assert re.fullmatch(r"manual move [+-]?\d+\.\d\d mm to \+12\.50 mm at 1\.0 mm/s", page.inner_text("#l-profile"))
    shots(page, artifacts, "dashboard_manual_move")
    server.wait_status(move["id"], {"completed"}, timeout_s=60)
    page.wait_for_selector("#mm-status[data-kind='ok']:has-text('completed')", timeout=WAIT_MS)
    assert abs(_table(server) - 0.0125) < 0.0003
    page.wait_for_selector("#rig-warning[data-state='off-zero']", timeout=WAIT_MS)  # no test starts there
    assert page.is_hidden("#form-lock") and page.input_value("#f-specimen_id") == "MM-1"  # the draft is back
    # a move's end: "end of move N" (the service said "end of test N" before issue 23), at both viewports
    for width, height in reversed(VIEWPORTS):
        page.set_viewport_size({"width": width, "height": height})
        poll(lambda: re.fullmatch(rf"\+12\.\d\d mm \u00b7 end of move {move['id']} \(completed\)",
                                   page.inner_text("#s-position")), 5, f"the strip's table position at {width}")
        assert page.locator("#s-position").is_visible()
        page.screenshot(path=str(artifacts / f"i23_end_of_move_{width}x{height}.png"))


def test_manual_motion_limits_refusals_units_and_offset(server, open_page, artifacts):
    """Move follows the displacement limit of the form; the service's own refusal is shown; a running test
    disables Zero and Move; the fields follow the unit choice; the sine's offset is taken from the table."""
    page, watch = open_page(server.url + "/", width=1920, height=1080, login=OPERATOR)
    watch.allowed_status.add(422)  # the refusal below
    fill_identity(page, "MM-2")
    # the same limits as a test: the reach of a move follows the displacement limit of the form
    page.fill("#f-mm_target", "120")
    page.wait_for_selector("#mm-move:not([disabled])", timeout=WAIT_MS)
    page.fill("#f-lim_displacement", "100")
    page.fill("#f-mm_target", "120")
    assert page.inner_text("[data-field='mm_target'] .range").startswith("-100 to 100 mm")
    assert "outside the allowed range" in page.inner_text("[data-field='mm_target'] .msg")
    assert page.is_disabled("#mm-move") and "a valid position" in page.inner_text("#mm-why")
    page.fill("#f-mm_speed", "80")
    assert "1 mm/s to 50 mm/s" in page.inner_text("[data-field='mm_speed'] .msg")
    assert page.is_disabled("#mm-zero") and "a valid speed" in page.inner_text("#mm-why")
    page.fill("#f-lim_displacement", "")
    page.fill("#f-mm_speed", "20")

    # the service checks again: a request it refuses (here altered on its way) is shown with its reason
    def too_fast(route):
        route.continue_(post_data=route.request.post_data.replace('"speed_m_per_s":0.02', '"speed_m_per_s":0.2'))

    page.route("**/api/rig/move", too_fast)
    known = _ids(server)
    page.fill("#f-mm_target", "10")
    page.press("#f-mm_target", "Enter")  # Enter in the field asks for this move (not for a test)
    page.wait_for_selector("#confirm-dialog[open]", timeout=WAIT_MS)
    assert page.inner_text("#confirm-title").startswith("Move the table to +10.00 mm?")
    page.click("#confirm-ok")
    page.wait_for_selector("#mm-status[data-kind='error']", timeout=WAIT_MS)
    status = page.inner_text("#mm-status")
    assert status.startswith("Not moved, refused by the service: speed_m_per_s = 0.2"), status
    assert "[0.001, 0.05] m/s" in status, status  # the range the service allows, said with the refusal
    assert _ids(server) == known  # nothing moved, nothing kept
    page.unroute("**/api/rig/move")

    # the fields follow the unit choice (values kept in SI)
    page.select_option("#units", "si")
    assert page.input_value("#f-mm_target") == "0.01" and page.input_value("#f-mm_speed") == "0.02"
    assert page.inner_text("[data-field='mm_target'] .unit") == "(m)"
    assert page.inner_text("[data-field='mm_speed'] .range") == "0.001 m/s to 0.05 m/s"
    page.select_option("#units", "lab")
    assert page.input_value("#f-mm_target") == "10"

    # a test runs: no manual motion
    running = server.start_test(sine_test(cycles=20, speed=1.0))
    page.wait_for_selector("#s-rig-cell[data-state='running']", timeout=WAIT_MS)
    poll(lambda: f"no test running (test #{running} runs)" in page.inner_text("#mm-why"), 5, "why not now")
    assert page.is_disabled("#mm-zero") and page.is_disabled("#mm-move")
    server.call("POST", f"/api/tests/{running}/stop", token=True)
    server.wait_status(running, {"stopped"}, timeout_s=60)
    server.zero_table()

    # the table moved to +12.50 mm elsewhere (a script): the offset of the next sine taken from there
    code, move = server.call("POST", "/api/rig/move", {"position_m": 0.0125, "speed_m_per_s": 0.05,
                                                       "isolator": "IUT_b", "supply_bar": 70}, token=True)
    assert code == 201, move
    server.wait_status(move["id"], {"completed"}, timeout_s=30)
    at = _table(server)
    page.wait_for_selector(f"#s-position[data-source^='end of test {move['id']}'], "
                           f"#s-position[data-source^='end of move {move['id']}']", timeout=WAIT_MS)
    record_checks(page)
    assert page.input_value("#f-offset") == ""
    page.click("#offset-from-table")
    offset = round(at * 1e5) / 1e5
    assert abs(float(page.input_value("#f-offset")) - offset * 1e3) < 1e-9, page.input_value("#f-offset")
    assert re.match(rf"set from the table position {re.escape(f'{at * 1e3:+.2f}')} mm \(where (test|move) "
                    rf"{move['id']} left it\): the test starts there", page.inner_text("#offset-note")), \
        page.inner_text("#offset-note")

    def taken(c):
        p = c["profile"]
        return abs(p.get("offset_m", 0) - offset) < 1e-12 and abs(p.get("start_m", 0) - offset) < 1e-12

    poll(lambda: any(taken(c) for c in page.evaluate("window.__checks")), 10,
          "the envelope check with the offset and the start where the table rests")
    page.wait_for_selector("#envelope[data-state='ok']", timeout=WAIT_MS)
    # the test starts where the table rests (start_m): the table is where it must be, so Start is not held
    # back by it
    poll(lambda: "the table at" not in page.inner_text("#start-why"), 10, "Start no longer waiting for the table")
    assert page.get_attribute("#rig-warning", "data-state") == "ok" and not page.is_visible("#rig-warning")
    page.locator("#offset-row").scroll_into_view_if_needed()
    page.screenshot(path=str(artifacts / "dashboard_offset_from_table_1920x1080.png"))
    # a typed offset is reached from zero: Start needs the table at zero again
    page.fill("#f-offset", "10")
    assert page.inner_text("#offset-note") == ""
    poll(lambda: "the table at zero" in page.inner_text("#start-why"), 10, "Start waiting for the table at zero")
    assert page.get_attribute("#rig-warning", "data-state") == "off-zero"
    page.fill("#f-offset", "")

    # the offset taken from the table, then the table zeroed elsewhere: the warning names the test's start and
    # offers the way out (start from zero) instead of Zero, which would not help
    page.click("#offset-from-table")
    page.wait_for_selector("#envelope[data-state='ok']", timeout=WAIT_MS)
    server.zero_table()
    page.wait_for_selector("#rig-warning[data-state='off-zero']", timeout=WAIT_MS)
    warning = page.inner_text("#rig-warning")
    assert f"Table not where this test starts ({offset * 1e3:+.2f} mm)" in warning, warning
    assert page.is_visible("#warning-from-zero") and page.locator("#warning-zero").count() == 0
    page.click("#warning-from-zero")
    page.wait_for_selector("#rig-warning[data-state='ok']", state="attached", timeout=WAIT_MS)
    assert page.inner_text("#offset-note") == ""
    assert abs(float(page.input_value("#f-offset")) - offset * 1e3) < 1e-9  # the offset stays, reached from zero
    poll(lambda: "the table at" not in page.inner_text("#start-why"), 10, "Start no longer waiting for the table")
