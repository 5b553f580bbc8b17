"""Limits the operator sets, each with an action (issue 17, item 2), and the shipped protocols with the service's
figures of the motion in the confirmation (item 3): the limits and actions reach the record; an indicating limit
shows its indications while the test goes on; controlled-stop and valve-close trips say in the banner what was
done; the confirmation shows what the service's check says (and says so when it says nothing).
"""

from __future__ import annotations

import json
import re
import urllib.request

import numpy as np

from .harness import (
    OPERATOR,
    WAIT_MS,
    fill_identity,
    poll,
    record_checks,
    shots,
    sine_test,
    start_from_form,
    wait_start_enabled,
)


def _confirmation(page) -> str:
    """Open the confirmation and return its text (the dialog stays open)."""
    wait_start_enabled(page)
    page.click("#start")
    page.wait_for_selector("#confirm-dialog[open]", timeout=WAIT_MS)
    return page.inner_text("#confirm-body")


def test_limits_with_actions_reach_the_record_and_indications_show(server, open_page, artifacts):
    """A velocity limit that only indicates, a tracking limit that stops under control: both in the confirmation,
    the strip and the record; the test goes on past the velocity limit and completes, its indications counted
    near the margins (10 kept as events, every one in the record's summary) and listed in words."""
    page, _ = open_page(server.url + "/", width=1366, height=768, login=OPERATOR)
    fill_identity(page, "LIM-1")
    page.select_option("#f-isolator", "IUT_b")
    page.fill("#f-amplitude", "30")
    page.fill("#f-frequency", "0.5")
    page.fill("#f-cycles", "6")
    page.fill("#f-speed", "2")
    # every limit has an action, the default valve close; the choices are the service's, each explained
    for key in ("displacement", "force", "velocity", "pressure", "tracking"):
        assert page.input_value(f"#f-act_{key}") == "valve_close", key
    options = page.eval_on_selector_all("#f-act_velocity option", "els => els.map(e => e.value)")
    assert options == ["valve_close", "controlled_stop", "indicate"], options
    help_text = page.inner_text("#limit-actions-help")
    assert "indicate an event is recorded, the test goes on" in help_text, help_text
    page.fill("#f-lim_velocity", "50")
    page.select_option("#f-act_velocity", "indicate")
    page.select_option("#f-act_tracking", "controlled_stop")
    assert page.get_attribute(".limit-row[data-limit='velocity_m_per_s']", "data-action") == "indicate"
    next_limits = page.inner_text("#s-limits")  # the strip: the limits the next test would get
    assert "indicate: |v| 50 mm/s" in next_limits and "controlled stop: |y-r| 50 mm" in next_limits, next_limits

    summary = _confirmation(page)
    assert re.search(r"velocity \|v\|\s+50 mm/s\s+indicate", summary), summary
    assert re.search(r"tracking error \|y-r\|\s+50 mm\s+controlled stop", summary), summary
    assert re.search(r"displacement \|d\|\s+150 mm\s+valve close", summary), summary
    warnings = page.inner_text("#confirm-body .warnings")
    assert "|v| 50 mm/s only indicates" in warnings and "exceeds |v| every cycle" in warnings, warnings
    assert page.is_disabled("#confirm-ok")  # the indicating limit must be ticked
    page.click("#confirm-cancel")
    start_from_form(page)
    page.wait_for_selector("#rig-status[data-status='running']", timeout=WAIT_MS)
    test_id = page.evaluate("window.__isorig.testId")

    rec = server.call("GET", f"/api/tests/{test_id}")[1]
    assert rec["limits"]["velocity_m_per_s"] == 0.05, rec["limits"]
    assert rec["limits"]["actions"] == {"displacement_m": "valve_close", "force_n": "valve_close",
                                        "velocity_m_per_s": "indicate", "load_pressure_pa": "valve_close",
                                        "tracking_error_m": "controlled_stop"}, rec["limits"]
    # the strip's limits come with the test's record, which the page asks for once it hears the test run
    strip = poll(lambda: (lambda t: t if "indicate: |v| 50 mm/s" in t else None)(page.inner_text("#s-limits")), 10,
                 "the strip's limits", shown=lambda: page.inner_text("#s-limits"))
    assert "controlled stop: |y-r| 50 mm" in strip, strip

    # indications while the test goes on: counted near the margins, in words in the events
    count = page.locator(".margin[data-limit='velocity_m_per_s'] .ma")
    poll(lambda: int(count.get_attribute("data-count") or 0) >= 2, 10, "two indications counted")
    assert re.fullmatch(r"indicated \d+\+?\u00d7", count.inner_text()), count.inner_text()
    assert page.get_attribute(".margin[data-limit='tracking_error_m']", "data-action") == "controlled_stop"
    events = page.inner_text("#live-events")
    assert re.search(r"LIMIT INDICATED: velocity [\d.]+ mm/s beyond the limit of 50 mm/s; the test goes on "
                     r"\(indication 1\)", events), events
    assert page.get_attribute("#rig-status", "data-status") == "running"
    if page.is_visible("#alert"):  # an earlier test's end
        page.click("#alert-close")
    shots(page, artifacts, "dashboard_limits_indicate")

    rec = server.wait_status(test_id, {"completed"}, timeout_s=40)  # the velocity limit did not stop it
    total = rec["summary"]["limit_indications"]["velocity_m_per_s"]
    kept = [e for e in rec["events"] if e["kind"] == "limit_indicate"]
    assert total >= 2 and len(kept) == min(total, 10), (total, len(kept))
    # once ended, the count is the record's (every excursion, also those beyond the 10 kept as events)
    poll(lambda: count.inner_text() == f"indicated {total}\u00d7", 10, f"the record's count {total}")
    assert page.locator("#live-events li.limit_indicate").count() == len(kept)

    # the test page: limits grouped by action, how often each indicating limit was exceeded, the events
    page.goto(f"{server.url}/?viewer=off#/tests/{test_id}")
    page.wait_for_selector("#t-events li.limit_indicate", timeout=WAIT_MS)
    summary = page.inner_text("#t-summary")
    assert "indicate: |v| 50 mm/s" in summary and "controlled stop: |y-r| 50 mm" in summary, summary
    assert f"|v| {total} times" in summary, summary


