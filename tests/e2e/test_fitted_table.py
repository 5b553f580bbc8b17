"""The Commissioning page's Fitted table as the lab's operators read it, at 1366x768 and 1920x1080 (screenshots in
artifacts/e2e/):

- a refused commissioning's fitted values are marked as not trusted, with their uncertainty, and a value without a
  finite uncertainty reads "not determined", not as a confident number;
- every column is whole, with or without a frequency response beside the table;
- a quantity declared 0 says its change with its unit ("+4.4 ms"), not as a bare number.

The page shows a commissioning's answer (GET /api/commissioning/{id}) made here from a refused fit's figures (the
noisy rig of test_commissioning_second_attempt.py at 10 mm/s), with what a refusal can hold besides: a bulk modulus
of 3e15 Pa with no uncertainty (the fit found next to no compliance in the oil column), a pre-sliding distance on a
rig declared without one. The page itself is the service's.
"""

from __future__ import annotations

import json
import math

import pytest

from .harness import WAIT_MS, settle, shots

CID = 90417  # no record of the service has this id: the page gets the answer routed below


def _estimates(**changes) -> dict:
    est = {
        "flow_gain_m3_per_s_v_sqrt_pa": (3.6192e-07, 1.0888e-07, "m3/(s V sqrt(Pa))"),
        "driver_gain_negative": (0.82232, 0.19366, "V/V"),
        "dead_zone_v": (0.79056, 0.082568, "V"),
        "driver_offset_v": (-0.062136, 0.08907, "V"),
        "valve_play_v": (1.0303e-11, 8.5731e-05, "V"),
        "valve_natural_frequency_rad_s": (254.43, 104.39, "rad/s"),
        "valve_damping_ratio": (0.68455, 0.025685, "-"),
        "bulk_modulus_pa": (12359569520.85, 18073508086.47, "Pa"),
        "position_latency_s": (0.0043622, 0.0011168, "s"),
        "mass_kg": (0.0, 280.25, "kg"),
        "friction_force_n": (1699.6, 693.06, "N"),
        "viscous_n_s_per_m": (227254.7, 144232.7, "N s/m"),
        "presliding_m": (1.63e-05, 3.1e-06, "m"),
        "bristle_damping_n_s_per_m": (0.0, 0.0, "N s/m"),
    }
    est.update(changes)
    return {name: {"value": v, "std": s, "unit": u, "meaning": name} for name, (v, s, u) in est.items()}


def _response() -> dict:
    f = [1.0 * 1.25 ** k for k in range(21)]  # 1 to 87 Hz
    gain = [0.2 / math.sqrt(1 + (x / 40) ** 2) for x in f]
    phase = [-math.degrees(math.atan(x / 40)) - 0.36 * x for x in f]
    pair = {"measured": {"magnitude": gain, "phase_deg": phase}, "model": {"magnitude": gain, "phase_deg": phase}}
    pressure = {"measured": {"magnitude": [4e5 * g for g in gain], "phase_deg": phase},
                "model": {"magnitude": [4e5 * g for g in gain], "phase_deg": phase}}
    return {"frequency_hz": f, "velocity_per_volt": pair, "load_pressure_per_volt": pressure, "periods": 8,
            "velocity_nrmse": 0.061, "pressure_nrmse": 0.083}


