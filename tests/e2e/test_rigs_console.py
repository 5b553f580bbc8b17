"""Several rigs on one database in the console: each service's History lists every rig's tests with a Rig
column, filters by rig, and offers no delete for another rig's test; the test page names the rig."""

from __future__ import annotations

from .harness import OPERATOR, WAIT_MS, Server, shots, sine_test


def test_history_shows_and_filters_every_rigs_tests(tmp_path, open_page, artifacts):
    db = f"sqlite:///{tmp_path / 'shared.db'}"
    a = Server(tmp_path / "a", database_url=db, rig_name="rig-a").start()
    try:
        b = Server(tmp_path / "b", database_url=db, rig_name="rig-b").start()
        try:
            ran_a = a.start_test({**sine_test(cycles=2, speed=10.0), "specimen_id": "ON-A"})
            ran_b = b.start_test({**sine_test(cycles=2, speed=10.0), "specimen_id": "ON-B"})
            status, ready_b = b.call("POST", "/api/tests", {**sine_test(), "specimen_id": "READY-B"}, token=True)
            assert status == 201, ready_b
            a.wait_status(ran_a, {"completed"}, timeout_s=60)
            b.wait_status(ran_b, {"completed"}, timeout_s=60)

            page, _ = open_page(a.url + "/#/history", width=1366, height=768, login=OPERATOR)
            row_b = page.wait_for_selector(f"#history-table tr[data-id='{ran_b}']", timeout=WAIT_MS)
            row_a = page.wait_for_selector(f"#history-table tr[data-id='{ran_a}']", timeout=WAIT_MS)
            assert row_a.query_selector("td.rig").inner_text() == "rig-a"
            assert "this-rig" in row_a.query_selector("td.rig").get_attribute("class")
            assert row_b.query_selector("td.rig").inner_text() == "rig-b" and "ON-B" in row_b.inner_text()
            # another rig's test that never ran is its service's: no delete here (it is refused, 409)
            assert page.locator(f"#history-table tr[data-id='{ready_b['id']}'] button[data-action]").count() == 0
            page.wait_for_function("document.getElementById('s-rig-label').textContent === 'rig rig-a'",
                                   timeout=WAIT_MS)  # the strip names the rig this console drives
            options = page.locator("#h-rig option").all_inner_texts()
            assert options == ["any", "rig-a (this console's)", "rig-b"], options
            shots(page, artifacts, "dashboard_history_rigs")

            page.select_option("#h-rig", "rig-b")
            page.click("#history-filter button[type='submit']")
            page.wait_for_selector(f"#history-table tr[data-id='{ran_a}']", state="detached", timeout=WAIT_MS)
            ids = page.locator("#history-table tbody tr").evaluate_all("rows => rows.map(r => r.dataset.id)")
            assert sorted(ids) == sorted([str(ran_b), str(ready_b["id"])]), ids

            page.click(f"#history-table tr[data-id='{ran_b}']")
            page.wait_for_selector("#t-summary .kv", timeout=WAIT_MS)
            rig = page.evaluate("[...document.querySelectorAll('#t-summary .kv')].filter("
                                "k => k.querySelector('span').textContent === 'rig').map(k => k.querySelector("
                                "'b').textContent)")
            assert rig == ["rig-b"], rig
        finally:
            b.stop()
    finally:
        a.stop()
