"""The operator's dashboard in Debian's chromium against the real `isorig serve` (simulated rig, accelerated).

The `open_page` fixture fails a test on any console error or any request to another host.
"""

from __future__ import annotations

import csv
import io

import pytest

from .harness import OPERATOR, WAIT_MS, fill_identity, poll, sine_test, start_from_form, wait_start_enabled

LOOPS_KEPT = 40  # finished cycles the live loop plot keeps (frontend/static/js/plots.js, LoopPlot.maxPast)


def _metrics(page) -> dict:
    return page.evaluate("() => ({...window.__isorig})")


def test_operator_flow(server, open_page, artifacts):
    """Choose IUT_b, 30 mm at 0.5 Hz, start after the confirmation (the console asks for a login), see the loop
    grow, finish, find it in history with who (the logged-in account) and what, CSV."""
    page, _ = open_page(server.url + "/")
    page.select_option("#f-isolator", "IUT_b")
    assert "0.68" in page.inner_text("#isolator-params")  # k_d of IUT_b (paper Table II), in kN/mm
    fill_identity(page, "E2E-FLOW")
    page.fill("#f-notes", "operator flow")
    page.fill("#f-supply", "70")
    page.fill("#f-amplitude", "30")
    page.fill("#f-frequency", "0.5")
    page.fill("#f-cycles", "4")
    page.fill("#f-taper_cycles", "1")
    page.fill("#f-speed", "2")
    wait_start_enabled(page)
    assert page.get_attribute("#envelope", "data-state") == "ok", page.inner_text("#envelope")
    _, before = server.call("GET", "/api/tests")

    # the confirmation summarises the motion before the valve opens; cancel sends nothing
    page.click("#start")
    page.wait_for_selector("#confirm-dialog[open]", timeout=WAIT_MS)
    summary = page.inner_text("#confirm-body")
    assert "±30.00 mm" in summary, summary  # peak displacement
    assert "94.2 mm/s" in summary, summary  # 2 pi f A = 2 pi 0.5 Hz 30 mm
    assert "peak force" in summary and "kN" in summary and "0:08" in summary, summary  # 4 cycles at 0.5 Hz
    page.click("#confirm-cancel")
    assert "cancelled" in page.inner_text("#setup-message")
    assert len(server.call("GET", "/api/tests")[1]) == len(before)

    start_from_form(page, login=OPERATOR)  # nobody logged in yet: asked once, after the confirmation
    page.wait_for_selector("#account-button[data-role='operator']", timeout=5000)
    assert page.inner_text("#account-button .acct-name") == OPERATOR[0]
    assert page.inner_text("#account-button .acct-role") == "operator"
    assert page.input_value("#f-operator_name") == OPERATOR[0]

    known = {t["id"] for t in before}
    new = poll(lambda: {t["id"] for t in server.call("GET", "/api/tests")[1]} - known, 15, "the new test")
    test_id = max(new)
    poll(lambda: _metrics(page).get("testId") == test_id, 15, "the live view to pick up the new test")
    page.wait_for_selector("#rig-status[data-status='running']", timeout=WAIT_MS)
    def loop_size():
        m = _metrics(page)
        return (m.get("loopCycles", 0), m.get("loopPoints", 0))

    first = loop_size()  # the loop grows: more points in the current cycle or more finished cycles
    grown = poll(lambda: (lambda now: now if now > first else None)(loop_size()), 15, "the loop to grow")
    assert grown > first, (first, grown)
    page.screenshot(path=str(artifacts / "dashboard_running.png"))

    page.wait_for_selector("#rig-status[data-status='completed']", timeout=60000)
    # the last samples and the last loop are drawn after the status came
    page.wait_for_function("window.__isorig.loopCycles >= 3 && window.__isorig.samples >= 7000", timeout=WAIT_MS)
    m = _metrics(page)
    assert m["loopCycles"] >= 3, m  # 4 target cycles: at least 3 closed loops drawn in grey
    assert m["samples"] >= 7000, m  # 8 s of test at 1 kHz, every sample
    assert page.inner_text("#l-keff") != "-"  # latest cycle's metrics shown
    page.screenshot(path=str(artifacts / "dashboard_completed.png"))

    page.click("nav a[data-view='history']")
    row = page.wait_for_selector(f"#history-table tr[data-id='{test_id}']", timeout=WAIT_MS)
    text = row.inner_text()
    for what in ("completed", "IUT_b", "E2E-FLOW", OPERATOR[0], "125 kN"):  # status, who, what
        assert what in text, text
    # filters: status, isolator and today's date keep it; another status hides it
    page.select_option("#h-status", "aborted")
    page.click("#history-filter button[type='submit']")
    page.wait_for_selector(f"#history-table tr[data-id='{test_id}']", state="detached", timeout=WAIT_MS)
    today = page.evaluate("(() => { const d = new Date(); const p = (x) => String(x).padStart(2, '0');"
                          " return `${d.getFullYear()}-${p(d.getMonth() + 1)}-${p(d.getDate())}`; })()")
    page.select_option("#h-status", "completed")
    page.select_option("#h-isolator", "IUT_b")
    page.fill("#h-since", today)
    page.fill("#h-until", today)
    page.click("#history-filter button[type='submit']")
    row = page.wait_for_selector(f"#history-table tr[data-id='{test_id}']", timeout=WAIT_MS)
    row.click()
    page.wait_for_selector("#t-cycles tbody tr", timeout=WAIT_MS)
    assert page.locator("#t-cycles tbody tr").count() >= 3
    summary = page.inner_text("#t-summary")
    for what in ("completed", "E2E-FLOW", OPERATOR[0], "operator flow", "|d| 150 mm"):
        assert what in summary, summary
    page.screenshot(path=str(artifacts / "dashboard_test_page.png"), full_page=True)

    with page.expect_download(timeout=30000) as info:
        page.click("#t-csv")
    data = open(info.value.path(), encoding="utf-8").read()
    rows = list(csv.reader(io.StringIO(data)))
    # a column the controller fills with its own quantity is labelled "KEY: NAME (UNIT)" (the servo's model_m
    # holds its target r); readers find it by the name before the colon
    assert [c.split(":")[0] for c in rows[0][:4]] == ["time_s", "target_m", "model_m", "displacement_m"], rows[0]
    assert len(rows) - 1 >= 7900, len(rows)  # every 1 kHz sample of the 8 s test


