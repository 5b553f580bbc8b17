"""Earthquake tests from the console (issue 16): a time history from a shipped ground motion run to completion with
the whole record drawn; a hybrid simulation with its storey drifts and the stability monitor, and a monitor that
trips; a set-up beyond the envelope refused in words (which sample, which limit), CSV records read with their unit
said, bad files refused with their line. At 1366x768 and 1920x1080 (screenshots at both sizes).
"""

from __future__ import annotations

import math
import re

import pytest

from .harness import OPERATOR, WAIT_MS, BusyPool, fill_identity, poll, shots, start_from_form, wait_start_enabled


def _earthquake_plots(page) -> dict:
    return page.evaluate("window.__isorigPlots().earthquake")


def _criteria_on_the_test_page(server, page, test_id: int) -> dict:
    """The test page's J criteria: one row per verdict of GET /api/tests/{id}/earthquake, its value (4 digits),
    bound and verdict; returns that answer."""
    page.wait_for_selector("#t-eq:not(.hidden) #t-eq-criteria tbody tr", timeout=WAIT_MS)
    eq = server.call("GET", f"/api/tests/{test_id}/earthquake?points=200")[1]
    verdicts = eq["record"]["verdicts"]
    rows = page.locator("#t-eq-criteria tbody tr")
    assert rows.count() == len(verdicts)
    for k, v in enumerate(verdicts):
        cells = [rows.nth(k).locator("td").nth(c).inner_text() for c in range(5)]
        assert cells[0] == v["name"] and cells[1] == v["meaning"] and cells[3] == v["bound"], cells
        value, unit = cells[2].split()
        assert unit == v["unit"] and float(value) == pytest.approx(v["value"], rel=6e-4, abs=1e-9), (cells, v)
        assert cells[4] == ("met" if v["met"] else "NOT met"), cells
    return eq


def _envelope(page, state: str, contains: str = "", timeout_s: float = 20) -> str:
    """The envelope box once it says `state` (and `contains`): the service's answer for the set-up now."""
    page.wait_for_selector(f"#envelope[data-state='{state}']", timeout=timeout_s * 1000)  # 'checking' till then
    return poll(lambda: (lambda t: t if contains in t else None)(page.inner_text("#envelope")), timeout_s,
                 f"the envelope box saying {contains!r}")


def _set_up(page, isolator="IUT_a", supply="100", speed="10"):
    fill_identity(page, "EQ-SPEC-1")
    page.select_option("#f-isolator", isolator)
    page.fill("#f-supply", supply)
    page.fill("#f-speed", speed)


def _mm(value_m: float) -> str:
    return f"{value_m * 1e3:.2f} mm"