def _answer(estimates: dict, state: str = "not_trusted", response: dict | None = None) -> dict:
    """GET /api/commissioning/{CID} as the service answers it for a fitted commissioning."""
    problems = [] if state == "trusted" else [
        "the flow balance (eq. 3, second line) explains 96.2 % of the table's motion; at least 98 % is needed",
        "bulk_modulus_pa has no finite uncertainty", "mass_kg = 0 kg is not a positive value"]
    declared = {"flow_gain_m3_per_s_v_sqrt_pa": 2.764e-07, "driver_gain_negative": 1.0, "dead_zone_v": 0.8621,
                "driver_offset_v": 0.02, "valve_play_v": 0.0, "valve_natural_frequency_rad_s": 251.32741228718345,
                "valve_damping_ratio": 0.7, "bulk_modulus_pa": 1e9, "position_latency_s": 0.0, "mass_kg": 1200.0,
                "friction_force_n": 1500.0, "viscous_n_s_per_m": 20000.0, "presliding_m": 0.0}
    conditions = {"rig": "simulated", "supply_pa": 1e7, "vertical_load_n": 0.0, "specimen": "none", "start_m": 0.0,
                  "max_stroke_m": 0.002, "max_velocity_m_per_s": 0.01}
    return {
        "id": CID, "status": "completed", "reason": None, "state": state,
        "words": "trusted" if state == "trusted" else "NOT trusted, no rig file: " + "; ".join(problems),
        "profile": {"kind": "commissioning", "start_m": 0.0, "max_stroke_m": 0.002, "max_velocity_m_per_s": 0.01},
        "conditions": conditions, "operator_name": "automation", "isolator": "none", "supply_bar": 100.0,
        "vertical_load_n": 0.0, "speed": 20.0, "driver": "simulated", "rig": "isorig default rig (sim.rig)",
        "plant_changes": {}, "created_at": "2026-11-30T01:23:06+00:00", "started_at": "2026-11-30T01:23:13+00:00",
        "ended_at": "2026-11-30T01:23:14+00:00", "time_s": 21.2, "duration_s": 21.2, "limits": {},
        "identification": {
            "trusted": state == "trusted", "problems": problems, "second_attempt": None, "conditions": conditions,
            "record": {"rig_time_s": 21.2, "peak_excursion_m": 0.000178, "peak_velocity_m_per_s": 0.00933,
                       "peak_command_v": 0.9698, "dither_s": 17.0, "completed": True},
            "fit": {"estimates": estimates, "flow_r2": 0.962, "force_r2": 0.952, "force_balance_s": 17.0},
            "response": response, "changed": {}},
        "declared": declared, "error": None, "fit_s": 28.6, "fitted_at": "2026-11-30T01:23:43+00:00",
        "applied": None, "record": f"/api/tests/{CID}", "rig_file": None}


def _trace_csv() -> str:
    rows = ["time_s,displacement_m,voltage_v"]
    rows += [f"{k / 100:.2f},{0.0015 * math.sin(k / 30):.6f},{0.4 * math.sin(k / 7):.4f}" for k in range(2000)]
    return "\n".join(rows) + "\n"


def _open_commissioning(open_page, server, answer: dict, width: int, height: int, units: str = "lab"):
    """The Commissioning page on commissioning CID, whose answer is `answer`."""
    page, watch = open_page(f"{server.url}/", width=width, height=height)
    page.route(f"**/api/commissioning/{CID}", lambda route: route.fulfill(
        status=200, content_type="application/json", body=json.dumps(answer)))
    page.route(f"**/api/tests/{CID}/data.csv", lambda route: route.fulfill(
        status=200, content_type="text/csv", body=_trace_csv()))
    if units != "lab":
        page.select_option("#units", units)
    page.evaluate(f"location.hash = '#/commission/{CID}'")
    page.wait_for_selector("#c-result:not(.hidden)", timeout=WAIT_MS)
    page.wait_for_selector(f"#c-run-title:has-text('#{CID}')", timeout=WAIT_MS)
    page.wait_for_selector("#c-table tbody tr[data-name='bulk_modulus_pa']", timeout=WAIT_MS)
    return page, watch


def _cells(page) -> dict:
    """The Fitted table by quantity: its cells' texts and the fitted cell's marks."""
    return page.evaluate("""() => Object.fromEntries([...document.querySelectorAll('#c-table tbody tr[data-name]')]
      .map((tr) => [tr.dataset.name, {cells: [...tr.cells].map((c) => c.innerText.trim()),
        trusted: tr.cells[1].dataset.trusted || null}]))""")


def _columns_whole(page) -> dict:
    """Where the Fitted table's columns end against its box and the window (every header and cell)."""
    return page.evaluate("""() => {
      const wrap = document.querySelector('#c-table').closest('.table-wrap');
      const box = wrap.getBoundingClientRect();
      const cells = [...document.querySelectorAll('#c-table th, #c-table td')].map((c) => c.getBoundingClientRect());
      return {scrollWidth: wrap.scrollWidth, clientWidth: wrap.clientWidth, boxRight: box.right,
              rightmost: Math.max(...cells.map((r) => r.right)), window: window.innerWidth,
              units: [...document.querySelectorAll('#c-table tr > :last-child')].map((c) => c.innerText.trim())};
    }""")


# --- 2. a refused fit's values -------------------------------------------------------------------------------

