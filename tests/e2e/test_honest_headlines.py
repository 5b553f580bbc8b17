"""Honest headlines (issue 23, part 2): once a test has ended, the live view's K_eff, EDC and xi_eff are the
figures of its steady cycles (the record's summary, as the PDF), and the loop drawn bold, on the live view and on
the test's page, is its last steady cycle, not the ramp-out that came last, as are the live readouts' peak and
valley and the limit margins; ramp cycles are marked as such."""

from __future__ import annotations

import re

import pytest

from .harness import VIEWPORTS, WAIT_MS, sine_test

KN_PER_MM = 1e6  # N/m in one kN/mm (the console's lab units)


def _shown(text: str, unit: str) -> float:
    """The number of a figure shown with its unit ("0.884 kN/mm" -> 0.884)."""
    m = re.match(r"^\s*([-+]?[0-9.]+(?:e[-+]?\d+)?)\s*" + re.escape(unit) + r"\s*$", text)
    assert m, f"{text!r} is not a figure in {unit}"
    return float(m.group(1))


@pytest.mark.parametrize("viewport", VIEWPORTS, ids=lambda v: f"{v[0]}x{v[1]}")
def test_headline_and_bold_loop_after_a_test_are_the_steady_cycles(server, open_page, artifacts, viewport):
    width, height = viewport
    page, _ = open_page(server.url + "/", width=width, height=height)
    page.evaluate("""() => {  // every headline label the page shows, in order
      window.__labels = [];
      const label = document.getElementById('l-keff-label');
      new MutationObserver(() => window.__labels.push(label.textContent)).observe(label, { childList: true,
        characterData: true, subtree: true });
    }""")
    test_id = server.start_test(sine_test(amplitude_m=0.03, frequency_hz=0.5, cycles=5, taper_cycles=1, speed=4.0))
    rec = server.wait_status(test_id, {"completed"}, timeout_s=60)
    summary = rec["summary"]
    _, cycles = server.call("GET", f"/api/tests/{test_id}/cycles")
    phases = [c["phase"] for c in cycles]
    assert phases[0] == "taper_in" and phases[-1] == "taper_out", phases
    steady = [c for c in cycles if c["phase"] == "steady"]
    assert summary["steady_cycles"] == len(steady) == 3  # 5 cycles: one ramp-in, three steady, one ramp-out
    mean = summary["loop_metrics_mean"]["k_eff_n_per_m"]
    taper_out = cycles[-1]["k_eff_n_per_m"]
    # the test can tell the two apart: the ramp-out loop is stiffer than the steady ones (1.029 against 0.884)
    assert abs(taper_out - mean) / mean > 0.02, (taper_out, mean)

    page.wait_for_function("document.getElementById('l-keff').closest('.kv').dataset.source === 'steady-mean'",
                           timeout=WAIT_MS)
    assert page.inner_text("#l-keff-label") == "K_eff (mean of 3 steady cycles)"
    keff = _shown(page.inner_text("#l-keff"), "kN/mm") * KN_PER_MM
    assert abs(keff - mean) / mean < 0.01, (keff, mean)  # the target: within 1 % of the summary's steady mean
    edc = summary["loop_metrics_mean"]["edc_j"]
    assert abs(_shown(page.inner_text("#l-edc"), "J") - edc) / edc < 0.01
    # while it ran, the ramp-in cycle was said to be one (not shown as a plain "last cycle")
    labels = page.evaluate("window.__labels")
    assert any("ramp-in, not steady" in x for x in labels), labels

    # the live loop: the last steady cycle bold, the ramp cycles dashed
    page.wait_for_selector("#plot-loop[data-bold-phase]", timeout=WAIT_MS)
    assert page.get_attribute("#plot-loop", "data-bold-phase") == "steady"
    assert page.get_attribute("#plot-loop", "data-bold-cycle") == str(steady[-1]["cycle"])
    assert page.inner_text("#loop-note").startswith(f"cycle {steady[-1]['cycle']} bold: the last steady cycle")
    # the readouts' peak and valley and the limit margins: the same cycle's, said so (not the ramp-out's)
    last = steady[-1]
    page.wait_for_function(f"document.querySelector('#readouts .pk').textContent === 'cycle {last['cycle']} peak'",
                           timeout=WAIT_MS)
    assert abs(cycles[-1]["d_max_m"] - last["d_max_m"]) > 5e-4, (cycles[-1], last)  # the two can be told apart
    page.wait_for_function(f"Math.abs(parseFloat(document.getElementById('r-y-max').textContent) - "
                           f"{last['d_max_m'] * 1e3}) < 0.05", timeout=WAIT_MS)
    assert abs(_shown(page.inner_text("#r-y-min"), "mm") - last["d_min_m"] * 1e3) < 0.05
    assert abs(_shown(page.inner_text("#r-f-max"), "kN") - last["f_max_n"] * 1e-3) < 0.05 * abs(last["f_max_n"]) * 1e-3
    assert page.text_content("#margins-name") == f"limits: margin in cycle {last['cycle']} (the last steady), action"
    page.screenshot(path=str(artifacts / f"i23_live_after_test_{width}x{height}.png"))

    # the test's page: the same loop bold, the means said to be over the steady cycles, ramp rows marked
    page.goto(f"{server.url}/?viewer=off#/tests/{test_id}")
    page.wait_for_selector("#t-loops[data-bold-phase]", timeout=WAIT_MS)
    assert page.get_attribute("#t-loops", "data-bold-phase") == "steady"
    assert page.get_attribute("#t-loops", "data-bold-cycle") == str(steady[-1]["cycle"])
    assert "the last steady cycle" in page.inner_text("#t-loops-note")
    summary_text = page.inner_text("#t-summary")
    assert "mean K_eff (3 steady cycles)" in summary_text, summary_text
    ramp_rows = page.eval_on_selector_all("#t-cycles tr.ramp-cycle td:first-child",
                                          "tds => tds.map(t => t.textContent)")
    assert ramp_rows == ["1 (ramp-in)", f"{cycles[-1]['cycle']} (ramp-out)"], ramp_rows
    page.screenshot(path=str(artifacts / f"i23_test_page_{width}x{height}.png"), full_page=True)