def test_refused_profile_shows_reason(server, open_page, artifacts):
    """A profile outside the envelope is explained before Start, with field, value and limit; Start stays
    disabled and says why; nothing is created."""
    page, _ = open_page(server.url + "/", login=OPERATOR)
    _, before = server.call("GET", "/api/tests")
    fill_identity(page)
    page.select_option("#f-isolator", "IUT_b")
    page.fill("#f-amplitude", "200")  # beyond the +-150 mm stroke: the field's own range says so
    page.wait_for_selector("#envelope[data-state='refused']", timeout=WAIT_MS)
    assert "up to 150 mm" in page.inner_text("[data-field='amplitude'] .msg")
    assert "invalid" in (page.get_attribute("#f-amplitude", "class") or "")
    assert page.is_disabled("#start")
    assert "valid values (amplitude)" in page.inner_text("#start-why")

    # inside the stroke but more flow than the pump gives: explained by the service before Start
    page.fill("#f-amplitude", "100")
    page.fill("#f-frequency", "2")
    page.wait_for_function("document.getElementById('envelope').textContent.includes('peak flow demand')",
                           timeout=WAIT_MS)
    early = page.inner_text("#envelope")
    assert "frequency_hz" in early and "313" in early and "l/min" in early, early
    assert page.get_attribute("#envelope", "data-state") == "refused"
    assert "invalid" in (page.get_attribute("#f-frequency", "class") or "")
    assert page.is_disabled("#start")
    assert "within the rig envelope" in page.inner_text("#start-why")
    page.screenshot(path=str(artifacts / "dashboard_refused.png"))
    # back inside: the refusal goes, Start comes back
    page.fill("#f-frequency", "0.5")
    wait_start_enabled(page)
    assert page.get_attribute("#envelope", "data-state") == "ok"
    assert "invalid" not in (page.get_attribute("#f-frequency", "class") or "")
    _, after = server.call("GET", "/api/tests")
    assert len(after) == len(before)  # nothing was created


