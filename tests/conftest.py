"""Settings for the whole test suite, made before any test module (or backend module) is imported."""

from __future__ import annotations

import os

import pytest

# TEST ONLY (backend.accounts.TEST_CHEAP_HASHES_ENV): cheap argon2id password hashes. Every service a test starts
# hashes its first admin's password, and the account tests add and log in people by the hundred: at argon2-cffi's
# defaults (~0.2 s of CPU, four threads, each) that was a large share of the backend tests' time. Inherited by the
# services and commands the tests start as processes. `ISORIG_TEST_ONLY_CHEAP_PASSWORD_HASHES= scripts/test.sh`
# (set, empty) runs the suite with production hashes; test_login_throttle.py uses them whatever this says.
os.environ.setdefault("ISORIG_TEST_ONLY_CHEAP_PASSWORD_HASHES", "1")

#: every test this session collected (node id: marker names), before -m, -k or xdist chose which run here; set only
#: when the session collected the whole suite (pyproject's testpaths, nothing ignored), else absent
WHOLE_SUITE = pytest.StashKey[dict]()


@pytest.hookimpl(tryfirst=True)
def pytest_collection_modifyitems(session, config, items):
    """Keep the whole suite's collection for tests/test_quick_tier.py, which otherwise collects it again in a
    process of its own (35 s of CPU on a loaded machine)."""
    whole = (config.args_source == pytest.Config.ArgsSource.TESTPATHS and not config.getoption("ignore")
             and not config.getoption("ignore_glob") and not config.getoption("lf", False))
    if whole:
        config.stash[WHOLE_SUITE] = {item.nodeid: sorted({m.name for m in item.iter_markers()}) for item in items}


@pytest.fixture(scope="session")
def whole_suite(pytestconfig) -> dict | None:
    """The whole suite's tests as this session collected them (node id: marker names), or None if it did not."""
    return pytestconfig.stash.get(WHOLE_SUITE, None)
