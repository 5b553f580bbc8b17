"""Password hashes (backend.accounts.password_hasher): argon2-cffi's defaults in production; the test suite's cheap
ones only when ISORIG_TEST_ONLY_CHEAP_PASSWORD_HASHES is 1 (tests/conftest.py), refused for any other value, and
never written over a stored production hash."""

from __future__ import annotations

import os

import pytest
from argon2 import PasswordHasher
from conftest import make_settings
from fastapi.testclient import TestClient

from backend import accounts
from backend.app import create_app

PASSWORD = "correct horse battery"


def _parameters(hasher: PasswordHasher) -> tuple:
    return hasher.time_cost, hasher.memory_cost, hasher.parallelism, hasher.hash_len, hasher.salt_len, hasher.type


def test_production_hashes_are_argon2_cffis_defaults_unless_the_suite_asks():
    default = PasswordHasher()
    assert default.time_cost >= 3 and default.memory_cost >= 64 * 1024  # argon2-cffi's defaults, RFC 9106's second
    for environ in ({}, {accounts.TEST_CHEAP_HASHES_ENV: ""}, {"ISORIG_OPERATOR_TOKEN": "x"}):
        assert _parameters(accounts.password_hasher(environ)) == _parameters(default), environ
    cheap = accounts.password_hasher({accounts.TEST_CHEAP_HASHES_ENV: "1"})
    assert cheap.memory_cost < default.memory_cost and cheap.time_cost <= default.time_cost
    cheap.verify(cheap.hash(PASSWORD), PASSWORD)


@pytest.mark.parametrize("value", ["0", "yes", "true", " 1", "2"])
def test_any_other_value_of_the_test_knob_is_refused(value):
    with pytest.raises(RuntimeError, match="test suite only"):
        accounts.password_hasher({accounts.TEST_CHEAP_HASHES_ENV: value})


def test_the_suite_names_the_variable_backend_accounts_reads():
    """tests/conftest.py sets the variable backend.accounts reads (else every test pays ~0.2 s a hash again)."""
    assert accounts.TEST_CHEAP_HASHES_ENV in os.environ
    assert _parameters(accounts._hasher) == _parameters(accounts.password_hasher(os.environ))


def _stored_hash(client, name: str) -> str:
    with client.app.state.sessions() as session:
        return accounts.get_user(session, name).password_hash


def _log_in(client, name: str) -> None:
    assert client.post("/api/session", json={"name": name, "password": PASSWORD}).status_code == 200


def test_a_login_rehashes_up_to_production_and_never_down_to_the_cheap_hashes(tmp_path, monkeypatch):
    production = PasswordHasher()
    cheap = accounts.password_hasher({accounts.TEST_CHEAP_HASHES_ENV: "1"})
    with TestClient(create_app(make_settings(tmp_path))) as c:
        monkeypatch.setattr(accounts, "_hasher", cheap)
        with c.app.state.sessions() as session:
            accounts.add_user(session, "cora", "operator", PASSWORD)
            accounts.add_user(session, "paul", "operator", PASSWORD)
            accounts.get_user(session, "paul").password_hash = production.hash(PASSWORD)
            session.commit()
        kept = _stored_hash(c, "paul")
        _log_in(c, "paul")  # a cheap hasher leaves a production hash as it is
        assert _stored_hash(c, "paul") == kept
        monkeypatch.setattr(accounts, "_hasher", production)
        _log_in(c, "cora")  # production rehashes a cheaper hash at its next login
        assert not production.check_needs_rehash(_stored_hash(c, "cora"))
        _log_in(c, "cora")


def test_a_service_with_the_cheap_hashes_says_so_and_one_without_says_nothing():
    from isorig.commands.serve import cheap_hash_warning

    warning = cheap_hash_warning({accounts.TEST_CHEAP_HASHES_ENV: "1"})
    assert accounts.TEST_CHEAP_HASHES_ENV in warning and "unset it" in warning and "WARNING" in warning
    assert cheap_hash_warning({}) is None
    assert cheap_hash_warning({accounts.TEST_CHEAP_HASHES_ENV: ""}) is None
