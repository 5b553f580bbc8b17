"""The rig and its link in the dashboard's top bar: the simulated default, and a real rig over UDP
(`isorig rig-emulator` in its own process, `isorig serve --rig udp://...`): connected, the link figures of a
running test, "not connected" once the rig is gone, and a table left off zero that keeps Start disabled until the
console's Zero brings it back.
"""

from __future__ import annotations

import json
import re

import pytest

from .harness import (
    OPERATOR,
    WAIT_MS,
    RigEmulator,
    Server,
    fill_identity,
    poll,
    settle,
    sine_test,
    start_from_form,
    wait_start_enabled,
)

VIEWPORTS = [(1366, 768), (1920, 1080)]
MS = r"\d+(\.\d{1,2})? ms"  # a latency: at most 2 decimals


def _shots(page, artifacts, name: str) -> None:
    """Screenshots at both viewports (the page ends at the first one)."""
    for width, height in reversed(VIEWPORTS):
        page.set_viewport_size({"width": width, "height": height})
        page.wait_for_function(f"window.innerWidth === {width}", timeout=WAIT_MS)
        settle(page)
        page.screenshot(path=str(artifacts / f"{name}_{width}x{height}.png"))


def _wait_new_test(srv, known: set, timeout_s: float = 15.0) -> int:
    """The id of a record created since ``known`` (a test or a manual move)."""
    return max(poll(lambda: {t["id"] for t in srv.call("GET", "/api/tests")[1]} - known, timeout_s,
                    "a new record"))


def _link(page) -> dict:
    return page.evaluate("() => ({...document.getElementById('rig-link').dataset})")


def _fits_top_bar(page) -> None:
    """The rig block stays inside the top bar, next to the rig status, at this viewport."""
    box = page.locator("#rig-link").bounding_box()
    bar = page.locator("#topbar").bounding_box()
    status = page.locator("#rig-status").bounding_box()
    assert box["y"] >= bar["y"] and box["y"] + box["height"] <= bar["y"] + bar["height"], (box, bar)
    assert box["x"] + box["width"] <= status["x"], (box, status)


def test_simulated_rig_is_named(server, open_page, artifacts):
    """The default service drives the simulated rig: named in the top bar, speed editable, no warning."""
    page, _ = open_page(server.url + "/", width=1366, height=768)
    page.wait_for_selector("#rig-link[data-kind='simulated'][data-connected='true']", timeout=WAIT_MS)
    assert page.inner_text("#rig-name") == "simulated rig"
    assert page.is_enabled("#f-speed")
    assert page.is_hidden("#rig-warning")
    _fits_top_bar(page)
    if page.is_visible("#alert"):  # a banner of an earlier test of the session
        page.click("#alert-close")
    _shots(page, artifacts, "dashboard_simulated_rig")
    page.click("#rig-link")  # the details popover
    assert "simulated" in page.inner_text("#rig-details")
    page.keyboard.press("Escape")
    assert page.is_hidden("#rig-details")


