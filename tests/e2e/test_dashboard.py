"""The operator's dashboard in Debian's chromium against the real `isorig serve` (simulated rig, accelerated).

The `open_page` fixture fails a test on any console error or any request to another host.
"""

from __future__ import annotations

import csv
import io
import time

from .harness import TOKEN, sine_test


def _metrics(page) -> dict:
    return page.evaluate("() => ({...window.__isorig})")


def _wait(predicate, timeout_s: float, what: str, interval_s: float = 0.1):
    deadline = time.monotonic() + timeout_s
    last = None
    while time.monotonic() < deadline:
        last = predicate()
        if last:
            return last
        time.sleep(interval_s)
    raise AssertionError(f"timed out after {timeout_s} s waiting for {what} (last: {last!r})")


def test_operator_flow(server, open_page, artifacts):
    """Choose IUT_b, 30 mm at 0.5 Hz, start with the token, see the loop grow, finish, find it in history, CSV."""
    page, _ = open_page(server.url + "/")
    page.select_option("#f-isolator", "IUT_b")
    assert "680000" in page.inner_text("#isolator-params")  # k_d of IUT_b (paper Table II), shown
    page.fill("#f-supply_bar", "70")
    page.fill("#f-amplitude_mm", "30")
    page.fill("#f-frequency_hz", "0.5")
    page.fill("#f-cycles", "4")
    page.fill("#f-taper_cycles", "1")
    page.fill("#f-speed", "2")
    page.wait_for_function("document.getElementById('envelope').dataset.state !== undefined")
    assert page.get_attribute("#envelope", "data-state") != "refused", page.inner_text("#envelope")

    page.click("#start")  # no token in this browser yet: the dialog asks once
    page.wait_for_selector("#token-dialog[open]", timeout=5000)
    page.fill("#token-input", TOKEN)
    page.click("#token-ok")
    assert page.evaluate("localStorage.getItem('isorig.operator_token')") == TOKEN

    _wait(lambda: _metrics(page).get("testId"), 15, "the live view to pick up the new test")
    test_id = _metrics(page)["testId"]
    page.wait_for_selector("#rig-status[data-status='running']", timeout=15000)
    points = []
    for _ in range(6):  # the loop grows: more points in the current cycle or more finished cycles
        m = _metrics(page)
        points.append((m.get("loopCycles", 0), m.get("loopPoints", 0)))
        time.sleep(0.25)
    assert len(set(points)) > 1 and points[-1] > points[0], points
    page.screenshot(path=str(artifacts / "dashboard_running.png"))

    page.wait_for_selector("#rig-status[data-status='completed']", timeout=60000)
    time.sleep(0.3)
    m = _metrics(page)
    assert m["loopCycles"] >= 3, m  # 4 target cycles: at least 3 closed loops drawn in grey
    assert m["samples"] >= 7000, m  # 8 s of test at 1 kHz, every sample
    assert page.inner_text("#l-keff") != "-"  # latest cycle's metrics shown
    page.screenshot(path=str(artifacts / "dashboard_completed.png"))

    page.click("nav a[data-view='history']")
    row = page.wait_for_selector(f"#history-table tr[data-id='{test_id}']", timeout=10000)
    assert "completed" in row.inner_text()
    assert "IUT_b" in row.inner_text()
    # filters: status, isolator and today's date keep it; another status hides it
    page.select_option("#h-status", "aborted")
    page.click("#history-filter button[type='submit']")
    page.wait_for_selector(f"#history-table tr[data-id='{test_id}']", state="detached", timeout=5000)
    today = page.evaluate("(() => { const d = new Date(); const p = (x) => String(x).padStart(2, '0');"
                          " return `${d.getFullYear()}-${p(d.getMonth() + 1)}-${p(d.getDate())}`; })()")
    page.select_option("#h-status", "completed")
    page.select_option("#h-isolator", "IUT_b")
    page.fill("#h-since", today)
    page.fill("#h-until", today)
    page.click("#history-filter button[type='submit']")
    row = page.wait_for_selector(f"#history-table tr[data-id='{test_id}']", timeout=5000)
    row.click()
    page.wait_for_selector("#t-cycles tbody tr", timeout=10000)
    assert page.locator("#t-cycles tbody tr").count() >= 3
    assert "completed" in page.inner_text("#t-summary")
    page.screenshot(path=str(artifacts / "dashboard_test_page.png"), full_page=True)

    with page.expect_download(timeout=30000) as info:
        page.click("#t-csv")
    data = open(info.value.path(), encoding="utf-8").read()
    rows = list(csv.reader(io.StringIO(data)))
    assert rows[0][:4] == ["time_s", "target_m", "model_m", "displacement_m"], rows[0]
    assert len(rows) - 1 >= 7900, len(rows)  # every 1 kHz sample of the 8 s test


