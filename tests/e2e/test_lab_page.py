"""The Lab page (issue 23, part 8, reports in the lab's units): an admin sets the lab's default units in the
console; the reports say which units they print in (report.json's lab.units), a browser that has not chosen
its own units opens in the lab's, an operator reads the page without changing it."""

from __future__ import annotations

import pytest

from .harness import OPERATOR, VIEWPORTS, WAIT_MS, hold_back_answer, poll, sine_test

ADMIN = ("e2e-lab-admin", "e2e-lab-admin-password")


def _lab_page(open_page, server, viewport, login):
    page, _ = open_page(server.url + "/#/lab", width=viewport[0], height=viewport[1], login=login)
    page.wait_for_selector("#lab-form", state="visible", timeout=WAIT_MS)
    page.wait_for_function("document.getElementById('lab-who').textContent !== ''", timeout=WAIT_MS)
    return page


def _save_units(page, units: str) -> None:
    page.select_option("#lab-units", units)
    page.click("#lab-save")  # the message says "saving..." at once, then "Saved" once this save has answered
    poll(lambda: page.inner_text("#lab-message").startswith("Saved"), 10, "the lab saved",
         shown=lambda: page.inner_text("#lab-message"))


@pytest.mark.parametrize("viewport", VIEWPORTS, ids=lambda v: f"{v[0]}x{v[1]}")
def test_the_lab_units_set_on_the_lab_page_reach_the_reports_and_new_browsers(server, open_page, artifacts,
                                                                              viewport):
    server.add_account(*ADMIN, role="admin")
    width, height = viewport
    admin = _lab_page(open_page, server, viewport, ADMIN)
    assert page_enabled(admin) and "You are an admin" in admin.inner_text("#lab-who")
    assert admin.input_value("#lab-units") == "lab"
    try:
        _save_units(admin, "si")
        assert server.call("GET", "/api/lab")[1]["units"] == "si"
        admin.screenshot(path=str(artifacts / f"i23_lab_page_si_{width}x{height}.png"))
        # a report made now names the lab's units
        test_id = server.start_test(sine_test(cycles=2, speed=4.0))
        server.wait_status(test_id, {"completed"})
        code, report = server.call("GET", f"/api/tests/{test_id}/report.json")
        assert code == 200 and report["lab"]["units"] == "si", (code, report.get("lab"))
        # a browser that has not chosen its units opens in the lab's (SI: the amplitude in m)
        fresh, _ = open_page(server.url + "/", width=width, height=height)
        poll(lambda: fresh.input_value("#units") == "si", 10, "the lab's units in a new browser")
        # an operator reads the page, cannot change it
        operator = _lab_page(open_page, server, viewport, OPERATOR)
        assert not page_enabled(operator) and "An admin changes these" in operator.inner_text("#lab-who")
        assert operator.input_value("#lab-units") == "si"
        operator.screenshot(path=str(artifacts / f"i23_lab_page_operator_{width}x{height}.png"))
    finally:  # the other tests of this service expect the lab's units
        _save_units(admin, "lab")
    assert server.call("GET", "/api/lab")[1]["units"] == "lab"
    code, report = server.call("GET", f"/api/tests/{test_id}/report.json")
    assert code == 200 and report["lab"]["units"] == "lab"


def page_enabled(page) -> bool:
    return page.evaluate("!document.getElementById('lab-fields').disabled")


def test_a_late_read_of_the_lab_never_undoes_a_save(server, open_page):
    """The page reads the lab on each visit; a read answered after a save (it was asked before it) is dropped:
    the saved name stays in the field. Before the fix the late read put the old name back."""
    server.add_account(*ADMIN, role="admin")
    admin = _lab_page(open_page, server, VIEWPORTS[0], ADMIN)
    before = server.call("GET", "/api/lab")[1]
    hold_back_answer(admin, "/api/lab")  # reads only: the save (PUT) answers at once
    admin.goto(server.url + "/#/live")
    admin.goto(server.url + "/#/lab")  # a visit: the page reads the lab again (slowly)
    try:
        admin.fill("#lab-name", "Late Read Lab")
        admin.click("#lab-save")
        poll(lambda: admin.inner_text("#lab-message").startswith("Saved"), 10, "the lab saved",
             shown=lambda: admin.inner_text("#lab-message"))
        admin.wait_for_function("window.__heldBackAnswered", timeout=WAIT_MS)
        admin.wait_for_timeout(300)  # whatever the late read would draw has been drawn
        assert admin.input_value("#lab-name") == "Late Read Lab"
        assert server.call("GET", "/api/lab")[1]["name"] == "Late Read Lab"
    finally:  # the other tests of this service expect the lab as it was
        admin.fill("#lab-name", before["name"])
        admin.click("#lab-save")
        poll(lambda: server.call("GET", "/api/lab")[1]["name"] == before["name"], 10, "the lab's name back")
