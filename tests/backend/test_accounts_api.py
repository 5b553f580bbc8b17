"""The accounts routes (backend/api/accounts.py, issue 34 item 4): what `isorig user` does, for an admin in the
console; secrets answered once and never logged; an admin cannot lock themselves out; every change in the audit
log; a page on another site sends nothing."""

from __future__ import annotations

import pytest
from test_accounts import PASSWORD, add, log_in, token_of

from backend import accounts


@pytest.fixture
def admin(client):
    add(client, "adam", "admin")
    add(client, "otto", "operator")
    assert log_in(client, "adam").status_code == 200
    return client


def test_only_an_admin_lists_the_accounts(client):
    add(client, "otto", "operator")
    assert client.get("/api/accounts").status_code == 401
    r = client.get("/api/accounts", headers=token_of(client, "otto"))
    assert r.status_code == 403 and "needs the role admin" in r.json()["detail"]


def test_an_admin_adds_an_account_that_then_logs_in(admin):
    c = admin
    r = c.post("/api/accounts", json={"name": "bea", "role": "approver", "password": "a long password"})
    assert r.status_code == 201, r.text
    assert r.json()["password"] is None and r.json()["account"]["state"] == "active"
    listed = {a["name"]: a for a in c.get("/api/accounts").json()["accounts"]}
    assert listed["bea"]["role"] == "approver" and listed["adam"]["logins"] == 1
    assert "password_hash" not in str(listed)
    c.cookies.clear()
    assert log_in(c, "bea", "a long password").json()["role"] == "approver"


def test_a_password_left_out_is_made_and_answered_once_never_logged(admin):
    c = admin
    r = c.post("/api/accounts", json={"name": "carl", "role": "operator"})
    assert r.status_code == 201
    made = r.json()["password"]
    assert len(made) >= accounts.PASSWORD_MIN_CHARS and r.headers["cache-control"] == "no-store"
    again = c.post("/api/accounts/carl/password", json={})
    second = again.json()["password"]
    assert second and second != made
    events = c.get("/api/events").json()
    text = str(events)
    assert made not in text and second not in text
    said = [e["message"] for e in (events["events"] if isinstance(events, dict) else events)]
    assert "account carl added (operator) by adam" in said
    assert "new password set for carl; its logins ended by adam" in said
    c.cookies.clear()
    assert log_in(c, "carl", made).status_code == 401
    assert log_in(c, "carl", second).status_code == 200


def test_bad_input_is_a_clear_422_naming_the_field_and_never_echoes_a_password(admin):
    c = admin
    cases = [({"name": "bad name!", "role": "operator"}, "name"), ({"name": "dora", "role": "boss"}, "role"),
             ({"name": "dora", "role": "operator", "password": "short"}, "password")]
    for body, field in cases:
        r = c.post("/api/accounts", json=body)
        assert r.status_code == 422, r.text
        assert r.json()["field"] == field and "short" not in str(r.json().get("value"))
    assert "at least 10 characters" in c.post("/api/accounts/otto/password", json={"password": "tiny"}).json()["detail"]
    assert c.post("/api/accounts", json={"name": "otto", "role": "viewer"}).status_code == 409
    assert c.post("/api/accounts", json={"name": "x", "role": "viewer", "extra": 1}).status_code == 422
    assert c.post("/api/accounts/nobody/disable").status_code == 404
    assert c.put("/api/accounts/otto/role", json={"role": "god"}).json()["field"] == "role"


def test_disable_role_and_tokens_act_at_once(admin):
    c = admin
    token = c.post("/api/accounts/otto/tokens").json()["token"]
    as_otto = {"Authorization": f"Bearer {token}"}
    assert c.get("/api/accounts", headers=as_otto).status_code == 403  # an operator
    assert c.put("/api/accounts/otto/role", json={"role": "admin"}).json()["account"]["role"] == "admin"
    assert c.get("/api/accounts", headers=as_otto).status_code == 200  # the new role, at once
    assert c.post("/api/accounts/otto/disable").json()["account"]["state"] == "disabled"
    assert c.get("/api/accounts", headers=as_otto).status_code == 401  # its token ended with it
    assert c.post("/api/accounts/otto/tokens").status_code == 409  # no token for a disabled account
    assert c.post("/api/accounts/otto/enable").json()["account"]["state"] == "active"
    assert c.get("/api/accounts", headers=as_otto).status_code == 401  # enabling does not bring tokens back
    c.post("/api/accounts/otto/tokens")
    assert c.delete("/api/accounts/otto/tokens").json()["revoked"] == 1


def test_an_admin_cannot_lock_themselves_out(admin):
    c = admin
    for method, path, body in (("POST", "/api/accounts/adam/disable", None),
                               ("PUT", "/api/accounts/adam/role", {"role": "viewer"})):
        r = c.request(method, path, json=body)
        assert r.status_code == 409 and "your own account" in r.json()["detail"], r.text
    assert c.get("/api/accounts").status_code == 200  # still an admin, still logged in


def test_a_foreign_page_cannot_add_an_account_with_the_admins_cookie(admin):
    c = admin
    for headers in ({"Origin": "http://evil.example"}, {"Sec-Fetch-Site": "cross-site"}):
        r = c.post("/api/accounts", json={"name": "mallory", "role": "admin", "password": PASSWORD}, headers=headers)
        assert r.status_code == 403, r.text
    r = c.post("/api/accounts", content=b'{"name":"mallory","role":"admin"}', headers={"Content-Type": "text/plain"})
    assert r.status_code == 415
    assert "mallory" not in str(c.get("/api/accounts").json())
