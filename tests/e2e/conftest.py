"""Fixtures of the browser tests: one `isorig serve` per session, chromium, watched pages.

The service has the 3D view on (viser starts only when a page asks for /viewer/); pages open with
``?viewer=off`` unless a test wants the 3D view, so software WebGL does not slow the other tests.

Every page records its request URLs, console errors and page errors; a test fails if any request leaves the
machine or the console shows an error. Screenshots go to artifacts/e2e/ (git-ignored).
"""

from __future__ import annotations

import time
from pathlib import Path

import pytest

from .harness import ARTIFACTS, PageWatch, Server, chromium_available, launch, log_in, watch_rejections

try:
    from playwright import sync_api as playwright_api
except ImportError:  # pragma: no cover - the [test] extra installs it
    playwright_api = None

if playwright_api is None:
    MISSING = "the Python package playwright is not installed (pip install -e '.[test]')"
elif not chromium_available():  # pragma: no cover - scripts/test.sh installs it
    MISSING = "Debian's chromium is missing (apt-get install -y chromium; scripts/test.sh does it)"
else:
    MISSING = None
HERE = Path(__file__).resolve().parent


def pytest_collection_modifyitems(config, items):
    """Skip the browser tests, saying why, where the browser or Playwright is missing."""
    if MISSING is None:
        return
    for item in items:
        if HERE in Path(str(item.fspath)).resolve().parents:
            item.add_marker(pytest.mark.skip(reason=MISSING))


@pytest.fixture(scope="session")
def server(tmp_path_factory):
    srv = Server(tmp_path_factory.mktemp("serve"), viewer=True).start()
    yield srv
    srv.stop()


@pytest.fixture(scope="session")
def browser():
    with playwright_api.sync_playwright() as p:
        b = launch(p)
        yield b
        b.close()


@pytest.fixture(scope="session")
def artifacts():
    ARTIFACTS.mkdir(parents=True, exist_ok=True)
    return ARTIFACTS


@pytest.fixture
def open_page(browser):
    """open_page(url) -> (page, watch); the page's console and requests are checked when the test ends."""
    opened = []

    def _open(url: str, width: int = 1500, height: int = 1000, login: tuple[str, str] | None = None,
              viewer: bool = False, cookie: str | None = None):
        """``login`` (name, password): the page opens logged in; ``cookie``: a login cookie of its own (stale)."""
        url += ("&" if "?" in url else "?") + ("viewer=on" if viewer else "viewer=off")
        context = browser.new_context(viewport={"width": width, "height": height}, accept_downloads=True)
        watch_rejections(context)
        page = context.new_page()
        watch = PageWatch(page)
        origin = "/".join(url.split("/")[:3])
        if login is not None:
            log_in(context, origin, login)
        if cookie is not None:
            context.add_cookies([{"name": "isorig_session", "value": cookie, "url": origin}])
        page.goto(url)
        page.wait_for_selector("body[data-ready='1']", timeout=15000)
        opened.append((context, page, watch))
        return page, watch

    yield _open
    problems = []
    for context, _page, watch in opened:
        if watch.foreign():
            problems.append(f"requests to another host: {watch.foreign()}")
        if watch.unexpected_errors():
            problems.append(f"console errors: {watch.unexpected_errors()}")
        context.close()
    assert not problems, "; ".join(problems)


@pytest.fixture(autouse=True)
def table_at_zero(request):
    """Every test that uses the shared service begins with its table at zero, as an operator brings it back
    after a trip or an abort: the service refuses a start while the table rests off zero (docs/backend.md)."""
    if "server" not in request.fixturenames:
        yield
        return
    srv = request.getfixturevalue("server")
    deadline = time.monotonic() + 60
    while srv.call("GET", "/api/rig/state")[1].get("status") != "idle" and time.monotonic() < deadline:
        time.sleep(0.2)
    srv.zero_table()
    yield