def test_time_history_from_a_preset_runs_to_completion(server, open_page, artifacts):
    """1920x1080: near_field_short x 0.5 on IUT_a at speed 10: the fields say their units and ranges, the
    confirmation has the service's figures for exactly this profile, the whole record is drawn (planned target and
    measured) while it runs and to its end, the loop and the displacement plots fill, History names the kind."""
    page, _ = open_page(server.url + "/", width=1920, height=1080, login=OPERATOR)
    _set_up(page)
    page.select_option("#f-profile", "history")
    assert page.is_hidden("#sine-fields") and page.is_visible("#eq-fields") and page.is_hidden("#hy-fields")
    page.select_option("#f-eq_source", "preset")
    page.select_option("#f-eq_preset", "near_field_short")
    page.fill("#f-eq_scale", "0,5")  # a decimal comma, read as one and said
    assert page.inner_text("[data-field='eq_scale'] .msg") == "read as 0.5"
    assert "above 0, up to 10" in page.inner_text("[data-field='eq_scale'] .range")
    assert page.inner_text("[data-field='eq_taper_in'] .unit") == "(s)"
    assert "0 to 600 s; empty: 0.5 s" in page.inner_text("[data-field='eq_taper_in'] .range")
    assert page.inner_text("[data-field='eq_mass'] .unit") == "(kg)"
    assert "empty: the vertical load / g" in page.inner_text("[data-field='eq_mass'] .range")
    assert "Within the rig envelope" in _envelope(page, "ok")

    body = {"isolator": "IUT_a", "supply_bar": 100, "speed": 10,
            "profile": {"kind": "history", "ground_motion": "near_field_short", "scale": 0.5}}
    check = server.call("POST", "/api/tests/check", body)[1]
    assert check["ok"] is True, check
    summary = start_from_form(page)
    assert "time history: ground motion near_field_short x 0.5" in summary, summary
    assert f"\u00b1{_mm(check['peak_displacement_m'])}" in summary, summary
    assert f"{check['peak_velocity_m_per_s'] * 1e3:.1f} mm/s" in summary, summary
    assert f"about {check['peak_force_n'] / 1e3:.1f} kN" in summary or "peak force (estimate)" in summary, summary
    assert "0:15" in summary and "wall time at 10x" in summary, summary
    assert "0 cycles" not in summary, summary
    page.wait_for_selector("#rig-status[data-status='running']", timeout=WAIT_MS)
    test_id = page.evaluate("window.__isorig.testId")
    page.wait_for_selector("#eq-panel:not(.hidden)", timeout=WAIT_MS)  # once the record of the running test came
    assert page.is_hidden("#stab-card") and page.is_hidden("#hy-drift-panel")
    poll(lambda: page.inner_text("#l-cycle") == "none (a time history)", 10, "the header saying there are no cycles")
    assert "time history: near_field_short x 0.5" in page.inner_text("#l-profile")
    plots = poll(lambda: (lambda d: d if d["plannedLoaded"] and d["filled"] > 100 else None)(_earthquake_plots(page)),
                  20, "the planned target and measured samples in the whole-record plot")
    assert [s["label"] for s in plots["plots"]["overview"]["series"]] == ["planned target", "measured y"], plots
    assert plots["plots"]["overview"]["x"] == "test time (s)" and plots["plots"]["overview"]["y"] == "displacement (mm)"
    if page.is_visible("#alert"):
        page.click("#alert-close")
    shots(page, artifacts, "dashboard_earthquake_history")

    rec = server.wait_status(test_id, {"completed"}, timeout_s=60)
    assert rec["profile"]["kind"] == "history" and rec["profile"]["ground_motion"]["preset"] == "near_field_short"
    assert rec["specimen_id"] == "EQ-SPEC-1" and rec["speed"] == 10
    page.wait_for_selector("#rig-status[data-status='completed']", timeout=WAIT_MS)
    # the whole record was drawn, to its end
    plots = poll(lambda: (lambda d: d if d["filled"] >= 0.97 * d["points"] else None)(_earthquake_plots(page)),
                  10, "the whole record drawn")
    assert page.evaluate("window.__isorig.loopPoints") > 0 or page.evaluate("window.__isorig.loopCycles") > 0
    # a page opened after the end draws the whole record too, not only what the stream still holds
    late, _ = open_page(server.url + "/", width=1366, height=768, login=OPERATOR)
    poll(lambda: (lambda d: d if d["plannedLoaded"] and d["firstMeasuredS"] is not None and d["firstMeasuredS"] < 0.5
                  and d["filled"] >= 0.97 * d["points"] else None)(_earthquake_plots(late)),
         15, "the whole record drawn on a page opened after the end")
    late.close()

    # History: the kind of test; its page: the profile, the report link
    page.goto(f"{server.url}/?viewer=off#/history")
    row = page.locator(f"#history-table tr[data-id='{test_id}']")
    row.wait_for(timeout=WAIT_MS)
    assert "time history: near_field_short x 0.5 (0:15)" in row.inner_text(), row.inner_text()
    row.click()
    page.wait_for_selector("#t-summary .kv", timeout=WAIT_MS)
    assert "time history: near_field_short x 0.5" in page.inner_text("#t-summary")
    assert page.is_visible("#t-pdf") and page.get_attribute("#t-pdf", "href") == f"/api/tests/{test_id}/report.pdf"
    # its J criteria with their verdicts, and the measured displacement over the target
    eq = _criteria_on_the_test_page(server, page, test_id)
    assert [v["name"] for v in eq["record"]["verdicts"]] == ["J1", "J2", "J3"]
    assert "judged on the whole record" in page.inner_text("#t-eq-judged")
    plot = page.evaluate("window.__isorigEqRecord()")
    assert [s["label"] for s in plot["series"]] == ["target r", "measured y"] and plot["y"] == "displacement (mm)"
    assert [s["label"] for s in plot["difference"]["series"]] == ["y - r"]
    assert "no cycles: an earthquake test is judged by its J criteria" in page.inner_text("#t-cycles")
    assert page.is_hidden("#t-eq-peaks")
    shots(page, artifacts, "dashboard_earthquake_test_page", full_page=True)

    # while the service's check pool is busy (503 with Retry-After), the page says so and asks again
    busy = BusyPool(3, retry_after_s=1, what="rebuild an earthquake test's figures")
    figures = re.compile(rf"/api/tests/{test_id}/earthquake\?")
    page.route(figures, busy)
    page.reload()
    page.wait_for_function("() => /the service is busy with other checks: asking again for the figures in 1 s/"
                           ".test(document.getElementById('t-eq-judged').textContent)", timeout=WAIT_MS)
    assert _criteria_on_the_test_page(server, page, test_id)["record"]["verdicts"] == eq["record"]["verdicts"]
    assert len(busy.refused_at) == 3 and "judged on the whole record" in page.inner_text("#t-eq-judged")
    page.unroute(figures)


