"""Accounts and roles (backend.accounts, backend.auth, backend/api/login.py): logins with cookies, API tokens,
the role each endpoint needs, who every event names."""

from __future__ import annotations

import pytest
from conftest import AUTH, make_settings, sine_test, wait_for
from fastapi.testclient import TestClient

from backend import accounts
from backend.app import create_app

PASSWORD = "correct horse battery"
ISOLATOR = {"name": "x_iso", "rho_bw_per_m": 100, "sigma_bw": 0.5, "n": 1, "kd_n_per_m": 1e6, "kw_n": 1e4}


def add(client, name: str, role: str, password: str | None = PASSWORD) -> None:
    with client.app.state.sessions() as session:
        accounts.add_user(session, name, role, password)
        session.commit()


def token_of(client, name: str) -> dict:
    with client.app.state.sessions() as session:
        token = accounts.new_token(session, name)
        session.commit()
    return {"Authorization": f"Bearer {token}"}


def log_in(client, name: str, password: str = PASSWORD):
    return client.post("/api/session", json={"name": name, "password": password})


@pytest.fixture
def people(client):
    for name, role in (("vera", "viewer"), ("otto", "operator"), ("anna", "approver"), ("adam", "admin")):
        add(client, name, role)
    return client


def test_first_start_creates_an_admin_and_tells_only_the_terminal_where_its_password_is(tmp_path, capsys):
    with TestClient(create_app(make_settings(tmp_path))) as c:
        said = capsys.readouterr().err
        path = tmp_path / accounts.FIRST_PASSWORD_FILE  # 0600, the password never on the terminal (issue 33)
        assert f"created the account 'admin' (role admin); its password is in {path}" in said
        password = path.read_text().strip()
        assert password not in said
        r = log_in(c, "admin", password)
        assert r.status_code == 200 and r.json() == {"name": "admin", "role": "admin", "via": "session"}
        # a wrong credential's answer never says where a secret lives
        r = c.post("/api/tests", json=sine_test(), headers={"Authorization": "Bearer wrong"})
        assert r.status_code == 401 and str(tmp_path) not in r.text and "operator-token" not in r.text
    with TestClient(create_app(make_settings(tmp_path))) as c:  # the second start creates nothing, says nothing
        assert "created the account" not in capsys.readouterr().err
        assert log_in(c, "admin", password).status_code == 200


def test_a_login_is_an_httponly_strict_cookie_that_ends_on_logout(people):
    c = people
    r = log_in(c, "otto")
    assert r.status_code == 200, r.text
    cookie = r.headers["set-cookie"].lower()
    assert "isorig_session=iss_" in cookie and "httponly" in cookie and "samesite=strict" in cookie
    assert "path=/" in cookie and "max-age=43200" in cookie
    secret = c.cookies.get("isorig_session")
    assert c.get("/api/session").json() == {"name": "otto", "role": "operator", "via": "session"}
    created = c.post("/api/tests", json=sine_test())
    assert created.status_code == 201, created.text
    assert created.json()["operator_name"] == "otto"
    assert c.get(f"/api/tests/{created.json()['id']}").json()["events"][0]["actor"] == "otto"
    assert c.delete("/api/session").status_code == 204
    assert c.get("/api/session").json()["name"] is None
    c.cookies.set("isorig_session", secret)  # the old cookie, replayed after the logout: ended on the server
    r = c.post("/api/tests", json=sine_test())
    assert r.status_code == 401 and "your login has ended" in r.json()["detail"]


def test_wrong_passwords_are_refused_alike_and_throttled(people):
    c = people
    for name in ("otto", "nobody_here"):  # an unknown name and a wrong password read the same
        r = log_in(c, name, "not the password")
        assert r.status_code == 401 and r.json()["detail"].startswith("wrong name or password")
    for _ in range(4):
        assert log_in(c, "otto", "not the password").status_code == 401
    r = log_in(c, "otto")  # five failures for otto in five minutes: even the right password waits
    assert r.status_code == 429 and int(r.headers["retry-after"]) > 0 and "try again in" in r.json()["detail"]