def test_live_view_follows_test_started_through_api(server, open_page, artifacts):
    """A test started by a script (REST) shows up in an open dashboard, with its status changes."""
    page, _ = open_page(server.url + "/")
    page.wait_for_selector("#conn.conn-up", timeout=WAIT_MS)
    test_id = server.start_test(sine_test(amplitude_m=0.02, frequency_hz=1.0, cycles=6, speed=2.0,
                                          isolator="IUT_a", supply_bar=100))
    page.wait_for_function(f"window.__isorig.testId === {test_id} && window.__isorig.samples > 500",
                           timeout=WAIT_MS)
    assert page.inner_text("#l-test") == f"#{test_id}"
    poll(lambda: page.inner_text("#l-isolator") == "IUT_a", 5, "the isolator in the header")
    page.wait_for_selector("#rig-status[data-status='running']", timeout=WAIT_MS)
    server.wait_status(test_id, {"completed"}, timeout_s=60)
    page.wait_for_selector("#rig-status[data-status='completed']", timeout=WAIT_MS)
    assert f"Test {test_id} completed" in page.inner_text("#alert-text")

    # a page opened while a test runs: time from navigation to the first live frame (recorded, not asserted);
    # it draws the loops stored before it joined, each once
    # (100 cycles, 50 s: it still runs when aborted below, however slow the page is to open on a loaded machine)
    test_id = server.start_test(sine_test(amplitude_m=0.02, frequency_hz=1.0, cycles=100, speed=2.0,
                                          isolator="IUT_a", supply_bar=100))
    server.wait_status(test_id, {"running"}, timeout_s=15)
    # 14 s of test (14 cycles at 1 Hz) on record: more than the 10 s of samples a late client gets
    poll(lambda: server.call("GET", f"/api/tests/{test_id}")[1]["cycles_done"] >= 14, 15, "14 cycles on record")
    late, _ = open_page(server.url + "/")
    late.wait_for_function("window.__isorig.firstLiveFrameMs !== null", timeout=WAIT_MS)
    first = _metrics(late)["firstLiveFrameMs"]
    (artifacts / "first_live_frame_ms.txt").write_text(f"{first:.0f}\n")
    _, rec = server.call("GET", f"/api/tests/{test_id}")
    stored = rec["cycles_done"]
    assert stored >= 12, rec
    # the history alone would give at most 10 loops; the page drew the stored ones too (the loop plot keeps the
    # latest 40: plots.js maxPast)
    late.wait_for_function(f"window.__isorig.loopCycles >= {min(stored, LOOPS_KEPT) - 1}", timeout=WAIT_MS)
    status, body = server.call("POST", f"/api/tests/{test_id}/abort", token=True)
    assert status == 200, body
    rec = server.wait_status(test_id, {"aborted"})
    late.wait_for_selector("#rig-status[data-status='aborted']", timeout=WAIT_MS)  # the page has the end too
    assert _metrics(late)["loopCycles"] <= rec["cycles_done"] + 1, (_metrics(late), rec["cycles_done"])
    late.screenshot(path=str(artifacts / "dashboard_aborted.png"))


@pytest.mark.parametrize("cookie", [None, "iss_a-stale-login"])
def test_abort_button_stops_the_rig(server, open_page, cookie):
    """ABORT ends a running test at once from any console, like an emergency stop: no login asked for, none
    needed (a second console without one, an ended one), no dialog in the way; the events say who asked."""
    page, _ = open_page(server.url + "/", cookie=cookie)
    test_id = server.start_test(sine_test(cycles=20, speed=1.0))
    page.wait_for_selector("#rig-status[data-status='running']", timeout=WAIT_MS)
    page.click("#abort")
    rec = server.wait_status(test_id, {"aborted"}, timeout_s=15)
    assert rec["status"] == "aborted"
    assert not page.is_visible("#login-dialog")
    page.wait_for_selector("#rig-status[data-status='aborted']", timeout=WAIT_MS)
    assert "ABORTED" in page.inner_text("#alert-text")
    asked = [e for e in rec["events"] if (e["values"] or {}).get("action") == "abort"]
    assert asked[0]["actor"] == "a console without login (127.0.0.1)", asked