def test_hybrid_simulation_shows_drifts_and_the_stability_monitor(server, open_page, artifacts):
    """1366x768: the demo building on IUT_a under near_field_short x 0.6 (speed 10): units and ranges of the
    building's fields, the confirmation says the building, the prediction and the monitor's threshold; live: the
    storey drifts, the monitor's indicator against its threshold; it completes untripped. Then the same with a
    threshold of 0.5 J and 0.1 %: the monitor trips, shown in red with its reason, the banner says it."""
    page, _ = open_page(server.url + "/", width=1366, height=768, login=OPERATOR)
    _set_up(page)
    page.select_option("#f-profile", "hybrid")
    assert page.is_visible("#hy-fields") and page.is_hidden("#eq-history-only")
    assert page.is_disabled("#f-eq_source option[value='disp_csv']")
    page.click("#hy-demo")
    page.fill("#f-eq_scale", "0.6")
    assert page.input_value("#f-hy_base_mass") == "4000"
    assert page.inner_text("[data-field='hy_base_mass'] .unit") == "(kg)"
    assert page.input_value("#f-hy_k_0") == "8" and page.inner_text("[data-field='hy_k_0'] .unit") == "(kN/mm)"
    assert page.input_value("#f-hy_damping") == "5" and page.inner_text("[data-field='hy_damping'] .unit") == "(%)"
    assert page.locator(".storey-row").count() == 3
    assert "empty: 125.03 kN (the building's weight)" in page.inner_text("[data-field='vertical_load'] .range")
    assert "empty: 100 J" in page.inner_text("[data-field='hy_limit_j'] .range")
    # a bad storey mass is refused at the field, Start says which
    page.fill("#f-hy_m_1", "-5")
    assert "outside the allowed range" in page.inner_text("[data-field='hy_m_1'] .msg")
    poll(lambda: "hy m 1" in page.inner_text("#start-why"), 5, "Start naming the storey mass")
    assert page.is_disabled("#start")
    page.fill("#f-hy_m_1", "3000")
    assert "Within the rig envelope" in _envelope(page, "ok")

    summary = start_from_form(page)
    assert "hybrid simulation (RTHS)" in summary and "base 4000 kg + 3 storeys" in summary, summary
    assert "springs 8 kN/mm, 6 kN/mm, 4 kN/mm" in summary and "damping 5.00 %" in summary, summary
    assert "fixed-base periods 0.296, 0.12, 0.0794 s" in summary, summary
    assert "predicted base displacement" in summary and "ground motion near_field_short x 0.6" in summary, summary
    assert "trips at E_err > max(100 J, 50.00 % of the input energy)" in summary, summary
    page.wait_for_selector("#rig-status[data-status='running']", timeout=WAIT_MS)
    test_id = page.evaluate("window.__isorig.testId")
    page.wait_for_selector("#stab-card:not(.hidden)", timeout=WAIT_MS)
    assert page.is_visible("#hy-drift-panel") and page.is_visible("#hy-stab-panel")
    plots = poll(lambda: (lambda d: d if d["drifts"] > 50 and d["stabilityPoints"] > 3 else None)(
        _earthquake_plots(page)), 20, "drifts and the monitor's indicator")
    assert plots["driftNames"] == ["drift_1_m", "drift_2_m", "drift_3_m"], plots
    assert [s["label"] for s in plots["plots"]["drift"]["series"]] == ["storey 1", "storey 2", "storey 3"]
    assert plots["plots"]["drift"]["y"] == "storey drift (mm)"
    assert [s["label"] for s in plots["plots"]["stab"]["series"]] == ["E_err / limit", "trips at 1 (the limit)"]
    assert [s["label"] for s in plots["plots"]["overview"]["series"]] == [
        "predicted base displacement (reference)", "command r", "measured y"]
    assert re.fullmatch(r"-?\d+(\.\d)? %", page.inner_text("#stab-value")), page.inner_text("#stab-value")
    assert re.search(r"E_err -?[\d.]+ J of the limit [\d.]+ J; input energy [\d.]+ J; trips at 100 %",
                     page.inner_text("#stab-detail")), page.inner_text("#stab-detail")
    if page.is_visible("#alert"):
        page.click("#alert-close")
    shots(page, artifacts, "dashboard_earthquake_hybrid")
    rec = server.wait_status(test_id, {"completed"}, timeout_s=60)
    assert rec["profile"]["kind"] == "hybrid" and rec["summary"]["stability"]["tripped"] is False
    page.wait_for_selector("#rig-status[data-status='completed']", timeout=WAIT_MS)
    assert page.get_attribute("#stab-card", "data-level") in ("ok", "warn", "bad")
    # after the shaking the table rests and the valve is quiet (issue 23 part 3): the command this page received
    # over the test's last second, as the console drew it
    quiet = poll(lambda: (lambda v: {"std_v": v} if v is not None else None)(
        page.evaluate("window.__isorig.endCommandStdV")), 10, "the command's std over the last second")
    assert quiet["std_v"] < 0.05, quiet
    shots(page, artifacts, "dashboard_earthquake_hybrid_at_rest")

    # the same building with a threshold it cannot keep: the monitor trips, in red with its reason
    server.zero_table()  # the structure leaves the isolator's residual displacement
    page.wait_for_selector("#rig-warning.hidden", state="attached", timeout=WAIT_MS)
    page.fill("#f-hy_limit_j", "0,5")
    assert page.inner_text("[data-field='hy_limit_j'] .msg") == "read as 0.5 J"
    page.fill("#f-hy_relative", "0.1")
    _envelope(page, "ok")
    summary = start_from_form(page)
    assert "trips at E_err > max(0.5 J, 0.10 % of the input energy)" in summary, summary
    page.wait_for_selector("#rig-status[data-status='aborted']", timeout=30000)
    page.wait_for_selector("#stab-card[data-level='tripped']", timeout=WAIT_MS)
    assert page.inner_text("#stab-value") == "TRIPPED"
    detail = page.get_attribute("#stab-detail", "title")
    assert re.search(r"Tripped at t = [\d.]+ s: RTHS stability monitor: the tracking error added [\d.]+ J",
                     detail), detail
    banner = page.inner_text("#alert-text")
    assert "ABORTED" in banner and "RTHS stability monitor" in banner and "valve close" in banner, banner
    shots(page, artifacts, "dashboard_earthquake_hybrid_trip")
    server.zero_table()

    # the completed test's page: J1-J5, each channel's peak against the reference, the reference overlay
    page.goto(f"{server.url}/?viewer=off#/tests/{test_id}")
    eq = _criteria_on_the_test_page(server, page, test_id)
    assert [v["name"] for v in eq["record"]["verdicts"]] == ["J1", "J2", "J3", "J4", "J5"]
    peaks = page.locator("#t-eq-peaks tbody tr")
    assert peaks.count() == len(eq["record"]["structure"]["peaks"])
    first = peaks.nth(0).inner_text()
    assert first.startswith("base displacement") and first.count("mm") == 2 and first.endswith("%"), first
    assert re.search(r"\d+\.\d\d mm\s+\d+\.\d\d mm\s+-?\d+\.\d\d %$", first), first  # the console's digits
    plot = page.evaluate("window.__isorigEqRecord()")
    assert [s["label"] for s in plot["series"]] == ["reference base displacement (full-numerical)",
                                                    "command r (the hybrid test's base)", "measured y"], plot
    assert [s["label"] for s in plot["difference"]["series"]] == ["y - r", "r - reference (base displacement)"]
    assert plot["difference"]["y"] == "difference (mm)"
    shots(page, artifacts, "dashboard_earthquake_hybrid_test_page", full_page=True)


