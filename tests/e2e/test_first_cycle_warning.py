"""The confirmation warns of a limit the first cycle is expected to trip (issue 23, part 5): the service's check
simulates the first cycle with the test's controller and limits on the rig model; the console shows its warning
under the envelope and lists it among the confirmation's warnings, which need a tick before Start."""

from __future__ import annotations

import pytest

from .harness import FIRST_CHECK_MS, OPERATOR, VIEWPORTS, WAIT_MS, fill_identity, poll, wait_start_enabled


def _set_up(page, controller: str) -> None:
    fill_identity(page, "I23-FIRST-CYCLE")
    page.select_option("#f-isolator", "IUT_b")
    page.fill("#f-supply", "70")
    page.fill("#f-amplitude", "30")
    page.fill("#f-frequency", "0.5")
    page.fill("#f-cycles", "3")
    page.select_option("#f-controller", controller)


@pytest.mark.parametrize("viewport", VIEWPORTS, ids=lambda v: f"{v[0]}x{v[1]}")
def test_the_confirmation_warns_of_a_first_cycle_trip(server, open_page, artifacts, viewport):
    width, height = viewport
    page, _ = open_page(server.url + "/", width=width, height=height, login=OPERATOR)
    # the paper's scenario with the paper's controller: mrac lurches and trips the pump-flow velocity limit
    _set_up(page, "mrac")
    wait_start_enabled(page, FIRST_CHECK_MS)
    poll(lambda: "expected to trip in its first cycle" in page.inner_text("#envelope"), 60,
         "the check's warning under the envelope")
    envelope = page.inner_text("#envelope")
    assert "velocity limit" in envelope and "mrac" in envelope, envelope
    page.click("#start")
    page.wait_for_selector("#confirm-dialog[open]", timeout=WAIT_MS)
    warnings = page.inner_text("#confirm-body .warnings")
    assert "expected to trip in its first cycle" in warnings and "velocity limit" in warnings, warnings
    assert page.is_disabled("#confirm-ok")  # a warning needs its tick
    page.screenshot(path=str(artifacts / f"i23_first_cycle_warning_{width}x{height}.png"))
    page.click("#confirm-cancel")
    # the default controller on the same test: no such warning
    page.select_option("#f-controller", "servo")
    poll(lambda: page.get_attribute("#envelope", "data-state") == "ok"
         and "expected to trip" not in page.inner_text("#envelope"), 60, "the servo's check without the warning")
    wait_start_enabled(page)
    page.click("#start")
    page.wait_for_selector("#confirm-dialog[open]", timeout=WAIT_MS)
    assert "expected to trip" not in page.inner_text("#confirm-body")
    page.click("#confirm-cancel")
