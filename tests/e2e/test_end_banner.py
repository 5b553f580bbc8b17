"""The end banner of a test (the message when a test finishes) is one compact line: it does not push the live
force-displacement loop below the fold at 1366x768, and its words are all there (its title; whole once clicked).
Screenshots at 1366x768 and 1920x1080 in artifacts/e2e/."""

from __future__ import annotations

from .harness import WAIT_MS, settle, shots, sine_test


def test_the_end_banner_leaves_the_loop_above_the_fold(server, open_page, artifacts):
    page, _ = open_page(f"{server.url}/", width=1366, height=768)
    test_id = server.start_test(sine_test(cycles=2, speed=4.0))
    server.wait_status(test_id, {"completed"})
    page.wait_for_selector("#rig-status[data-status='completed']", timeout=WAIT_MS)
    # the end banner, with the tracking verdict the live header shows too
    page.wait_for_function(f"document.getElementById('alert-text').textContent.startsWith('Test {test_id} completed; "
                           "tracking error')", timeout=WAIT_MS)
    page.wait_for_selector("#l-verdict-kv:not(.hidden)", timeout=WAIT_MS)
    page.evaluate("window.scrollTo(0, 0)")
    settle(page)
    page.wait_for_timeout(300)  # the loop's height follows the banner (a ResizeObserver)
    page.screenshot(path=str(artifacts / "end_banner_1366x768.png"))
    assert page.is_visible("#alert")
    banner = page.locator("#alert").bounding_box()
    loop = page.locator("#plot-loop").bounding_box()
    assert loop["height"] >= 240 and loop["y"] >= banner["y"] + banner["height"], (banner, loop)
    assert loop["y"] + loop["height"] <= 768, (banner, loop)  # whole, above the fold, with the banner shown
    assert banner["height"] <= 32, banner  # one line
    # the whole message is there: on the banner's title, and in full once clicked
    full = page.inner_text("#alert-text")
    assert page.get_attribute("#alert-text", "title") == full
    page.click("#alert-text")
    assert page.evaluate("document.getElementById('alert').classList.contains('open')")
    page.click("#alert-text")
    shots(page, artifacts, "end_banner")
    page.set_viewport_size({"width": 1920, "height": 1080})
    settle(page)
    page.wait_for_timeout(300)
    loop = page.locator("#plot-loop").bounding_box()
    assert loop["y"] + loop["height"] <= 1080 and page.is_visible("#alert"), loop