def test_refusals_and_records_are_said_in_words(server, open_page, artifacts, tmp_path):
    """1366x768: near_field_short x 1 on IUT_b at 100 bar is beyond the pump: the envelope box names the sample, its
    time and the limit, the scale is outlined, Start is disabled and says why; a lower scale fits. CSV records:
    a file in cm/s2 without a unit in its header is read as m/s2, said as assumed and warned about, and the
    service refuses it in words; choosing cm/s2 makes it fit; a header naming g against a chosen m/s2 is refused;
    a gap is refused with its line; a semicolon file with decimal commas is read. Nothing is created."""
    page, watch = open_page(server.url + "/", width=1366, height=768, login=OPERATOR)
    before = len(server.call("GET", "/api/tests")[1])
    _set_up(page, isolator="IUT_b")
    page.select_option("#f-profile", "history")
    page.select_option("#f-eq_preset", "near_field_short")
    page.fill("#f-eq_scale", "1")
    text = _envelope(page, "refused", "history sample")
    assert re.search(r"Refused: history sample \d+ at t = [\d.]+ s: velocity [\d.]+ m/s needs 313 l/min", text), text
    assert "lower the ground-motion scale" in text, text
    assert "invalid" in page.get_attribute("#f-eq_scale", "class")
    assert page.is_disabled("#start") and "a set-up within the rig envelope" in page.inner_text("#start-why")
    shots(page, artifacts, "dashboard_earthquake_refused")
    page.fill("#f-eq_scale", "0.3")
    _envelope(page, "ok")
    assert "invalid" not in (page.get_attribute("#f-eq_scale", "class") or "")

    # a ground motion in cm/s2 whose header names no unit
    rows = "\n".join(f"{k * 0.01:.2f},{80 * math.sin(6.283 * k * 0.01) * min(1, k / 100, (1000 - k) / 100):.4f}"
                     for k in range(1001))
    cms = tmp_path / "record_cms.csv"
    cms.write_text("# a record, no unit in the header\ntime_s,acceleration\n" + rows + "\n")
    page.select_option("#f-eq_source", "acc_csv")
    assert page.is_visible("#eq-unit-row")
    page.set_input_files("#f-eq_file", str(cms))
    note = page.locator("#eq-file-note")
    poll(lambda: "1001 rows" in note.inner_text(), 5, "the file read")
    assert "read as m/s2 (assumed: the header names no unit" in note.inner_text(), note.inner_text()
    assert "the wrong unit?" in note.inner_text() and note.get_attribute("class") == "msg warn"
    text = _envelope(page, "refused", "beyond any recorded ground motion")
    assert "Refused: " in text and "cm/s2" in text and "(assumed: no units given)" in text, text
    page.select_option("#f-eq_acc_unit", "cm/s2")
    poll(lambda: "read as cm/s2 (chosen)" in note.inner_text(), 5, "the unit chosen")
    _envelope(page, "ok")

    # the header says g, the operator chose m/s2: refused, nothing guessed
    g_file = tmp_path / "record_g.csv"
    g_file.write_text("time_s,acceleration_g\n" + "\n".join(f"{k * 0.01:.2f},{0.1 if k % 50 == 0 else 0.0}"
                                                            for k in range(200)))
    page.select_option("#f-eq_acc_unit", "m/s2")
    page.set_input_files("#f-eq_file", str(g_file))
    poll(lambda: "the file's header names g" in note.inner_text(), 5, "the unit conflict")
    assert page.is_disabled("#start") and "ground motion file" in page.inner_text("#start-why")

    # a PEER .AT2 file: read by the service's reader, in g; a truncated one is refused with its line
    at2 = tmp_path / "burst.AT2"
    values = [0.15 * math.sin(2 * math.pi * k * 0.01) * math.sin(math.pi * k / 300) ** 2 for k in range(300)]
    body = "\n".join("".join(f"{v:15.7E}" for v in values[i:i + 5]) for i in range(0, 300, 5))
    head = "PEER NGA STRONG MOTION DATABASE RECORD\nSYNTHETIC BURST, 1/1/2000, ISORIG, 000\n" \
           "ACCELERATION TIME HISTORY IN UNITS OF G\nNPTS=  {n}, DT=   .0100 SEC\n"
    at2.write_text(head.format(n=300) + body + "\n")
    busy = BusyPool(2, retry_after_s=2, what="read an .AT2 file")  # the check pool, which reads it, busy twice
    page.route("**/api/ground-motions/read-at2", busy)
    page.set_input_files("#f-eq_file", str(at2))  # the unit chosen is still m/s2
    poll(lambda: "a PEER .AT2 file is in g" in note.inner_text(), 5, "the .AT2 unit conflict")
    assert len(busy.refused_at) == 2
    page.unroute("**/api/ground-motions/read-at2")
    assert page.is_disabled("#start")
    page.select_option("#f-eq_acc_unit", "auto")
    poll(lambda: "300 values at 0.01 s" in note.inner_text(), 5, "the .AT2 file read")
    read = note.inner_text()
    assert "burst.AT2 (PEER .AT2: PEER NGA STRONG MOTION DATABASE RECORD, SYNTHETIC BURST" in read, read
    assert f"; peak {max(abs(v) for v in values):.4f} g, read as g (the .AT2 file's unit)" in read, read
    _envelope(page, "ok")
    shots(page, artifacts, "dashboard_earthquake_at2")
    cut = tmp_path / "cut.AT2"
    cut.write_text(head.format(n=400) + body + "\n")
    watch.allowed_status.add(422)
    page.set_input_files("#f-eq_file", str(cut))
    poll(lambda: "a truncated record" in note.inner_text(), 5, "the truncated .AT2 file")
    assert note.inner_text().startswith("cut.AT2: line 64: the file ends after 300 values but NPTS = 400"), \
        note.inner_text()
    assert page.is_disabled("#start") and "ground motion file" in page.inner_text("#start-why")

    # a displacement history with a gap: refused with its line
    gap = tmp_path / "gap.csv"
    lines = [f"{k * 0.01:.2f},{0.001 * k:.4f}" for k in range(40) if k not in (20, 21, 22)]
    gap.write_text("time_s,displacement_m\n" + "\n".join(lines) + "\n")
    page.select_option("#f-eq_source", "disp_csv")
    assert page.is_hidden("#eq-unit-row") and page.is_hidden("#eq-mass-row")
    page.set_input_files("#f-eq_file", str(gap))
    poll(lambda: "a gap" in note.inner_text(), 5, "the gap")
    assert "line 22: time steps from 0.19 s to 0.23 s" in note.inner_text(), note.inner_text()
    assert page.is_disabled("#start")

    # semicolons and decimal commas: read as decimals, said
    semi = tmp_path / "semi.csv"
    semi.write_text("time_s;displacement_m\n" + "\n".join(
        f"{k * 0.01:.2f};{0.01 * math.sin(math.pi * k / 200) ** 2:.5f}".replace(".", ",") for k in range(401)))
    page.set_input_files("#f-eq_file", str(semi))
    poll(lambda: "401 rows" in note.inner_text(), 5, "the semicolon file")
    read = note.inner_text()
    assert "decimal commas read as decimals" in read and "peak 10.00 mm" in read, read
    page.fill("#f-eq_scale", "2")
    assert "-100 to 100, not 0" in page.inner_text("[data-field='eq_scale'] .range")  # a negative one mirrors
    _envelope(page, "ok")
    wait_start_enabled(page)
    shots(page, artifacts, "dashboard_earthquake_csv")
    assert len(server.call("GET", "/api/tests")[1]) == before  # nothing was created
    watch.allowed_status.add(422)