def test_a_disabled_account_stops_acting_at_once(people):
    c = people
    headers = token_of(c, "otto")
    assert log_in(c, "otto").status_code == 200
    assert c.post("/api/isolators", json=ISOLATOR, headers=headers).status_code == 201
    with c.app.state.sessions() as session:
        accounts.disable_user(session, "otto")
        session.commit()
    assert c.post("/api/isolators", json={**ISOLATOR, "name": "y_iso"}, headers=headers).status_code == 401
    assert c.post("/api/isolators", json={**ISOLATOR, "name": "y_iso"}).status_code == 401  # the cookie too
    c.cookies.clear()
    assert log_in(c, "otto").status_code == 401


def test_api_tokens_are_stored_hashed_and_can_be_revoked(people):
    c = people
    headers = token_of(c, "otto")
    token = headers["Authorization"].split()[1]
    with c.app.state.sessions() as session:
        stored = [cred.secret_sha256 for cred in session.query(accounts.Credential)]
    assert token not in stored and all(len(s) == 64 for s in stored)
    assert c.get("/api/session", headers=headers).json() == {"name": "otto", "role": "operator", "via": "token"}
    with c.app.state.sessions() as session:
        assert accounts.revoke_tokens(session, "otto") == 1
        session.commit()
    assert c.post("/api/isolators", json=ISOLATOR, headers=headers).status_code == 401


def test_ended_logins_are_deleted_and_live_ones_and_tokens_kept(people):
    from datetime import timedelta

    from backend.models import utcnow

    c = people
    token = token_of(c, "otto")
    assert log_in(c, "otto").status_code == 200
    live = c.cookies.get("isorig_session")
    for _ in range(3):  # three more logins, then each ended: one expired, one logged out long ago, one just now
        assert log_in(c, "anna").status_code == 200
    with c.app.state.sessions() as session:
        sessions = session.query(accounts.Credential).filter_by(kind="session").order_by(accounts.Credential.id).all()
        assert len(sessions) == 4
        sessions[1].expires_at = utcnow() - timedelta(seconds=1)
        sessions[2].revoked_at = utcnow() - accounts.SESSION_LIFETIME - timedelta(minutes=1)
        sessions[3].revoked_at = utcnow()
        session.commit()
    assert log_in(c, "vera").status_code == 200  # a login purges what can never be used again
    with c.app.state.sessions() as session:
        kinds = sorted(cred.kind for cred in session.query(accounts.Credential))
    assert kinds == ["session", "session", "session", "token"]  # otto's live one, the one just ended, vera's
    c.cookies.set("isorig_session", live)
    assert c.get("/api/session").json()["name"] == "otto"
    assert c.get("/api/session", headers=token).json()["via"] == "token"


def test_a_person_cannot_record_another_name(people):
    c = people
    assert log_in(c, "otto").status_code == 200
    r = c.post("/api/tests", json=sine_test(operator_name="alice"))
    assert r.status_code == 422 and r.json()["field"] == "operator_name" and "otto" in r.json()["detail"]
    assert c.post("/api/tests", json=sine_test(operator_name="otto")).status_code == 201
    # the service account (ISORIG_OPERATOR_TOKEN) keeps the name a lab's script gives, beside its own
    c.cookies.clear()
    r = c.post("/api/tests", json=sine_test(operator_name="bob"), headers=AUTH)
    assert r.json()["operator_name"] == "bob (through automation)"
    assert r.json()["events"][0]["actor"] == "automation"


def test_stop_and_abort_stay_open_and_name_the_account(people):
    c = people
    r = c.post("/api/tests?start=true", json=sine_test(profile={"cycles": 200}, speed=1.0), headers=AUTH)
    test_id = r.json()["id"]
    assert log_in(c, "vera").status_code == 200  # a viewer may end a test: it only takes energy out of the rig
    assert c.post(f"/api/tests/{test_id}/abort").status_code == 200
    rec = wait_for(c, test_id)
    asked = [e for e in rec["events"] if (e["values"] or {}).get("action") == "abort"]
    assert asked[0]["actor"] == "vera", asked


# ------------------------------------------------------------------------------------- the role of every endpoint

