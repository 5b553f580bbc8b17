"""Input checks that cannot be bypassed (issue 23, part 4, the console): a structure or ground-motion file that
does not parse keeps Start disabled until it is replaced or cleared (never the default building in its place),
and a hybrid test's vertical load says where it comes from, in the console's digits."""

from __future__ import annotations

import json
import math

import pytest

from .harness import FIRST_CHECK_MS, OPERATOR, VIEWPORTS, WAIT_MS, BusyPool, fill_identity, poll, wait_start_enabled

GOOD_BUILDING = {"name": "two storeys", "base_mass_kg": 5000.0, "masses_kg": [4000.0, 3000.0],
                 "stiffness_n_per_m": [9e6, 7e6], "damping_ratio": 0.05}


def _start_why(page) -> str:
    return page.inner_text("#start-why")


def _blocked_by(page, words: str) -> None:
    poll(lambda: page.is_disabled("#start") and words in _start_why(page), 10, f"Start disabled, naming {words!r}")


@pytest.mark.parametrize("viewport", VIEWPORTS, ids=lambda v: f"{v[0]}x{v[1]}")
def test_a_bad_structure_file_keeps_start_disabled_until_replaced_or_cleared(server, open_page, artifacts,
                                                                            viewport, tmp_path):
    width, height = viewport
    page, watch = open_page(server.url + "/", width=width, height=height, login=OPERATOR)
    fill_identity(page, "I23-HYBRID")
    page.select_option("#f-isolator", "IUT_a")
    page.fill("#f-supply", "100")
    page.fill("#f-speed", "10")
    page.select_option("#f-profile", "hybrid")
    page.click("#hy-demo")
    page.fill("#f-eq_scale", "0.3")
    wait_start_enabled(page, FIRST_CHECK_MS)
    # the vertical load says where it comes from, in the console's digits (0.01 kN), not 125.0347875
    weight_n = 12750.0 * 9.80665  # the demo building: 12.75 t
    assert f"empty: {weight_n / 1e3:.2f} kN (the building's weight)" in \
        page.inner_text("[data-field='vertical_load'] .range")
    assert page.get_attribute("#f-vertical_load", "placeholder") == f"{weight_n / 1e3:.2f}"

    broken = tmp_path / "broken.json"
    broken.write_text('{"base_mass_kg": 4000, "masses_kg": [3000, 3000')  # cut short
    page.set_input_files("#hy-file", str(broken))
    _blocked_by(page, "structure file")
    note = page.inner_text("#hy-file-note")
    assert note.startswith("broken.json: not JSON") and "Start waits until" in note, note
    assert page.get_attribute("#hy-file-note", "class") == "msg bad"
    assert page.is_visible("#hy-file-clear")
    page.screenshot(path=str(artifacts / f"i23_bad_structure_file_{width}x{height}.png"))
    # no other change re-enables Start: the scale changed, the envelope checked again (its answer drawn anew)
    page.evaluate("document.querySelectorAll('#envelope > *').forEach((e) => { e.dataset.before = '1'; })")
    page.fill("#f-eq_scale", "0.25")
    page.wait_for_selector("#envelope[data-state] > :not([data-before])", timeout=WAIT_MS)
    _blocked_by(page, "structure file")
    # cleared: the building in the fields (unchanged) is what runs
    page.click("#hy-file-clear")
    wait_start_enabled(page)
    assert page.is_hidden("#hy-file-clear") and "cleared" in page.inner_text("#hy-file-note")
    assert page.input_value("#f-hy_base_mass") == "4000"

    # a JSON file that is no building: blocked again; a good file replaces it
    wrong = tmp_path / "wrong.json"
    wrong.write_text(json.dumps({"base_mass_kg": 4000, "masses_kg": [3000], "stiffness_n_per_m": [1e6, 2e6],
                                 "damping_ratio": 0.05}))
    page.set_input_files("#hy-file", str(wrong))
    _blocked_by(page, "structure file")
    assert "as many springs as storeys" in page.inner_text("#hy-file-note")
    good = tmp_path / "good.json"
    good.write_text(json.dumps(GOOD_BUILDING))
    page.set_input_files("#hy-file", str(good))
    wait_start_enabled(page)
    assert "2 storeys read into the fields" in page.inner_text("#hy-file-note")
    assert page.locator(".storey-row").count() == 2
    good_weight = 12000.0 * 9.80665
    assert f"empty: {good_weight / 1e3:.2f} kN (the building's weight)" in \
        page.inner_text("[data-field='vertical_load'] .range")

    # the confirmation says the vertical load and where it came from; cancelled, nothing is sent
    page.click("#start")
    page.wait_for_selector("#confirm-dialog[open]", timeout=WAIT_MS)
    body = page.inner_text("#confirm-body")
    assert f"{good_weight / 1e3:.2f} kN" in body and "vertical load: the building's weight" in body, body
    page.screenshot(path=str(artifacts / f"i23_hybrid_confirmation_{width}x{height}.png"))
    page.click("#confirm-cancel")

    # a building heavier than the jack (125 t: 1226 kN against 850 kN): the refusal names the building's weight,
    # the jack's capacity and how to set the load, and Start stays disabled
    watch.allowed_status.add(422)  # the check's refusal
    heavy = tmp_path / "heavy.json"
    heavy.write_text(json.dumps({**GOOD_BUILDING, "name": "heavy", "base_mass_kg": 50000.0,
                                 "masses_kg": [25000.0, 25000.0, 25000.0], "stiffness_n_per_m": [9e7, 8e7, 7e7]}))
    page.set_input_files("#hy-file", str(heavy))
    page.wait_for_selector("#envelope[data-state='refused']", timeout=FIRST_CHECK_MS)
    refusal = page.inner_text("#envelope")
    assert "the building weighs 1226 kN" in refusal and "carries at most 850 kN" in refusal, refusal
    assert "vertical_load_n (the API; the console's vertical load)" in refusal, refusal
    assert page.is_disabled("#start")
    page.screenshot(path=str(artifacts / f"i23_building_heavier_than_the_jack_{width}x{height}.png"))
    # the load set in the console (here 800 kN): the building runs
    page.fill("#f-vertical_load", "800")
    wait_start_enabled(page)
    assert "Within the rig envelope" in page.inner_text("#envelope")