@pytest.mark.parametrize("width,height", [(1366, 768), (1920, 1080)])
def test_a_refused_fits_values_are_not_shown_as_confident_numbers(server, open_page, artifacts, width, height):
    answer = _answer(_estimates(bulk_modulus_pa=(3.2e15, None, "Pa")))
    page, _ = _open_commissioning(open_page, server, answer, width, height)
    page.wait_for_selector("#c-verdict[data-state='not_trusted']", timeout=WAIT_MS)
    page.evaluate("document.querySelector('#c-table').scrollIntoView()")
    settle(page)
    page.screenshot(path=str(artifacts / f"fitted_table_refused_{width}x{height}.png"))
    assert "not trusted" in page.inner_text("#c-table thead").lower()
    assert "not trusted" in page.inner_text("#c-table-note").lower()
    rows = _cells(page)
    bulk = rows["bulk_modulus_pa"]["cells"]
    assert bulk[1] == "not determined" and "3.2" not in " ".join(bulk[1:]), bulk  # no number at all
    assert bulk[2] == "none" and bulk[4] == "-", bulk
    assert bulk[3] == "1000" and bulk[5] == "MPa", bulk  # the declared value stays
    # the others keep their value and uncertainty, each marked as not trusted
    gain = rows["flow_gain_m3_per_s_v_sqrt_pa"]["cells"]
    assert gain[1] == "6.9" and gain[2].startswith("\u00b12.1"), gain
    assert {r["trusted"] for r in rows.values()} == {"false"}, rows


def test_a_trusted_fit_is_not_marked(server, open_page):
    page, _ = _open_commissioning(open_page, server, _answer(_estimates(), state="trusted"), 1920, 1080)
    page.wait_for_selector("#c-verdict[data-state='trusted']", timeout=WAIT_MS)
    assert "not trusted" not in page.inner_text("#c-table thead").lower()
    assert page.is_hidden("#c-table-note")
    rows = _cells(page)
    assert {r["trusted"] for r in rows.values()} == {None}, rows
    assert rows["bulk_modulus_pa"]["cells"][1] == "12360", rows["bulk_modulus_pa"]


# --- 3. every column of the Fitted table whole ---------------------------------------------------------------

@pytest.mark.parametrize("units", ["si", "lab"])
@pytest.mark.parametrize("response", [False, True], ids=["no_response", "with_response"])
def test_the_fitted_tables_columns_are_whole(server, open_page, artifacts, units, response):
    answer = _answer(_estimates(), response=_response() if response else None)
    for width, height in ((1920, 1080), (1366, 768)):
        page, _ = _open_commissioning(open_page, server, answer, width, height, units=units)
        assert page.is_visible("#c-response-panel") == response
        page.evaluate("document.querySelector('#c-table').scrollIntoView()")
        settle(page)
        name = f"fitted_table_columns_{'response' if response else 'alone'}_{units}_{width}x{height}.png"
        page.screenshot(path=str(artifacts / name))
        seen = _columns_whole(page)
        assert seen["scrollWidth"] <= seen["clientWidth"], seen  # nothing hidden behind a scroll bar
        assert seen["rightmost"] <= seen["boxRight"] + 0.5 and seen["boxRight"] <= seen["window"], seen
        assert seen["units"][0] == "unit" and "N s/m" in seen["units"][-1], seen


# --- 4. a change from a declared 0, with its unit -----------------------------------------------------------

@pytest.mark.parametrize("units", ["lab", "si"])
def test_a_change_from_a_declared_zero_has_its_unit(server, open_page, artifacts, units):
    page, _ = _open_commissioning(open_page, server, _answer(_estimates()), 1366, 768, units=units)
    page.evaluate("document.querySelector('#c-table').scrollIntoView()")
    settle(page)
    shots(page, artifacts, f"fitted_table_change_from_zero_{units}")
    rows = {name: r["cells"] for name, r in _cells(page).items()}
    lab = units == "lab"
    # declared 0: the change in the unit of the row (the page's units), signed; no bare number
    assert rows["position_latency_s"][3:] == (["0.0", "+4.4 ms", "ms"] if lab else ["0.0000", "+0.0044 s", "s"])
    assert rows["presliding_m"][3:] == (["0.0000", "+0.0163 mm", "mm"] if lab else ["0.0000000", "+0.0000163 m", "m"])
    assert rows["valve_play_v"][3:] == ["0.000000", "0.000000 V", "V"]  # within its uncertainty of 0: no sign
    # a declared value other than 0: the change in per cent, as before
    assert rows["flow_gain_m3_per_s_v_sqrt_pa"][4] == "+30.9 %"
    assert rows["mass_kg"][4] == "-100.0 %"