# the smallest role each endpoint needs; None: open to anyone who reaches the console (reads, checks, login)
ROLE_OF = {
    ("POST", "/api/tests"): "operator",
    ("POST", "/api/tests/{test_id}/start"): "operator",
    ("DELETE", "/api/tests/{test_id}"): "operator",
    ("POST", "/api/tests/{test_id}/archive"): "operator",
    ("POST", "/api/tests/{test_id}/restore"): "operator",
    ("POST", "/api/isolators"): "operator",
    ("DELETE", "/api/isolators/{name}"): "operator",
    ("POST", "/api/rig/move"): "operator",
    ("POST", "/api/rig/zero"): "operator",
    ("POST", "/api/commissioning"): "operator",
    ("POST", "/api/commissioning/{test_id}/apply"): "operator",
    ("POST", "/api/tests/{test_id}/approve"): "approver",
    ("POST", "/api/tests/{test_id}/reject"): "approver",
    ("PUT", "/api/lab"): "admin",
    ("POST", "/api/accounts"): "admin",
    ("PUT", "/api/accounts/{name}/role"): "admin",
    ("POST", "/api/accounts/{name}/password"): "admin",
    ("POST", "/api/accounts/{name}/disable"): "admin",
    ("POST", "/api/accounts/{name}/enable"): "admin",
    ("POST", "/api/accounts/{name}/tokens"): "admin",
    ("DELETE", "/api/accounts/{name}/tokens"): "admin",
    ("PUT", "/api/lab/logo"): "admin",
    ("PUT", "/api/acceptance/tolerances/{protocol}"): "admin",
    ("DELETE", "/api/acceptance/tolerances/{protocol}"): "admin",
    ("POST", "/api/tests/{test_id}/stop"): None,  # ending a test: anyone (an emergency stop)
    ("POST", "/api/tests/{test_id}/abort"): None,
    ("POST", "/api/tests/check"): None,
    ("POST", "/api/commissioning/check"): None,
    ("POST", "/api/ground-motions/read-at2"): None,
    ("POST", "/api/session"): None,
    ("DELETE", "/api/session"): None,
}


def endpoints(client) -> list[tuple[str, str]]:
    schema = client.get("/openapi.json").json()
    return [(method.upper(), path) for path, ops in schema["paths"].items() for method in ops]


def test_every_endpoint_has_a_role_rule(client):
    """A new endpoint that changes anything must be entered in ROLE_OF (and so tested below)."""
    for method, path in endpoints(client):
        if method != "GET":
            assert (method, path) in ROLE_OF, f"{method} {path} has no role rule in ROLE_OF"


def _call(client, method: str, path: str, headers: dict):
    concrete = path.replace("{test_id}", "1").replace("{name}", "x_iso").replace("{protocol}", "quick_check")
    body = {"POST": ISOLATOR if path == "/api/isolators" else {}, "PUT": {"data_base64": None}}.get(method)
    return client.request(method, concrete, json=body, headers=headers)


@pytest.mark.parametrize("role", ["viewer", "operator", "approver", "admin"])
def test_each_role_is_refused_exactly_what_it_may_not_do(people, role):
    """Every mutating endpoint, called by each role: below its rule 403 (or 401 for nobody), never run; at or
    above it, never refused for the role (it may still fail on its body or the record's state, 404/409/422, or
    because this account ran the test it would approve, 403)."""
    c = people
    name = {"viewer": "vera", "operator": "otto", "approver": "anna", "admin": "adam"}[role]
    headers = token_of(c, name)
    c.post("/api/tests", json=sine_test(), headers=AUTH)  # test 1 exists, ready
    rank = accounts.ROLES.index(role)
    for (method, path), needed in ROLE_OF.items():
        if path == "/api/session":
            continue
        r = _call(c, method, path, headers)
        if needed is not None and accounts.ROLES.index(needed) > rank:
            assert r.status_code == 403, (role, method, path, r.status_code, r.text)
            assert f"needs the role {needed}" in r.json()["detail"]
        else:  # allowed: may still be refused for who ran the test (approve) or the record's state, never the role
            assert r.status_code != 401 and "needs the role" not in r.text, (role, method, path, r.status_code, r.text)
        nobody = _call(c, method, path, {})
        if needed is not None:
            assert nobody.status_code == 401, (method, path, nobody.status_code)
    if rank < accounts.ROLES.index("operator"):
        assert c.get("/api/tests/1").json()["status"] == "ready"  # nothing moved


def test_reads_are_open(people):
    c = people
    c.post("/api/tests", json=sine_test(), headers=AUTH)
    for method, path in endpoints(c):
        if method == "GET" and "{" not in path and path != "/api/accounts":  # (accounts: admins; no logo: 404)
            assert c.get(path).status_code == (404 if path == "/api/lab/logo" else 200), path
