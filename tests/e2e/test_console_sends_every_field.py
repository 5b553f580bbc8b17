"""The console sends every field the API takes (issue 23, part 6): a displacement history's negative scale (the
record mirrored), a ground motion's check_units: false (asked for in the confirmation), the test's label; and it
reads a move's position source, "end of move N", as the service now says it (and "end of test N" as before)."""

from __future__ import annotations

import math

import pytest

from .harness import OPERATOR, VIEWPORTS, WAIT_MS, fill_identity, poll, record_checks, wait_start_enabled


def _checked_with(page, predicate, what: str) -> dict:
    """The last envelope check's body once it satisfies `predicate`."""
    return poll(lambda: (lambda b: b if b and predicate(b) else None)(
        page.evaluate("window.__checks.length ? window.__checks[window.__checks.length - 1] : null")), 10, what)


def _history_set_up(page):
    fill_identity(page, "I23-FIELDS")
    page.select_option("#f-isolator", "IUT_a")
    page.fill("#f-supply", "100")
    page.fill("#f-speed", "10")
    page.select_option("#f-profile", "history")


@pytest.mark.parametrize("viewport", VIEWPORTS, ids=lambda v: f"{v[0]}x{v[1]}")
def test_negative_displacement_scale_check_units_and_label_are_sent(server, open_page, artifacts, viewport, tmp_path):
    width, height = viewport
    page, watch = open_page(server.url + "/", width=width, height=height, login=OPERATOR)
    record_checks(page)
    _history_set_up(page)
    page.fill("#f-label", "I23 mirrored record")

    # a displacement history scaled by -1.5: the record mirrored, sent as it is
    disp = tmp_path / "disp.csv"
    disp.write_text("time_s,displacement_m\n" + "\n".join(
        f"{k * 0.01:.2f},{0.01 * math.sin(math.pi * k / 200) ** 2:.5f}" for k in range(401)) + "\n")
    page.select_option("#f-eq_source", "disp_csv")
    page.set_input_files("#f-eq_file", str(disp))
    poll(lambda: "401 rows" in page.inner_text("#eq-file-note"), 10, "the displacement file read")
    assert "-100 to 100, not 0 (times the displacement; negative: the record mirrored)" in \
        page.inner_text("[data-field='eq_scale'] .range")
    page.fill("#f-eq_scale", "-1.5")
    body = _checked_with(page, lambda b: b["profile"].get("scale") == -1.5, "a check with the scale -1.5")
    assert body["label"] == "I23 mirrored record", body
    assert body["profile"]["displacement"]["displacement_m"][100] == pytest.approx(0.01)
    wait_start_enabled(page)
    assert page.get_attribute("#envelope", "data-state") == "ok", page.inner_text("#envelope")
    page.fill("#f-eq_scale", "0")
    poll(lambda: "not 0" in page.inner_text("[data-field='eq_scale'] .msg"), 5, "0 refused at the field")
    assert page.is_disabled("#start")
    page.fill("#f-eq_scale", "-101")
    poll(lambda: "outside the allowed range" in page.inner_text("[data-field='eq_scale'] .msg"), 5, "-101 refused")

    # a ground motion with a peak of 0.003 g: refused with the unit check, taken as read without it
    weak = tmp_path / "weak.csv"
    weak.write_text("time_s,acceleration_m_per_s2\n" + "\n".join(
        f"{k * 0.01:.2f},{0.03 * math.sin(2 * math.pi * k * 0.01) * math.sin(math.pi * k / 400) ** 2:.5f}"
        for k in range(401)) + "\n")
    page.select_option("#f-eq_source", "acc_csv")
    page.fill("#f-eq_scale", "1")
    assert page.is_visible("#f-eq_check_units") and page.is_checked("#f-eq_check_units")
    watch.allowed_status.add(422)
    page.set_input_files("#f-eq_file", str(weak))
    poll(lambda: "The service will refuse it" in page.inner_text("#eq-file-note"), 10, "the weak record warned")
    body = _checked_with(page, lambda b: isinstance(b["profile"].get("ground_motion"), dict), "a check with the record")
    assert "check_units" not in body["profile"]["ground_motion"], body["profile"]["ground_motion"].keys()
    page.wait_for_selector("#envelope[data-state='refused']", timeout=WAIT_MS)
    page.uncheck("#f-eq_check_units")
    poll(lambda: "Taken as read: the unit check is off" in page.inner_text("#eq-file-note"), 10, "the note")
    body = _checked_with(page, lambda b: (b["profile"].get("ground_motion") or {}).get("check_units") is False,
                         "a check with check_units false")
    wait_start_enabled(page)
    page.click("#start")
    page.wait_for_selector("#confirm-dialog[open]", timeout=WAIT_MS)
    warnings = page.inner_text("#confirm-dialog")
    assert "the ground motion's unit check is off (check_units: false): its peak of 0.00295 g" in warnings, warnings
    assert page.locator("#confirm-body .warning-tick").count() >= 1
    assert page.is_disabled("#confirm-ok")  # each warning needs its tick
    page.screenshot(path=str(artifacts / f"i23_check_units_off_{width}x{height}.png"))
    page.click("#confirm-cancel")
    page.check("#f-eq_check_units")
    _checked_with(page, lambda b: "check_units" not in (b["profile"].get("ground_motion") or {}), "the check back on")


def test_a_moves_position_source_is_read_as_a_move(server, open_page):
    """state.js reads "end of move N" (the service's words for a manual move's end) as it reads "end of test N":
    the source in words, and which is newer than the live stream's last run."""
    page, _ = open_page(server.url + "/", width=1366, height=768)
    out = page.evaluate("""async () => {
      const s = await import('/js/state.js');
      const words = [s.sourceWords('end of move 7 (completed)'), s.sourceWords('end of test 4 (stopped)'),
        s.sourceWords('the rig (probe)')];
      const runs = [s.endedRun('end of move 7 (completed)'), s.endedRun('end of test 4 (stopped)'), s.endedRun('live')];
      const keep = { rigState: s.state.rigState, position: s.state.position, conn: s.state.conn,
        helloSeen: s.state.helloSeen };
      s.state.conn = true; s.state.helloSeen = true;  // the stream says: nothing runs
      const move7 = 'end of move 7 (completed)';
      s.state.rigState = { status: 'idle', table_position_m: 0.001, position_source: move7,
        force_n: 10, force_source: move7, command_v: 0, command_source: move7 };
      s.state.position = { m: 0.002, testId: 6, live: false };  // an older run than move 7
      const older = s.tablePosition();
      const olderForce = s.rigReadings().force;
      s.state.position = { m: 0.002, testId: 8, live: false };  // a newer run than move 7: the answer is outdated
      const newer = s.tablePosition();
      const newerForce = s.rigReadings().force;
      Object.assign(s.state, keep);
      return { words, runs, older, olderForce, newer, newerForce };
    }""")
    assert out["words"] == ["where move 7 left it", "where test 4 left it", "the rig's reading"], out
    assert out["runs"] == [{"kind": "move", "id": 7}, {"kind": "test", "id": 4}, None], out
    assert out["older"] == {"m": 0.001, "source": "end of move 7 (completed)"}, out
    assert out["olderForce"] == {"value": 10, "source": "end of move 7 (completed)"}, out
    assert out["newer"]["m"] == 0.002 and out["newer"]["source"] in ("end of test 8", "end of move 8"), out
    assert out["newerForce"]["value"] is None, out