@pytest.mark.realtime  # the rig emulator in its own process: run alone, after the others (scripts/test.sh)
def test_udp_rig_link_health(open_page, artifacts, tmp_path):
    """A service on an emulated UDP rig: the rig and "connected", speed fixed at 1, a test's round trip and last
    sequence updating, then "not connected" (and Start explained) once the emulator stops."""
    emulator = RigEmulator(isolator="IUT_a")
    srv = None
    try:
        srv = Server(tmp_path / "serve", rig=emulator.url).start()
        page, _ = open_page(srv.url + "/", width=1366, height=768, login=OPERATOR)
        page.wait_for_selector("#rig-link[data-kind='udp'][data-connected='true']", timeout=WAIT_MS)
        assert page.inner_text("#rig-name") == emulator.url
        assert page.inner_text("#rig-state") == "connected"
        assert re.search(f"round trip {MS}", page.inner_text("#rig-figs")), page.inner_text("#rig-figs")
        title = page.get_attribute("#rig-link", "title")  # the link settings in the tooltip
        assert "control period 1 ms" in title and "link timeout" in title and "arm timeout" in title, title
        page.click("#rig-link")
        details = page.inner_text("#rig-details")
        for what in ("host", "port", "control period", "link timeout", "arm timeout", "protocol"):
            assert what in details, details
        assert "link not authenticated" in details, details  # loopback without a key file: protocol 1, and said
        page.click("#setup h2")  # a click elsewhere closes it
        assert page.is_hidden("#rig-details")
        # a real rig runs in real time: speed fixed at 1, with the reason
        assert not page.is_enabled("#f-speed")
        assert page.input_value("#f-speed") == "1"
        assert "real time" in page.inner_text("#speed-note")
        assert page.is_hidden("#rig-warning")
        _fits_top_bar(page)
        _shots(page, artifacts, "dashboard_udp_idle")

        # a test at speed 1 from the form: the link figures of the running test update
        page.select_option("#f-isolator", "IUT_a")
        fill_identity(page)
        page.fill("#f-supply", "100")
        page.fill("#f-amplitude", "10")
        page.fill("#f-frequency", "1")
        # 120 s in real time, ended by Stop once the page has shown it: 8 s and 20 s ended before a loaded machine's
        # page read its running details
        page.fill("#f-cycles", "120")
        page.fill("#f-taper_cycles", "1")
        start_from_form(page)
        page.wait_for_selector("#rig-link[data-source='test'][data-last-sequence]", timeout=WAIT_MS)
        first = _link(page)
        page.wait_for_function("Number(document.getElementById('rig-link').dataset.lastSequence) > "
                               f"{int(first['lastSequence']) + 200}", timeout=WAIT_MS)
        figs = page.inner_text("#rig-figs")
        assert re.search(f"round trip p50 {MS}, p99 {MS}", figs), figs
        for what in ("lost ", "rejected ", "rig missed ", "seq "):
            assert re.search(what + r"\d+\b", figs), figs
        assert float(_link(page)["roundTripMs"]) > 0
        _fits_top_bar(page)
        _shots(page, artifacts, "dashboard_udp_running")
        page.click("#rig-link")  # the details: settings and every figure of the running test
        details = page.inner_text("#rig-details")
        assert f"test #{page.evaluate('window.__isorig.testId')} running" in details, details
        assert "measurements lost" in details and "last sequence" in details, details
        box = page.locator("#rig-details").bounding_box()
        right = max(box["x"] + box["width"], sum(page.locator("#rig-link").bounding_box()[k] for k in ("x", "width")))
        clip = {"x": 0, "y": 0, "width": right + 20, "height": box["y"] + box["height"] + 12}
        page.screenshot(path=str(artifacts / "dashboard_udp_details.png"), clip=clip)
        page.keyboard.press("Escape")
        test_id = page.evaluate("window.__isorig.testId")
        page.click("#stop")  # a ramp-out over the link, then the rig disarmed
        rec = srv.wait_status(test_id, {"stopped"})
        assert rec["speed"] == 1.0 and rec["driver"] == emulator.url, rec
        # between tests FORCE is the rig's own reading, COMMAND 0 V (not armed: the valve is closed)
        page.wait_for_function("document.getElementById('r-f').dataset.source === 'the rig (probe)'", timeout=WAIT_MS)
        assert "the rig's reading" in page.get_attribute("#r-f", "title")
        page.wait_for_function("document.getElementById('r-v').textContent === '0.000 V'", timeout=WAIT_MS)

        # the rig goes away: not connected (red) within a poll, and Start says why it would fail
        emulator.stop()
        page.wait_for_selector("#rig-link[data-connected='false']", timeout=WAIT_MS)
        assert page.inner_text("#rig-state") == "NOT CONNECTED"
        assert page.is_visible("#rig-warning")
        assert "Start is disabled" in page.inner_text("#rig-warning")
        page.wait_for_selector("#start[disabled]", timeout=WAIT_MS)  # a start cannot succeed: disabled, saying why
        assert "the rig is not connected" in page.inner_text("#start-why")
        page.wait_for_selector("#s-rig-cell[data-state='not-connected']", timeout=WAIT_MS)
        # no force or command to show: a dash, the tooltip says why (not the figures of before)
        for readout in ("#r-f", "#r-v"):
            page.wait_for_selector(f"{readout}[data-source='none']", timeout=WAIT_MS)
            assert page.inner_text(readout) == "-"
            assert "no reading: the rig does not answer" in page.get_attribute(readout, "title")
        _fits_top_bar(page)
        _shots(page, artifacts, "dashboard_udp_not_connected")
    finally:
        emulator.stop()
        if srv is not None:
            srv.stop()