def test_trips_say_which_action_was_taken(server, open_page, artifacts):
    """A controlled-stop trip: the target brakes to rest, the banner says so; a valve-close limit tripping during
    that controlled stop closes the valve, and the banner says both."""
    page, _ = open_page(server.url + "/", width=1920, height=1080)
    page.wait_for_selector("#conn.conn-up", timeout=WAIT_MS)

    # no taper-in: the target starts at its top speed, so the velocity limit trips at once, moving outwards
    body = sine_test(cycles=10, speed=2.0, taper_cycles=0)
    body["limits"] = {"velocity_m_per_s": 0.08, "actions": {"velocity_m_per_s": "controlled_stop"}}
    test_id = server.start_test(body)
    rec = server.wait_status(test_id, {"aborted"}, timeout_s=30)
    assert rec["reason"].startswith("velocity limit tripped (controlled stop)"), rec["reason"]
    page.wait_for_selector("#rig-status[data-status='aborted']", timeout=WAIT_MS)
    page.wait_for_function("document.getElementById('alert-text').textContent.includes('ABORTED')", timeout=WAIT_MS)
    banner = page.inner_text("#alert-text")
    assert re.fullmatch(rf"LIMIT TRIP - Test {test_id} ABORTED: velocity [\d.]+ mm/s beyond the limit of 80 mm/s; "
                        r"controlled stop: the target brakes to rest within every displacement limit and holds there "
                        r"under control, the test ends aborted", banner), banner
    assert page.get_attribute("#alert", "data-kind") == "bad"

    # that controlled stop braked the table to rest off zero: where it rests, no test starts until it is zeroed
    page.wait_for_selector("#rig-warning[data-state='off-zero']", timeout=WAIT_MS)
    with urllib.request.urlopen(f"{server.url}/api/tests/{test_id}/data.csv", timeout=30) as r:
        lines = r.read().decode().splitlines()
    header = lines[0].split(",")
    rows = np.array([[float(x or "nan") for x in line.split(",")] for line in lines[1:]])
    t_trip = [e for e in rec["events"] if e["kind"] == "limit_trip"][0]["time_s"]
    braking = rows[:, header.index("time_s")] > t_trip
    force = np.abs(rows[:, header.index("force_n")])
    at_trip, peak = force[np.flatnonzero(braking)[0]], force[braking].max()
    assert peak > at_trip  # the brake went on outwards from where the velocity tripped
    server.zero_table()
    # the same test and trip, with a force limit (valve close) that the brake passes on its way to rest
    body["limits"] = {"velocity_m_per_s": 0.08, "force_n": 0.5 * (at_trip + peak),
                      "actions": {"velocity_m_per_s": "controlled_stop"}}  # force: valve close
    test_id = server.start_test(body)
    rec = server.wait_status(test_id, {"aborted"}, timeout_s=30)
    trips = [e["values"] for e in rec["events"] if e["kind"] == "limit_trip"]
    assert [t["action"] for t in trips] == ["controlled_stop", "valve_close"] and trips[1]["escalation"], trips
    page.wait_for_function("document.getElementById('alert-text').textContent"
                           f".startsWith('LIMIT TRIP - Test {test_id}')", timeout=WAIT_MS)
    banner = page.inner_text("#alert-text")
    assert "velocity" in banner and "controlled stop: the target brakes to rest" in banner, banner
    assert re.search(r"then, during the controlled stop: force [\d.]+ kN beyond the limit of [\d.]+ kN; "
                     r"valve close: the valve closes now", banner), banner
    events = page.inner_text("#live-events")
    assert "LIMIT TRIP during the controlled stop: force" in events, events
    assert "{" not in events and "escalation" not in events, events  # words, no internals
    page.screenshot(path=str(artifacts / "dashboard_limit_escalation_1920x1080.png"))
    # the valve closed mid-stroke: the table rests off zero, where no test may start
    page.wait_for_selector("#rig-warning[data-state='off-zero']", timeout=WAIT_MS)
    assert f"where test {test_id} left it" in page.inner_text("#rig-warning")
    assert page.is_disabled("#start") and "the table at zero" in page.inner_text("#start-why")