def test_refused_profile_shows_reason(server, open_page, artifacts):
    """A profile outside the envelope is explained before Start and refused with field, value and limit."""
    page, watch = open_page(server.url + "/", token=TOKEN)
    watch.allowed_status.add(422)  # the refusal this test provokes
    _, before = server.call("GET", "/api/tests")
    page.select_option("#f-isolator", "IUT_b")
    page.fill("#f-amplitude_mm", "200")  # beyond the +-150 mm stroke
    page.wait_for_selector("#envelope[data-state='refused']", timeout=5000)
    text = page.inner_text("#envelope")
    assert "stroke" in text and "150" in text, text
    assert "invalid" in (page.get_attribute("#f-amplitude_mm", "class") or "")

    # inside the stroke but more flow than the pump gives: explained before Start (POST /api/tests/check) ...
    page.fill("#f-amplitude_mm", "100")
    page.fill("#f-frequency_hz", "2")
    page.wait_for_function("document.getElementById('envelope').textContent.includes('peak flow demand')", timeout=5000)
    early = page.inner_text("#envelope")
    assert "frequency_hz" in early and "313" in early, early
    assert page.get_attribute("#envelope", "data-state") == "refused"
    # ... and refused by the service at Start with the limit
    page.click("#start")
    page.wait_for_function("document.getElementById('setup-message').textContent.startsWith('Refused')",
                           timeout=10000)
    message = page.inner_text("#envelope")
    assert "frequency_hz" in message and "l/min" in message, message
    assert page.get_attribute("#envelope", "data-state") == "refused"
    assert "invalid" in (page.get_attribute("#f-frequency_hz", "class") or "")
    page.screenshot(path=str(artifacts / "dashboard_refused.png"))
    _, after = server.call("GET", "/api/tests")
    assert len(after) == len(before)  # nothing was created


