"""The Accounts page (issue 34 item 4): an admin adds an account (its password made by the service and shown once),
changes its role, sets a new password, disables and enables it, makes and revokes an API token, all in the console;
the admin's own row cannot be disabled or demoted; an operator sees no Accounts link and the page says only an admin
manages accounts. Screenshots at 1366x768 and 1920x1080."""

from __future__ import annotations

from .harness import OPERATOR, WAIT_MS, shots

ADMIN = ("e2e-accounts-admin", "e2e-accounts-admin-password")
NEW = "e2e-newcomer"


def _row(server, name: str) -> dict:
    return next(a for a in _admin_list(server) if a["name"] == name)


def _admin_list(server) -> list[dict]:
    import json
    import urllib.request

    login = urllib.request.Request(f"{server.url}/api/session", method="POST",
                                   headers={"Content-Type": "application/json"},
                                   data=json.dumps({"name": ADMIN[0], "password": ADMIN[1]}).encode())
    with urllib.request.urlopen(login, timeout=30) as r:
        cookie = r.headers["set-cookie"].split(";", 1)[0]
    with urllib.request.urlopen(urllib.request.Request(f"{server.url}/api/accounts", headers={"Cookie": cookie}),
                                timeout=30) as r:
        return json.loads(r.read())["accounts"]


def _confirm(page) -> None:
    page.wait_for_selector("#confirm-dialog[open]", timeout=WAIT_MS)
    page.click("#confirm-ok")
    page.wait_for_selector("#confirm-dialog:not([open])", state="hidden", timeout=WAIT_MS)


def test_an_admin_manages_accounts_in_the_console(server, open_page, artifacts):
    server.add_account(*ADMIN, role="admin")
    page, watch = open_page(f"{server.url}/#/accounts", width=1366, height=768, login=ADMIN)
    watch.allowed_status.add(401)  # the newcomer's old password, tried after its reset
    page.wait_for_selector("#nav-accounts:visible", timeout=WAIT_MS)
    page.wait_for_selector(f"#acct-table tr[data-name='{ADMIN[0]}']", timeout=WAIT_MS)
    mine = page.locator(f"#acct-table tr[data-name='{ADMIN[0]}']")
    assert mine.locator("select").is_disabled()  # never demote yourself here
    assert mine.locator("button[data-act='disable']").count() == 0
    assert "(you)" in mine.inner_text()

    # a new viewer, its password made by the service and shown once
    page.fill("#acct-name", NEW)
    page.select_option("#acct-role", "viewer")
    page.click("#acct-add")
    page.wait_for_selector("#acct-secret:visible", timeout=WAIT_MS)
    made = page.inner_text("#acct-secret-value").strip()
    assert len(made) >= 10 and f"{NEW}'s password" in page.inner_text("#acct-secret")
    page.wait_for_selector(f"#acct-table tr[data-name='{NEW}'][data-state='active']", timeout=WAIT_MS)
    assert server.call("POST", "/api/session", {"name": NEW, "password": made})[0] == 200
    shots(page, artifacts, "accounts_page_added")
    page.click("#acct-secret-hide")
    assert not page.is_visible("#acct-secret")

    row = page.locator(f"#acct-table tr[data-name='{NEW}']")
    # role: viewer -> approver, after a confirmation
    row.locator("select").select_option("approver")
    _confirm(page)
    page.wait_for_selector("#acct-message:has-text('is now approver')", timeout=WAIT_MS)
    assert _row(server, NEW)["role"] == "approver"

    # a password the admin types; the old one stops working
    row.locator("button[data-act='password']").click()
    page.wait_for_selector("#confirm-dialog[open]", timeout=WAIT_MS)
    assert page.get_attribute("#confirm-password", "type") == "password"
    page.fill("#confirm-password", "  typed by the admin ")
    _confirm(page)
    page.wait_for_selector("#acct-message:has-text('New password set')", timeout=WAIT_MS)
    assert server.call("POST", "/api/session", {"name": NEW, "password": made})[0] == 401
    assert server.call("POST", "/api/session", {"name": NEW, "password": "  typed by the admin "})[0] == 200

    # an API token, shown once, then revoked
    row.locator("button[data-act='token']").click()
    _confirm(page)
    page.wait_for_selector("#acct-secret:visible", timeout=WAIT_MS)
    assert page.inner_text("#acct-secret-value").startswith("ist_")
    page.wait_for_selector(f"#acct-table tr[data-name='{NEW}'] button[data-act='revoke']", timeout=WAIT_MS)
    assert _row(server, NEW)["tokens"] == 1
    row.locator("button[data-act='revoke']").click()
    _confirm(page)
    page.wait_for_selector("#acct-message:has-text('Revoked 1 API token')", timeout=WAIT_MS)

    # disable, then enable
    row.locator("button[data-act='disable']").click()
    _confirm(page)
    page.wait_for_selector(f"#acct-table tr[data-name='{NEW}'][data-state='disabled']", timeout=WAIT_MS)
    assert server.call("POST", "/api/session", {"name": NEW, "password": "  typed by the admin "})[0] == 401
    shots(page, artifacts, "accounts_page_disabled")
    page.locator(f"#acct-table tr[data-name='{NEW}'] button[data-act='enable']").click()
    page.wait_for_selector(f"#acct-table tr[data-name='{NEW}'][data-state='active']", timeout=WAIT_MS)
    assert server.call("POST", "/api/session", {"name": NEW, "password": "  typed by the admin "})[0] == 200
    status, events = server.call("GET", "/api/events?limit=200")
    said = " ".join(e["message"] for e in (events["events"] if isinstance(events, dict) else events))
    assert f"account {NEW} disabled" in said and f"by {ADMIN[0]}" in said
    assert made not in str(events)


def test_an_operator_sees_no_accounts_page(server, open_page, artifacts):
    page, _ = open_page(f"{server.url}/#/accounts", width=1366, height=768, login=OPERATOR)
    page.wait_for_selector("#acct-who:has-text('only an admin manages accounts')", timeout=WAIT_MS)
    assert not page.is_visible("#nav-accounts")
    assert not page.is_visible("#acct-admin")
    assert page.locator("#acct-table tbody tr").count() == 0
    shots(page, artifacts, "accounts_page_operator")