def test_stop_button_ramps_out(server, open_page):
    """Stop finishes the running test with a ramp-out: status 'stopped'; a console without a login may stop."""
    page, _ = open_page(server.url + "/")
    test_id = server.start_test(sine_test(cycles=30, speed=1.0))
    page.wait_for_function(f"window.__isorig.testId === {test_id}", timeout=WAIT_MS)
    page.wait_for_selector("#rig-status[data-status='running']", timeout=WAIT_MS)
    page.click("#stop")
    rec = server.wait_status(test_id, {"stopped"}, timeout_s=20)
    assert rec["status"] == "stopped"
    page.wait_for_selector("#rig-status[data-status='stopped']", timeout=WAIT_MS)


def test_add_isolator_plausibility_api_refusal_and_delete(server, open_page, artifacts):
    """Values a thousand times off ask for a confirmation; the API's refusal (field and range) is shown; a valid
    isolator is saved in the console's units; a user isolator can be deleted after a confirmation, a preset not."""
    page, watch = open_page(server.url + "/", width=1366, height=768, login=OPERATOR)
    watch.allowed_status.add(422)
    assert page.is_disabled("#iso-delete")  # IUT_b is a preset
    page.click("#add-isolator summary")
    assert "(kN/mm)" in page.inner_text("[data-field='iso-kd_n_per_m']")  # units of the console
    values = {"name": "e2e_LRB", "rho_bw_per_m": "0,2", "sigma_bw": "0.5", "n": "1", "kd_n_per_m": "500",
              "kw_n": "20"}  # k_d typed as N/mm in a kN/mm field: 1000 times too stiff
    for key, value in values.items():
        page.fill(f"#iso-{key}", value)
    assert "read as 0.2 1/mm" in page.inner_text("[data-field='iso-rho_bw_per_m'] .msg")
    assert "wrong unit" in page.inner_text("[data-field='iso-kd_n_per_m'] .msg")
    page.click("#iso-save")
    page.wait_for_selector("#confirm-dialog[open]", timeout=WAIT_MS)
    assert "post-yield stiffness 500 kN/mm" in page.inner_text("#confirm-body"), page.inner_text("#confirm-body")
    assert page.is_disabled("#confirm-ok")  # the warning must be ticked
    page.click("#confirm-cancel")
    assert page.locator("#f-isolator option[value='e2e_LRB']").count() == 0  # nothing saved

    page.fill("#iso-kd_n_per_m", "0.5")
    page.fill("#iso-kw_n", "5e5")  # 5e8 N: beyond the API's range; ticked through, the API refuses it
    page.click("#iso-save")
    page.wait_for_selector("#confirm-dialog[open]", timeout=WAIT_MS)
    page.check("#confirm-body .warning-tick")
    page.click("#confirm-ok")
    page.wait_for_function("document.getElementById('iso-error').textContent.length > 0", timeout=WAIT_MS)
    assert "kw_n" in page.inner_text("#iso-error"), page.inner_text("#iso-error")

    page.fill("#iso-kw_n", "20")
    page.click("#iso-save")
    page.wait_for_function("document.getElementById('f-isolator').value === 'e2e_LRB'", timeout=WAIT_MS)
    assert page.inner_text("#iso-error") == ""
    params = page.inner_text("#isolator-params")
    assert "0.5" in params and "20" in params and "user-defined" in params, params
    _, iso = server.call("GET", "/api/isolators/e2e_LRB")
    assert iso["kd_n_per_m"] == 5e5 and iso["kw_n"] == 2e4 and abs(iso["rho_bw_per_m"] - 200) < 1e-9, iso
    assert page.locator("#f-isolator optgroup[label='user-defined'] option[value='e2e_LRB']").count() == 1

    assert page.is_enabled("#iso-delete")
    page.click("#iso-delete")
    page.wait_for_selector("#confirm-dialog[open]", timeout=WAIT_MS)
    page.screenshot(path=str(artifacts / "dashboard_delete_isolator.png"))
    page.click("#confirm-ok")
    page.wait_for_function("document.getElementById('setup-message').textContent.includes('deleted')", timeout=WAIT_MS)
    assert page.locator("#f-isolator option[value='e2e_LRB']").count() == 0
    assert server.call("GET", "/api/isolators/e2e_LRB")[0] == 404
    assert server.call("DELETE", "/api/isolators/IUT_a", token=True)[0] == 409  # presets stay


