"""The service token (ISORIG_OPERATOR_TOKEN, the account 'automation'): required to act without a login; no
shared token exists without it. Accounts and roles: test_accounts.py."""

from __future__ import annotations

import pytest
from conftest import AUTH, make_settings, sine_test
from fastapi.testclient import TestClient

from backend.app import create_app

MUTATING = [
    ("post", "/api/tests", sine_test()),
    ("post", "/api/isolators", {"name": "x", "rho_bw_per_m": 100, "sigma_bw": 0.5, "n": 1, "kd_n_per_m": 1e6,
                                "kw_n": 1e4}),
    ("post", "/api/tests/1/start", None),
    ("delete", "/api/tests/1", None),
]


def test_without_the_service_token_no_shared_token_acts_and_none_is_written(tmp_path):
    settings = make_settings(tmp_path, operator_token=None)
    with TestClient(create_app(settings)) as c:
        assert not (tmp_path / "operator-token").exists()  # the shared token file of old is retired
        assert c.post("/api/tests", json=sine_test(), headers=AUTH).status_code == 401
        assert c.post("/api/tests", json=sine_test(), headers={"Authorization": "Bearer "}).status_code == 401


@pytest.mark.parametrize(("method", "path", "body"), MUTATING)
def test_mutating_endpoints_need_the_token(client, method, path, body):
    client.post("/api/tests", json=sine_test(), headers=AUTH)  # test 1 exists
    kwargs = {"json": body} if body is not None else {}
    for headers in ({}, {"Authorization": "Bearer wrong"}, {"Authorization": "Basic dXNlcjpwdw=="}):
        r = getattr(client, method)(path, headers=headers, **kwargs)
        assert r.status_code == 401, (path, headers, r.text)
        assert "needs an account with the role operator" in r.json()["detail"] or "not valid" in r.json()["detail"]
        assert r.headers.get("www-authenticate") == "Bearer"
    assert client.get("/api/tests/1").json()["status"] == "ready"  # nothing moved


def test_read_only_endpoints_need_no_token(client):
    client.post("/api/tests", json=sine_test(), headers=AUTH)
    for path in ("/api/health", "/api/rig", "/api/isolators", "/api/isolators/IUT_a", "/api/tests", "/api/tests/1",
                 "/api/tests/1/cycles", "/api/tests/1/data.csv", "/api/events", "/openapi.json"):
        assert client.get(path).status_code == 200, path


def test_no_cors_by_default(client):
    r = client.options("/api/tests", headers={"Origin": "http://evil.example", "Access-Control-Request-Method": "POST"})
    assert "access-control-allow-origin" not in r.headers
    r = client.get("/api/health", headers={"Origin": "http://evil.example"})
    assert "access-control-allow-origin" not in r.headers


@pytest.mark.parametrize("action", ["stop", "abort"])
def test_a_running_test_is_ended_by_anyone_and_who_asked_is_recorded(client, action):
    """Stop and abort are never refused for a missing or wrong token (an emergency stop on a second console, a
    stale token in a browser): the test ends, and the event names who asked (the address without a token)."""
    from conftest import wait_for, zero_table

    for headers in ({}, {"Authorization": "Bearer wrong"}, AUTH):
        r = client.post("/api/tests?start=true", json=sine_test(profile={"cycles": 200}, speed=1.0), headers=AUTH)
        assert r.status_code == 201, r.text
        test_id = r.json()["id"]
        ended = client.post(f"/api/tests/{test_id}/{action}", headers=headers)
        assert ended.status_code == 200, ended.text
        rec = wait_for(client, test_id)
        assert rec["status"] == ("stopped" if action == "stop" else "aborted"), rec
        asked = [e for e in rec["events"] if (e["values"] or {}).get("action") == action]
        who = "automation" if headers is AUTH else "a console without login (testclient)"
        assert asked[0]["actor"] == who and asked[0]["message"] == f"{action} requested by {who}", asked
        zero_table(client)  # an abort leaves the table where it was
