"""Issue 34 item 1 in the console: the follow detector is in the limits list with its thresholds and its action
(controlled stop, the default, or indicate); set to indicate, the paper's controller runs to its end within the
limits, and the record and the test page say it was set to indicate."""

from __future__ import annotations

import re

from .harness import OPERATOR, WAIT_MS, fill_identity, poll, shots, start_from_form, wait_start_enabled


def test_the_follow_detector_is_a_limit_the_operator_sets_to_indicate(server, open_page, artifacts):
    page, _ = open_page(server.url + "/", width=1366, height=768, login=OPERATOR)
    fill_identity(page, "FOLLOW-1")
    assert page.input_value("#f-act_follow") == "controlled_stop"
    options = page.eval_on_selector_all("#f-act_follow option", "els => els.map(e => e.value)")
    assert options == ["controlled_stop", "indicate"]
    thresholds = page.inner_text("#follow-thresholds")
    assert "2 %" in thresholds and "1 %" in thresholds and "10 Hz" in thresholds, thresholds
    assert "follow detector" in page.inner_text("#limit-actions-help")

    # the paper's controller on IUT_a, 20 mm at 1 Hz: the tracking rule finds it 33 % off at 4 s
    page.select_option("#f-isolator", "IUT_a")
    page.select_option("#f-controller", "mrac")
    page.fill("#f-amplitude", "20")
    page.fill("#f-frequency", "1")
    page.fill("#f-cycles", "6")
    page.fill("#f-speed", "20")
    page.select_option("#f-act_follow", "indicate")
    assert page.get_attribute(".limit-row[data-limit='follow']", "data-action") == "indicate"
    page.locator("#limits").scroll_into_view_if_needed()
    shots(page, artifacts, "follow_limit_setup")
    assert "indicate: follow detector" in page.inner_text("#s-limits")

    wait_start_enabled(page, timeout_ms=120_000)  # the first check of an mrac test on a loaded machine
    summary = start_from_form(page)
    assert re.search(r"follow detector\s+oscillation: .*\s+indicate", summary), summary
    page.wait_for_selector("#rig-status[data-status='running']", timeout=WAIT_MS)
    test_id = page.evaluate("window.__isorig.testId")
    record = poll(lambda: (lambda r: r if r["status"] not in ("created", "running") else None)(
        server.call("GET", f"/api/tests/{test_id}")[1]), 60, "the test's end")
    assert record["status"] == "completed", record["reason"]
    assert record["limits"]["actions"]["follow"] == "indicate"
    assert record["summary"]["limit_indications"]["follow"] == 1

    page.goto(server.url + f"/?viewer=off#/tests/{test_id}")
    page.wait_for_selector(".tracking-verdict", timeout=WAIT_MS)
    text = page.inner_text("body")
    assert "indicate: follow detector" in text and "follow 1 time" in text, text
    assert "FOLLOW DETECTOR INDICATED" in text
    shots(page, artifacts, "follow_limit_test_page")