def test_protocols_listed_and_the_confirmation_uses_the_services_figures(server, open_page, artifacts):
    """The shipped protocols from GET /api/protocols with their duration; the chosen one's title and levels; the
    confirmation shows the figures of the service's check (peak displacement, velocity, force, duration), and
    says when the service gave none."""
    page, watch = open_page(server.url + "/", width=1920, height=1080, login=OPERATOR)
    _, protocols = server.call("GET", "/api/protocols")
    assert len(protocols) >= 2
    options = page.eval_on_selector_all("#f-profile option", "els => els.map(e => [e.value, e.textContent])")
    for p in protocols:
        minutes, seconds = divmod(round(p["duration_s"]), 60)
        text = dict(options)[f"protocol:{p['name']}"]
        assert text == f"protocol {p['name']} ({minutes}:{seconds:02d}, {p['cycles_total']} cycles)", text
    quick = next(p for p in protocols if p["name"] == "quick_check")
    fill_identity(page, "PROT-1")
    page.select_option("#f-isolator", "IUT_b")
    page.select_option("#f-profile", "protocol:quick_check")
    assert page.is_hidden("#sine-fields")
    info = page.inner_text("#protocol-info")
    assert quick["title"] in info and quick["description"] in info, info
    rows = page.locator("#protocol-info .protocol-levels tr")
    assert rows.count() == 1 + len(quick["levels"])  # a header and one row per level
    assert re.search(r"10\.00 mm\s+1 Hz\s+3 \+1\+1\s+0:05", rows.nth(1).inner_text()), rows.nth(1).inner_text()
    box = page.locator("#protocol-info")  # the whole table in view, no column cut (the panel does not scroll it)
    assert box.evaluate("e => e.scrollWidth <= e.clientWidth + 1"), box.evaluate("e => [e.scrollWidth, e.clientWidth]")
    assert "duration 0:10 (test time)" in info and "peak \u00b120.00 mm, 125.7 mm/s" in info, info
    page.locator("#protocol-info").screenshot(path=str(artifacts / "dashboard_protocol_1920x1080.png"))

    # the confirmation: the service's figures for exactly this set-up
    record_checks(page)
    page.fill("#f-supply", "80")  # a change: a new check, recorded
    poll(lambda: page.evaluate("window.__checkAnswers.length") >= 1, 10, "the envelope check's answer")
    answer = page.evaluate("window.__checkAnswers[window.__checkAnswers.length - 1]")
    assert answer["ok"] and answer["duration_s"] == 10.0, answer
    summary = _confirmation(page)
    force = f"about {answer['peak_force_n'] / 1e3:.3g} kN"
    for what in ("protocol quick_check", "\u00b120.00 mm", "125.7 mm/s", force, "the service's upper estimate",
                 "0:10", "10 cycles"):
        assert what in summary, (what, summary)
    assert "worked out in this console" not in summary
    page.screenshot(path=str(artifacts / "dashboard_confirm_protocol_1920x1080.png"))
    page.click("#confirm-cancel")

    # figures that differ from anything the console could work out: shown as the service gives them
    def altered(route):
        data = route.fetch().json()
        if data.get("ok"):
            data.update(peak_force_n=12345.0, duration_s=99.0, cycles_total=77)
        route.fulfill(status=200, content_type="application/json", body=json.dumps(data))

    page.route("**/api/tests/check", altered)
    page.fill("#f-supply", "81")
    wait_start_enabled(page)
    summary = _confirmation(page)
    assert "about 12.3 kN" in summary and "1:39" in summary and "77 cycles" in summary, summary
    page.click("#confirm-cancel")
    page.unroute("**/api/tests/check")

    # a service whose check gives no figures: displacement, velocity and duration from the motion, said so
    def bare(route):
        data = route.fetch().json()
        for key in ("peak_displacement_m", "peak_velocity_m_per_s", "peak_force_n", "duration_s", "cycles_total"):
            data.pop(key, None)
        route.fulfill(status=200, content_type="application/json", body=json.dumps(data))

    page.route("**/api/tests/check", bare)
    page.select_option("#f-profile", "sine")
    page.fill("#f-amplitude", "25")
    page.fill("#f-frequency", "0.5")
    page.fill("#f-cycles", "5")
    summary = _confirmation(page)
    assert "\u00b125.00 mm" in summary and "78.5 mm/s" in summary and "0:10" in summary, summary
    assert "worked out in this console" in summary and "the service's check gave no force estimate" in summary, summary
    page.click("#confirm-cancel")
    page.unroute("**/api/tests/check")
    assert not watch.unexpected_errors()