def test_live_view_follows_test_started_through_api(server, open_page, artifacts):
    """A test started by a script (REST) shows up in an open dashboard, with its status changes."""
    page, _ = open_page(server.url + "/")
    page.wait_for_selector("#conn.conn-up", timeout=10000)
    test_id = server.start_test(sine_test(amplitude_m=0.02, frequency_hz=1.0, cycles=6, speed=2.0,
                                          isolator="IUT_a", supply_bar=100))
    page.wait_for_function(f"window.__isorig.testId === {test_id} && window.__isorig.samples > 500",
                           timeout=15000)
    assert page.inner_text("#l-test") == f"#{test_id}"
    _wait(lambda: page.inner_text("#l-isolator") == "IUT_a", 5, "the isolator in the header")
    page.wait_for_selector("#rig-status[data-status='running']", timeout=10000)
    server.wait_status(test_id, {"completed"}, timeout_s=60)
    page.wait_for_selector("#rig-status[data-status='completed']", timeout=10000)
    assert f"Test {test_id} completed" in page.inner_text("#alert-text")

    # a page opened while a test runs: time from navigation to the first live frame (recorded, not asserted);
    # it draws the loops stored before it joined, each once
    test_id = server.start_test(sine_test(amplitude_m=0.02, frequency_hz=1.0, cycles=60, speed=2.0,
                                          isolator="IUT_a", supply_bar=100))
    server.wait_status(test_id, {"running"}, timeout_s=15)
    time.sleep(7.0)  # 14 s of test: more than the 10 s of samples a late client gets
    late, _ = open_page(server.url + "/")
    late.wait_for_function("window.__isorig.firstLiveFrameMs !== null", timeout=10000)
    first = _metrics(late)["firstLiveFrameMs"]
    (artifacts / "first_live_frame_ms.txt").write_text(f"{first:.0f}\n")
    _, rec = server.call("GET", f"/api/tests/{test_id}")
    stored = rec["cycles_done"]
    assert stored >= 12, rec
    # the history alone would give at most 10 loops; the page drew the stored ones too
    late.wait_for_function(f"window.__isorig.loopCycles >= {stored - 1}", timeout=10000)
    status, body = server.call("POST", f"/api/tests/{test_id}/abort", token=True)
    assert status == 200, body
    _, rec = server.call("GET", f"/api/tests/{test_id}")
    time.sleep(0.5)
    assert _metrics(late)["loopCycles"] <= rec["cycles_done"] + 1, (_metrics(late), rec["cycles_done"])
    late.wait_for_selector("#rig-status[data-status='aborted']", timeout=10000)
    late.screenshot(path=str(artifacts / "dashboard_aborted.png"))


def test_abort_button_stops_the_rig(server, open_page):
    """Abort ends a running test at once; a wrong stored token is refused and the operator is asked again."""
    page, watch = open_page(server.url + "/", token="not-the-token")
    watch.allowed_status.add(401)  # the wrong token's refusal
    test_id = server.start_test(sine_test(cycles=20, speed=1.0))
    page.wait_for_selector("#rig-status[data-status='running']", timeout=15000)
    page.click("#abort")
    page.wait_for_selector("#token-dialog[open]", timeout=5000)
    assert "refused" in page.inner_text("#token-reason")
    assert server.call("GET", f"/api/tests/{test_id}")[1]["status"] == "running"  # nothing moved yet
    page.fill("#token-input", TOKEN)
    page.click("#token-ok")
    rec = server.wait_status(test_id, {"aborted"}, timeout_s=15)
    assert rec["status"] == "aborted"
    page.wait_for_selector("#rig-status[data-status='aborted']", timeout=10000)
    assert "ABORTED" in page.inner_text("#alert-text")
    assert page.evaluate("localStorage.getItem('isorig.operator_token')") == TOKEN


def test_stop_button_ramps_out(server, open_page):
    """Stop finishes the running test with a ramp-out: status 'stopped'."""
    page, _ = open_page(server.url + "/", token=TOKEN)
    test_id = server.start_test(sine_test(cycles=30, speed=1.0))
    page.wait_for_function(f"window.__isorig.testId === {test_id}", timeout=15000)
    page.wait_for_selector("#rig-status[data-status='running']", timeout=15000)
    page.click("#stop")
    rec = server.wait_status(test_id, {"stopped"}, timeout_s=20)
    assert rec["status"] == "stopped"
    page.wait_for_selector("#rig-status[data-status='stopped']", timeout=10000)


def test_add_isolator_validated_by_the_api(server, open_page):
    """The add-isolator form shows the API's refusal (field and range), then saves a valid isolator."""
    page, watch = open_page(server.url + "/", token=TOKEN)
    watch.allowed_status.add(422)
    page.click("#add-isolator summary")
    values = {"name": "e2e_LRB", "rho_bw_per_m": "200", "sigma_bw": "0.5", "n": "1", "kd_n_per_m": "5e5",
              "kw_n": "5e8"}  # k_w far beyond the allowed range (a unit mistake)
    for key, value in values.items():
        page.fill(f"#iso-{key}", value)
    page.click("#iso-save")
    page.wait_for_function("document.getElementById('iso-error').textContent.length > 0", timeout=5000)
    error = page.inner_text("#iso-error")
    assert "kw_n" in error, error
    page.fill("#iso-kw_n", "2e4")
    page.click("#iso-save")
    page.wait_for_function("document.getElementById('f-isolator').value === 'e2e_LRB'", timeout=5000)
    assert page.inner_text("#iso-error") == ""
    params = page.inner_text("#isolator-params")
    assert "200" in params and "20000" in params, params
    assert page.locator("#f-isolator optgroup[label='user-defined'] option[value='e2e_LRB']").count() == 1