@pytest.mark.realtime  # the rig emulator in its own process: run alone, after the others (scripts/test.sh)
def test_udp_rig_table_off_zero_keeps_start_disabled(open_page, artifacts, tmp_path):
    """An emulated rig restarts mid-test (`--restart-after-s 0.6`) and leaves its table mid-stroke: the strip
    shows where it rests (the rig's own reading), Start stays disabled saying why, and a start the service refuses
    (409, nothing moved) is shown in words beside Start; Zero (with its confirmation) moves the table back on the
    rig, Start comes back and the refusal goes."""
    emulator = RigEmulator("--restart-after-s", "0.6", isolator="IUT_a")
    srv = None
    try:
        srv = Server(tmp_path / "serve", rig=emulator.url).start()
        first = srv.start_test({**sine_test(amplitude_m=0.01, frequency_hz=1.0, cycles=6, speed=1.0,
                                            isolator="IUT_a", supply_bar=100)})
        rec = srv.wait_status(first, {"failed"}, timeout_s=30)  # the rig restarted: link lost
        _, state = srv.call("GET", "/api/rig/state")
        assert state["position_source"] == "the rig (probe)" and abs(state["table_position_m"]) > 0.002, state
        position = f"{state['table_position_m'] * 1e3:+.2f} mm"

        page, watch = open_page(srv.url + "/", width=1366, height=768, login=OPERATOR)
        watch.allowed_status.add(409)  # the refused start below
        page.wait_for_selector("#rig-link[data-connected='true']", timeout=WAIT_MS)
        page.wait_for_selector("#s-position[data-source='the rig (probe)']", timeout=WAIT_MS)
        assert page.inner_text("#s-position") == f"{position} \u00b7 the rig (probe)"
        fill_identity(page)
        page.select_option("#f-isolator", "IUT_a")
        page.fill("#f-supply", "100")
        page.fill("#f-amplitude", "10")
        page.fill("#f-frequency", "1")
        page.fill("#f-cycles", "3")
        page.wait_for_selector("#envelope[data-state='ok']", timeout=WAIT_MS)
        page.wait_for_selector("#rig-warning[data-state='off-zero']", timeout=WAIT_MS)
        page.wait_for_function("!document.getElementById('start-why').textContent.includes('envelope check')",
                               timeout=WAIT_MS)  # the set-up checked: only the table keeps Start disabled
        assert page.is_disabled("#start")
        why = page.inner_text("#start-why")
        assert f"Start needs: the table at zero (it rests at {position}, see above: Zero brings it back)" in why, why
        warning = page.inner_text("#rig-warning")
        assert warning.startswith("Table off zero: Start is disabled until it rests at zero."), warning
        assert f"The table rests at {position} (the rig's reading)" in warning, warning
        assert "within \u00b12 mm of zero" in warning, warning
        assert page.is_enabled("#warning-zero") and page.is_enabled("#mm-zero")  # the way back, at hand
        assert page.inner_text("#mm-position") == f"{position} \u00b7 the rig's reading"
        _shots(page, artifacts, "dashboard_udp_off_zero")

        # the console's view is 2 s old at worst: should a start still reach the service, its refusal is shown
        # (until the start is refused: a reading asked for after the refusal is the rig's own, or it would clear it)
        refused = []
        page.on("response", lambda r: refused.append(r.url) if "/start" in r.url and r.status == 409 else None)

        def at_zero(route):
            if refused:
                route.continue_()
                return
            data = route.fetch().json()
            data["table_position_m"] = 0.0
            route.fulfill(status=200, content_type="application/json", body=json.dumps(data))

        page.route("**/api/rig/state", at_zero)
        wait_start_enabled(page)
        start_from_form(page)
        page.wait_for_function("document.getElementById('setup-message').dataset.cause === 'position'", timeout=WAIT_MS)
        message = page.inner_text("#setup-message")
        assert message.startswith("Not started, refused by the service: the table is at"), message
        assert "nothing moved" in message, message
        assert [t["id"] for t in srv.call("GET", "/api/tests")[1]] == [first]  # nothing created
        page.unroute("**/api/rig/state")
        page.wait_for_selector("#start[disabled]", timeout=WAIT_MS)  # the rig's reading again
        assert "the table at zero" in page.inner_text("#start-why")
        assert page.inner_text("#setup-message") == message  # the refusal stays: its cause is still there
        page.screenshot(path=str(artifacts / "dashboard_udp_off_zero_refused_1366x768.png"))
        assert rec["status"] == "failed"

        # Zero: the console moves the table back on the rig (POST /api/rig/zero), after a confirmation
        page.fill("#f-mm_speed", "10")
        page.click("#warning-zero")
        page.wait_for_selector("#confirm-dialog[open]", timeout=WAIT_MS)
        confirm = page.inner_text("#confirm-body")
        assert position in confirm and "10 mm/s" in confirm, confirm
        page.click("#confirm-ok")
        move = _wait_new_test(srv, {first})
        rec = srv.wait_status(move, {"completed"}, timeout_s=30)
        assert rec["profile"]["kind"] == "move" and rec["profile"]["end_m"] == 0.0, rec["profile"]
        assert rec["driver"].startswith("udp://") and rec["profile"]["speed_m_per_s"] == 0.01, rec
        page.wait_for_selector("#mm-status[data-kind='ok']:has-text('completed')", timeout=WAIT_MS)
        assert page.inner_text("#mm-status").startswith(f"Move #{move} completed"), page.inner_text("#mm-status")
        _, state = srv.call("GET", "/api/rig/state")
        assert abs(state["table_position_m"]) < 0.001, state  # the rig's own reading
        page.wait_for_function("(() => { const w = document.getElementById('rig-warning');"
                               " return w.dataset.state === 'ok' && w.classList.contains('hidden'); })()",
                               timeout=WAIT_MS)
        wait_start_enabled(page)
        page.wait_for_function("document.getElementById('setup-message').textContent === ''", timeout=WAIT_MS)
    finally:
        emulator.stop()
        if srv is not None:
            srv.stop()