@pytest.mark.parametrize("viewport", VIEWPORTS, ids=lambda v: f"{v[0]}x{v[1]}")
def test_a_ground_motion_file_that_does_not_parse_keeps_start_disabled(server, open_page, artifacts, viewport,
                                                                       tmp_path):
    width, height = viewport
    page, _ = open_page(server.url + "/", width=width, height=height, login=OPERATOR)
    fill_identity(page, "I23-HISTORY")
    page.select_option("#f-isolator", "IUT_a")
    page.fill("#f-supply", "100")
    page.fill("#f-speed", "10")
    page.select_option("#f-profile", "history")
    page.select_option("#f-eq_source", "preset")
    page.fill("#f-eq_scale", "0.3")
    wait_start_enabled(page, FIRST_CHECK_MS)
    page.select_option("#f-eq_source", "acc_csv")
    _blocked_by(page, "ground motion file")  # no file yet
    garbage = tmp_path / "garbage.csv"
    garbage.write_text("this is not, a record\nat all\n")
    page.set_input_files("#f-eq_file", str(garbage))
    poll(lambda: page.inner_text("#eq-file-note").startswith("garbage.csv: "), 10, "the file refused")
    _blocked_by(page, "ground motion file")
    good = tmp_path / "good.csv"
    good.write_text("time_s,acceleration_m_per_s2\n" + "\n".join(
        f"{k * 0.01:.2f},{1.5 * math.sin(2 * math.pi * k * 0.01) * math.sin(math.pi * k / 400) ** 2:.5f}"
        for k in range(401)) + "\n")
    page.set_input_files("#f-eq_file", str(good))
    poll(lambda: "401 rows" in page.inner_text("#eq-file-note"), 10, "the good file read")
    wait_start_enabled(page)
    # the bad file again, then the choice cleared: the good file read before is not used in its place
    page.set_input_files("#f-eq_file", str(garbage))
    _blocked_by(page, "ground motion file")
    page.set_input_files("#f-eq_file", [])
    poll(lambda: page.inner_text("#eq-file-note").startswith("no file chosen"), 10, "the file cleared")
    _blocked_by(page, "ground motion file")
    page.screenshot(path=str(artifacts / f"i23_ground_motion_cleared_{width}x{height}.png"))
    page.select_option("#f-eq_source", "preset")
    wait_start_enabled(page)


def test_a_busy_check_pool_is_said_and_asked_again_after_its_retry_after(server, open_page):
    """The set-up check runs in the service's check pool: while the pool is busy (503 with Retry-After) the page
    says so and asks again after the answer's Retry-After (not a fixed wait), then draws the answer."""
    page, watch = open_page(server.url + "/", login=OPERATOR)
    page.evaluate("""() => { window.__envelopeTexts = [];
        new MutationObserver(() => window.__envelopeTexts.push(document.getElementById('envelope').textContent))
          .observe(document.getElementById('envelope'), { childList: true, characterData: true, subtree: true }); }""")
    busy = BusyPool(3, retry_after_s=1, what="build a sine profile")
    page.route("**/api/tests/check", busy)
    fill_identity(page, "BUSY-POOL")
    page.fill("#f-amplitude", "5")
    page.fill("#f-frequency", "0.5")
    wait_start_enabled(page, FIRST_CHECK_MS)
    assert len(busy.refused_at) == 3, busy.refused_at
    assert "Within the rig envelope" in page.inner_text("#envelope")
    said = page.evaluate("window.__envelopeTexts")
    assert any("the service is busy with other checks; asking again in 1 s" in text for text in said), said
    gaps = [b - a for a, b in zip(busy.refused_at, busy.refused_at[1:], strict=False)]
    assert all(gap >= 0.9 for gap in gaps), gaps  # it waited the Retry-After before asking again
    assert all("/api/tests/check" in url for _, url in watch.busy), watch.busy