def test_limit_trip_is_shown_prominently(server, open_page, artifacts):
    """A tracking-error trip (bound set low through the API) raises the red banner with the limit's values."""
    page, _ = open_page(server.url + "/")
    page.wait_for_selector("#conn.conn-up", timeout=10000)
    body = sine_test(cycles=10, speed=1.0)
    body["limits"] = {"tracking_error_m": 0.0005}  # 0.5 mm: the start-up transient exceeds it
    test_id = server.start_test(body)
    rec = server.wait_status(test_id, {"aborted"}, timeout_s=30)
    assert rec["reason"], rec
    page.wait_for_selector("#rig-status[data-status='aborted']", timeout=10000)
    page.wait_for_function("document.getElementById('alert-text').textContent.includes('LIMIT TRIP')",
                           timeout=10000)
    assert page.get_attribute("#alert", "data-kind") == "bad"
    assert page.locator("#live-events li.limit_trip").count() >= 1
    assert "tracking_error_m" in page.inner_text("#live-events")
    page.screenshot(path=str(artifacts / "dashboard_limit_trip.png"))


def test_vertical_load_is_entered_in_kn_within_the_jacks_range(server, open_page, artifacts):
    """The field shows its range and default; 900 kN is refused before Start; 300 kN travels with the test."""
    page, _ = open_page(server.url + "/")
    page.evaluate(f"localStorage.setItem('isorig.operator_token', '{TOKEN}')")
    page.reload()
    page.select_option("#f-isolator", "IUT_a")
    assert page.inner_text("#vertical-load-note") == "0 to 850 kN; empty: 125 kN"
    page.fill("#f-supply_bar", "100")
    page.fill("#f-amplitude_mm", "10")
    page.fill("#f-frequency_hz", "2")
    page.fill("#f-cycles", "4")
    page.fill("#f-speed", "4")
    page.fill("#f-vertical_load_kn", "900")
    page.wait_for_function("document.getElementById('envelope').dataset.state === 'refused'", timeout=10000)
    assert "vertical" in page.inner_text("#envelope").lower() and "850" in page.inner_text("#envelope")
    assert "invalid" in (page.get_attribute("#f-vertical_load_kn", "class") or "")
    page.fill("#f-vertical_load_kn", "300")
    page.wait_for_function("document.getElementById('envelope').dataset.state !== 'refused'", timeout=10000)
    before = {t["id"] for t in server.call("GET", "/api/tests")[1]}
    page.click("#start")
    _wait(lambda: {t["id"] for t in server.call("GET", "/api/tests")[1]} - before, 15, "the new test")
    test_id = max({t["id"] for t in server.call("GET", "/api/tests")[1]} - before)
    assert server.call("GET", f"/api/tests/{test_id}")[1]["vertical_load_n"] == 300e3
    _wait(lambda: page.inner_text("#l-vertical-load") == "300 kN", 15, "the load in the live header")
    # the adapted parameters under the names and units the servo declares (GET /api/rig)
    _wait(lambda: "flow gain ratio g (-)" in page.inner_text("#plot-adapt"), 10, "the servo's adapted names")
    assert "learned frequency (Hz, right)" in page.inner_text("#plot-adapt")
    assert "valve's true flow gain" in page.inner_text("#adapt-note")
    page.screenshot(path=str(artifacts / "dashboard_vertical_load.png"))
    server.wait_status(test_id, {"completed"}, timeout_s=60)