def test_limit_trip_is_shown_prominently(server, open_page, artifacts):
    """A tracking-error trip (bound set low through the API) raises the red banner with the limit's values."""
    page, _ = open_page(server.url + "/")
    page.wait_for_selector("#conn.conn-up", timeout=WAIT_MS)
    body = sine_test(cycles=10, speed=1.0, controller="mrac")
    body["limits"] = {"tracking_error_m": 0.0005}  # 0.5 mm: the MRAC's start-up transient exceeds it
    test_id = server.start_test(body)
    rec = server.wait_status(test_id, {"aborted"}, timeout_s=30)
    assert rec["reason"], rec
    page.wait_for_selector("#rig-status[data-status='aborted']", timeout=WAIT_MS)
    page.wait_for_function("document.getElementById('alert-text').textContent.includes('LIMIT TRIP')",
                           timeout=WAIT_MS)
    assert page.get_attribute("#alert", "data-kind") == "bad"
    assert page.locator("#live-events li.limit_trip").count() >= 1
    events = page.inner_text("#live-events")
    assert "LIMIT TRIP: tracking error" in events and "beyond the limit of 0.5 mm" in events, events
    # the action taken, in the event and in the banner (valve close: the default action)
    assert "valve close: the valve command ramps to 0 V in 0.1 s" in events, events
    assert "valve close: the valve command ramps to 0 V" in page.inner_text("#alert-text")
    assert "pid" not in events and "worker" not in events, events  # no internals
    page.screenshot(path=str(artifacts / "dashboard_limit_trip.png"))
    # dismissed, then the page reloaded: the old trip is no news (the badge and the strip still say how it ended)
    page.click("#alert-close")
    page.reload()
    page.wait_for_selector("body[data-ready='1']", timeout=WAIT_MS)
    page.wait_for_selector("#rig-status[data-status='aborted']", timeout=WAIT_MS)
    # the stream's hello and the record have come (its events, the trip among them)
    page.wait_for_function("document.getElementById('live-events').textContent.includes('LIMIT TRIP')",
                           timeout=WAIT_MS)
    assert page.is_hidden("#alert"), page.inner_text("#alert-text")


def test_vertical_load_is_entered_in_kn_within_the_jacks_range(server, open_page, artifacts):
    """The field shows its range and default; 900 kN is refused before Start; 300 kN travels with the test."""
    page, _ = open_page(server.url + "/", login=OPERATOR)
    page.select_option("#f-isolator", "IUT_a")
    # the default in the console's digits, and where it comes from (issue 23)
    assert page.inner_text("#vertical-load-note") == "0 to 850 kN; empty: 125.00 kN (the rig's default)"
    fill_identity(page)
    page.fill("#f-supply", "100")
    page.fill("#f-amplitude", "10")
    page.fill("#f-frequency", "2")
    page.fill("#f-cycles", "4")
    page.fill("#f-speed", "4")
    page.fill("#f-vertical_load", "900")
    page.wait_for_function("document.getElementById('envelope').dataset.state === 'refused'", timeout=WAIT_MS)
    assert "850 kN" in page.inner_text("[data-field='vertical_load'] .msg")
    assert "invalid" in (page.get_attribute("#f-vertical_load", "class") or "")
    page.fill("#f-vertical_load", "300")
    page.wait_for_function("document.getElementById('envelope').dataset.state === 'ok'", timeout=WAIT_MS)
    before = {t["id"] for t in server.call("GET", "/api/tests")[1]}
    summary = start_from_form(page)
    assert "300.00 kN" in summary and "vertical load: entered" in summary, summary  # the console's digits
    poll(lambda: {t["id"] for t in server.call("GET", "/api/tests")[1]} - before, 15, "the new test")
    test_id = max({t["id"] for t in server.call("GET", "/api/tests")[1]} - before)
    assert server.call("GET", f"/api/tests/{test_id}")[1]["vertical_load_n"] == 300e3
    poll(lambda: page.inner_text("#l-vertical-load") == "300 kN", 15, "the load in the live header")
    # the adapted parameters under the names and units the servo declares (GET /api/rig), one axis each
    poll(lambda: "flow gain ratio g (-)" in page.inner_text("#plot-adapt"), 10, "the servo's adapted names")
    assert "learned frequency (Hz)" in page.inner_text("#plot-adapt")
    assert "valve's true flow gain" in page.inner_text("#plot-adapt")
    page.screenshot(path=str(artifacts / "dashboard_vertical_load.png"))
    server.wait_status(test_id, {"completed"}, timeout_s=60)
