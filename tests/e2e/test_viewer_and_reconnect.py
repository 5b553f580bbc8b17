"""The 3D rig view through the service's relay, and reconnection after a service restart.

Both use the session's `isorig serve` (3D view on); the restart test runs last and leaves it running.
"""

from __future__ import annotations

import json
import time
import urllib.request

from .harness import OPERATOR, PageWatch, log_in, sine_test, watch_rejections


def test_3d_view_is_relayed_and_follows_the_rig(server, open_page, artifacts):
    with urllib.request.urlopen(f"{server.url}/viewer/status", timeout=5) as r:
        assert json.load(r)["enabled"] is True
    page, watch = open_page(server.url + "/", height=1700, viewer=True)  # tall enough to show the 3D panel
    assert page.get_attribute("#viewer-box iframe", "src") == "/viewer/"
    frame = page.frame_locator("#viewer-box iframe")
    frame.locator("canvas").first.wait_for(timeout=30000)  # viser's client runs, served by the relay
    test_id = server.start_test(sine_test(cycles=10, speed=1.0))
    # the scene's GUI text follows the live stream (hub -> viser -> relay -> iframe)
    frame.get_by_text(f"test #{test_id}", exact=False).first.wait_for(timeout=20000)
    time.sleep(1.0)
    assert frame.locator("[aria-label*='share' i], [title*='share' i]").count() == 0  # share button hidden
    page.locator("#viewer-box").screenshot(path=str(artifacts / "dashboard_3d.png"))  # scrolled into view
    page.screenshot(path=str(artifacts / "dashboard_with_3d.png"))
    page.click("#viewer-toggle")  # the operator can hide it (kept per browser)
    assert page.locator("#viewer-box iframe").count() == 0
    assert page.evaluate("localStorage.getItem('isorig.viewer')") == "off"
    page.click("#viewer-toggle")
    page.wait_for_selector("#viewer-box iframe")
    assert page.evaluate("localStorage.getItem('isorig.viewer')") == "on"
    server.call("POST", f"/api/tests/{test_id}/abort", token=True)
    sockets = [u for u in watch.requests if u.startswith("ws")]
    assert any(u.endswith("/viewer") for u in sockets), sockets  # viser's socket goes through the relay
    assert not watch.foreign(), watch.foreign()


def test_reconnects_after_service_restart(server, browser, artifacts):
    """Stop the service under an open dashboard (Ctrl-C: it brings the running test's table back first), start it
    again: the page reconnects, says how the test ended, shows where the table was left (the service keeps it
    across the restart) in the strip and the DISPLACEMENT readout, Zero works, and it follows a new test."""
    srv = server
    context = browser.new_context(viewport={"width": 1400, "height": 900})
    watch_rejections(context)
    log_in(context, srv.url, OPERATOR)
    try:
        page = context.new_page()
        watch = PageWatch(page)
        # while the service is down the browser logs failed websocket connections and nothing else
        watch.allowed_patterns.append(r"WebSocket connection to 'ws://127\.0\.0\.1:\d+/ws/live' failed")
        # ... and the rig's state it asks for every 2 s (and records), refused while the service is down
        watch.allowed_patterns.append(r"^Failed to load resource: net::ERR_CONNECTION_REFUSED$")
        page.goto(srv.url + "/?viewer=off")
        page.wait_for_selector("body[data-ready='1']", timeout=15000)
        page.wait_for_selector("#conn.conn-up", timeout=10000)
        running = srv.start_test(sine_test(cycles=30, speed=1.0))
        page.wait_for_function(f"window.__isorig.testId === {running} && window.__isorig.samples > 200",
                               timeout=15000)
        srv.stop()  # the service goes away in the middle of a test
        page.wait_for_selector("#conn.conn-down", timeout=10000)
        # the strip says so, and nothing can be started meanwhile
        page.wait_for_selector("#s-rig-cell[data-state='no-connection']", timeout=5000)
        assert page.is_disabled("#start") and "no connection" in page.inner_text("#start-why")
        time.sleep(0.5)  # at least one failed attempt
        srv.start()
        page.wait_for_selector("#conn.conn-up", timeout=15000)
        assert page.evaluate("window.__isorig.connects") >= 2
        _, rec = srv.call("GET", f"/api/tests/{running}")
        assert rec["status"] in ("interrupted", "aborted"), rec
        # the page keeps that test on screen and says how it ended
        page.wait_for_selector(f"#rig-status[data-status='{rec['status']}']", timeout=10000)
        assert rec["status"].upper() in page.inner_text("#alert-text")
        page.screenshot(path=str(artifacts / "dashboard_interrupted.png"))
        # the interrupted test left the table where it was, and the restarted service knows where: Zero
        _, state = srv.call("GET", "/api/rig/state")
        assert state["position_source"] == f"end of test {running} ({rec['status']})", state
        source = f"end of test {running} ({rec['status']})"  # the service's figure, not the page's last sample
        page.wait_for_function(f"document.getElementById('s-position').dataset.source === {source!r}", timeout=10000)
        # told to stop, the service brought the table back before it exited (issue 21), and the DISPLACEMENT
        # readout says where the table is now, as the strip does, not the last sample before the restart
        assert abs(state["table_position_m"]) < 0.001, state
        page.wait_for_function(f"document.getElementById('r-y').dataset.source === {source!r}", timeout=10000)
        assert page.inner_text("#r-y") == page.inner_text("#s-position").split()[0] + " mm", (
            page.inner_text("#r-y"), page.inner_text("#s-position"))
        page.fill("#f-mm_speed", "50")
        page.click("#mm-zero")
        page.wait_for_selector("#confirm-dialog[open]", timeout=5000)
        assert f"{abs(state['table_position_m']) * 1e3:.2f} mm" in page.inner_text("#confirm-body")
        page.click("#confirm-ok")
        page.wait_for_selector("#mm-status[data-kind='ok']:has-text('completed')", timeout=30000)
        _, state = srv.call("GET", "/api/rig/state")
        assert abs(state["table_position_m"]) < 0.001, state
        status, rec = srv.call("POST", "/api/tests", sine_test(cycles=2, speed=4.0), token=True)
        assert status == 201, rec
        status, started = srv.call("POST", f"/api/tests/{rec['id']}/start", token=True)
        assert status == 200, started
        page.wait_for_function(f"window.__isorig.testId === {rec['id']} && window.__isorig.samples > 200",
                               timeout=15000)
        srv.wait_status(rec["id"], {"completed"}, timeout_s=30)
        page.screenshot(path=str(artifacts / "dashboard_after_restart.png"))
        assert not watch.foreign(), watch.foreign()
        assert not watch.unexpected_errors(), watch.unexpected_errors()
    finally:
        context.close()
