"""Settings for the whole test suite, made before any test module (or backend module) is imported."""

from __future__ import annotations

import os

# TEST ONLY (backend.accounts.TEST_CHEAP_HASHES_ENV): cheap argon2id password hashes. Every service a test starts
# hashes its first admin's password, and the account tests add and log in people by the hundred: at argon2-cffi's
# defaults (~0.2 s of CPU, four threads, each) that was a large share of the backend tests' time. Inherited by the
# services and commands the tests start as processes. `ISORIG_TEST_ONLY_CHEAP_PASSWORD_HASHES= scripts/test.sh`
# (set, empty) runs the suite with production hashes; test_login_throttle.py uses them whatever this says.
os.environ.setdefault("ISORIG_TEST_ONLY_CHEAP_PASSWORD_HASHES", "1")