def test_a_protocol_tests_page_says_its_verdict_and_its_levels(server, open_page, artifacts):
    """quick_check run to its end: History shows PASSED beside the status and no mean over the levels; the test
    page has the verdict, the checks, the rules and one row per level (amplitude, steady cycles, K_eff) as
    GET .../acceptance gives them. The same protocol with a tolerance no isolator keeps (0.001 %) FAILS, naming
    the rule and its cycles."""
    import json
    from pathlib import Path

    strict = json.loads(Path("sim/protocol_data/quick_check.json").read_text())
    strict["name"] = "quick_check_strict"
    for rule in strict["acceptance"]:
        rule["tolerance_fraction"] = 1e-5
    ids = {}
    for name, profile in (("passed", {"kind": "protocol", "name": "quick_check"}),
                          ("failed", {"kind": "protocol", "protocol": strict})):
        server.zero_table()
        ids[name] = server.start_test({"isolator": "IUT_b", "supply_bar": 100, "speed": 10.0, "profile": profile})
        server.wait_status(ids[name], {"completed"}, timeout_s=60)
    page, _ = open_page(server.url + "/#/history", width=1366, height=768)
    row = page.locator(f"#history-table tr[data-id='{ids['passed']}']")
    row.wait_for(timeout=WAIT_MS)
    assert "PASSED" in row.inner_text() and "by level (test page)" in row.inner_text(), row.inner_text()
    assert "FAILED" in page.locator(f"#history-table tr[data-id='{ids['failed']}']").inner_text()

    acc = server.call("GET", f"/api/tests/{ids['passed']}/acceptance")[1]
    page.goto(f"{server.url}/?viewer=off#/tests/{ids['passed']}")
    page.wait_for_selector("#t-acc:not(.hidden) #t-acc-levels tbody tr", timeout=WAIT_MS)
    assert page.inner_text("#t-acc-verdict") == "PASSED" and acc["verdict"] == "PASSED"
    assert page.inner_text("#t-acc-note").startswith(f"{acc['summary']['verdicts']} checks on ")
    assert page.locator("#t-acc-rules li").count() == len(acc["rules"]) == 2
    levels = page.locator("#t-acc-levels tbody tr")
    assert levels.count() == 2
    first = levels.nth(0).inner_text()
    k_eff = acc["levels"][0]["means"]["k_eff_n_per_m"]
    assert "10.00 mm" in first and f"{k_eff / 1e6:.3f} kN/mm"[:5] in first, (first, k_eff)
    assert "mean K_eff" not in page.inner_text("#t-summary") and "PASSED (0 of" in page.inner_text("#t-summary")
    cycles = page.locator("#t-cycles tbody tr")  # ramp cycles marked (quick_check: 1 + 3 + 1 per level)
    assert cycles.nth(0).inner_text().startswith("1 (ramp-in)")
    assert cycles.nth(4).inner_text().startswith("5 (ramp-out)")
    assert cycles.nth(1).inner_text().split()[0] == "2" and "ramp-cycle" in cycles.nth(0).get_attribute("class")
    page.screenshot(path=str(artifacts / "dashboard_protocol_test_page_1366x768.png"), full_page=True)

    page.goto(f"{server.url}/?viewer=off#/tests/{ids['failed']}")
    page.wait_for_selector("#t-acc-verdict.unmet", timeout=WAIT_MS)
    assert page.inner_text("#t-acc-verdict") == "FAILED"
    failed = page.inner_text("#t-acc-failed")
    assert "keff_vs_3rd_cycle:" in failed and "cycle(s)" in failed, failed