def test_a_page_that_joins_a_running_history_late_draws_it_from_its_start(server, open_page):
    """A time history started by a script 12 s ago (speed 1): a page opened now draws the whole record so far,
    from t = 0 (the stored samples, GET /api/tests/{id}/earthquake `so_far`), not only the stream's last 10 s."""
    server.zero_table()
    body = {"isolator": "IUT_a", "supply_bar": 100, "speed": 1.0,
            "profile": {"kind": "history", "ground_motion": "far_field_long", "scale": 0.3}}
    test_id = server.start_test(body)
    try:
        poll(lambda: server.call("GET", f"/api/tests/{test_id}")[1]["samples_stored"] > 12000, 30,
             "12 s of the record stored")
        so_far = server.call("GET", f"/api/tests/{test_id}/earthquake?points=500")[1]
        assert so_far["status"] == "running" and so_far["record"] is None
        t = so_far["so_far"]["time_s"]
        assert t[0] == 0.0 and t[-1] > 11.9 and all(b > a for a, b in zip(t[:-1], t[1:], strict=True))
        assert len(t) <= 500 * t[-1] / 45 + 2  # at the planned series' step
        page, _ = open_page(server.url + "/", width=1366, height=768, login=OPERATOR)
        plots = poll(lambda: (lambda d: d if d["plannedLoaded"] and d["firstMeasuredS"] is not None
                              and d["firstMeasuredS"] < 0.5 else None)(_earthquake_plots(page)),
                     15, "the record drawn from its start")
        assert plots["filled"] > 0.25 * plots["points"], plots  # beyond 12 s of 45 s
    finally:
        server.call("POST", f"/api/tests/{test_id}/abort", token=True)
        server.wait_status(test_id, {"aborted", "completed"}, timeout_s=30)
        server.zero_table()
