"""A short schemathesis run over the OpenAPI schema: whatever a client sends, never a 5xx."""

from __future__ import annotations

import atexit
import shutil
import tempfile
from pathlib import Path

import pytest

schemathesis = pytest.importorskip("schemathesis")
from conftest import AUTH, make_settings  # noqa: E402
from hypothesis import HealthCheck, settings  # noqa: E402
from schemathesis.checks import not_a_server_error  # noqa: E402

from backend.app import create_app  # noqa: E402

_DATA = Path(tempfile.mkdtemp(prefix="isorig-fuzz-"))
atexit.register(shutil.rmtree, _DATA, ignore_errors=True)
APP = create_app(make_settings(_DATA))
schema = schemathesis.openapi.from_asgi("/openapi.json", APP)


@pytest.fixture(scope="module", autouse=True)
def _stop_worker_after_fuzz():
    yield
    APP.state.service.shutdown()  # a fuzzed start may have launched a test


@schema.parametrize()
@settings(max_examples=12, deadline=None, suppress_health_check=list(HealthCheck), derandomize=True)
def test_no_server_errors(case):
    case.call_and_validate(headers=AUTH, checks=[not_a_server_error])
