"""Protocols scaled to the specimen in the console (issue 23, part 1): the EN 15129 protocols' levels are
fractions of the design displacement d_bd, run at the specimen's design frequency; the console takes the
specimen's d_bd and frequency, shows the levels in mm and Hz before Start, sends design_displacement_m and
frequency_hz, and the test's acceptance levels follow them."""

from __future__ import annotations

import pytest

from .harness import OPERATOR, VIEWPORTS, WAIT_MS, fill_identity, poll, record_checks, start_from_form, started_test_id


@pytest.mark.parametrize("viewport", VIEWPORTS, ids=lambda v: f"{v[0]}x{v[1]}")
def test_en15129_levels_follow_the_design_displacement(server, open_page, artifacts, viewport):
    width, height = viewport
    page, _ = open_page(server.url + "/", width=width, height=height, login=OPERATOR)
    record_checks(page)
    fill_identity(page, "I23-DBD")
    page.select_option("#f-isolator", "IUT_b")
    page.fill("#f-supply", "70")
    page.fill("#f-speed", "10")
    assert page.is_hidden("#design-displacement-row")  # a sine has none
    page.select_option("#f-profile", "protocol:en15129_type_test")
    assert page.is_visible("#design-displacement-row")
    assert page.inner_text("[data-field='design_displacement'] .range") == "above 0, up to 150 mm; empty: 20 mm"
    amplitudes = lambda: page.eval_on_selector_all(  # noqa: E731 - the levels table's amplitude column
        "#protocol-info .protocol-levels tr td:nth-child(2)", "tds => tds.map(t => t.textContent)")
    assert amplitudes() == ["5.00 mm", "10.00 mm", "13.40 mm", "20.00 mm"]  # the protocol's own 20 mm
    page.fill("#f-design_displacement", "30")
    poll(lambda: amplitudes() == ["7.50 mm", "15.00 mm", "20.10 mm", "30.00 mm"], 5, "the levels scaled to 30 mm")
    total = page.inner_text("#protocol-info .protocol-total")
    assert "peak \u00b130.00 mm, 94.2 mm/s; design displacement d_bd 30.00 mm (entered" in total, total
    assert "frequency 0.5 Hz (the protocol's)" in total, total
    # the specimen's design frequency: every level at it, the velocity and the duration with it
    assert page.is_visible("#design-frequency-row")
    assert page.inner_text("[data-field='design_frequency'] .range").endswith("; empty: 0.5 Hz")
    frequencies = lambda: page.eval_on_selector_all(  # noqa: E731 - the levels table's frequency column
        "#protocol-info .protocol-levels tr td:nth-child(3)", "tds => tds.map(t => t.textContent)")
    assert frequencies() == ["0.5 Hz"] * 4
    page.fill("#f-design_frequency", "0.25")
    poll(lambda: frequencies() == ["0.25 Hz"] * 4, 5, "every level at 0.25 Hz")
    total = page.inner_text("#protocol-info .protocol-total")
    assert "peak \u00b130.00 mm, 47.1 mm/s" in total and "frequency 0.25 Hz (entered: every level)" in total, total
    assert "duration 1:20" in total, total  # 20 cycles at 0.25 Hz (40 s at the protocol's 0.5 Hz)
    body = poll(lambda: (lambda c: c if c and c["profile"].get("frequency_hz") == 0.25 else None)(
        page.evaluate("window.__checks.length ? window.__checks[window.__checks.length - 1] : null")), 10,
        "a check with design_displacement_m 0.03 and frequency_hz 0.25")
    assert body["profile"] == {"kind": "protocol", "name": "en15129_type_test", "design_displacement_m": 0.03,
                               "frequency_hz": 0.25}
    page.wait_for_selector("#envelope[data-state='ok']", timeout=WAIT_MS)
    page.locator("#design-frequency-row").scroll_into_view_if_needed()
    page.screenshot(path=str(artifacts / f"i23_protocol_scaled_{width}x{height}.png"))
    if width != 1366:
        return  # one run of the protocol is enough: the wider viewport checks the form only
    summary = start_from_form(page)
    assert "protocol en15129_type_test, d_bd 30.00 mm (entered), at 0.25 Hz (entered)" in summary, summary
    levels = "7.50 mm at 0.25 Hz x 3, 15.00 mm at 0.25 Hz x 3, 20.10 mm at 0.25 Hz x 3, 30.00 mm at 0.25 Hz x 3"
    assert levels in summary, summary
    page.wait_for_function("location.hash === '#/live'", timeout=WAIT_MS)
    test_id = started_test_id(page)  # not the live view's id at once: the session's previous test for a moment
    rec = server.wait_status(test_id, {"completed"}, timeout_s=90)
    assert rec["profile"]["design_displacement_m"] == 0.03 and rec["profile"]["frequency_hz"] == 0.25, rec["profile"]
    assert {b["frequency_hz"] for b in rec["scenario"]["profile"]} == {0.25} and rec["duration_s"] == 80.0
    _, acceptance = server.call("GET", f"/api/tests/{test_id}/acceptance")
    levels = [round(lv["amplitude_m"], 6) for lv in acceptance["levels"]]
    assert levels == [0.0075, 0.015, 0.0201, 0.03], acceptance["levels"]
    # the test page's acceptance levels and the report follow the specimen's d_bd, at both viewports
    page.goto(f"{server.url}/#/tests/{test_id}")
    shown = lambda: page.eval_on_selector_all(  # noqa: E731 - the test page's level table: amplitude, frequency
        "#t-acc-levels tbody tr", "trs => trs.map(r => [r.cells[1].textContent, r.cells[2].textContent])")
    for width, height in reversed(VIEWPORTS):
        page.set_viewport_size({"width": width, "height": height})
        poll(lambda: shown() == [["7.50 mm", "0.25 Hz"], ["15.00 mm", "0.25 Hz"], ["20.10 mm", "0.25 Hz"],
                                 ["30.00 mm", "0.25 Hz"]], 10, f"the levels on the test page at {width}x{height}")
        assert page.locator("#t-acc-levels").is_visible()
        page.locator("#t-acc-levels").scroll_into_view_if_needed()
        page.screenshot(path=str(artifacts / f"i23_protocol_scaled_test_page_{width}x{height}.png"))
    _, report = server.call("GET", f"/api/tests/{test_id}/report.json")
    assert [(round(lv["amplitude_m"], 6), lv["frequency_hz"]) for lv in report["headline"]["levels"]] == [
        (0.0075, 0.25), (0.015, 0.25), (0.0201, 0.25), (0.03, 0.25)], report["headline"]["levels"]
    assert report["acceptance"]["protocol"] == "en15129_type_test" and report["acceptance"]["verdicts"]
