"""Shared helpers of the browser tests and the dashboard benchmark: run `isorig serve`, drive Debian's chromium.

The service runs on a free loopback port with a temporary SQLite database, the service token (ISORIG_OPERATOR_TOKEN,
the account 'automation') for the tests' own API calls, and an operator account the browser logs in as.
Chromium is Debian's (/usr/bin/chromium, `apt-get install -y chromium`); Playwright's own browser download is
not used.
"""

from __future__ import annotations

import json
import os
import re
import shutil
import signal
import socket
import subprocess
import sys
import threading
import time
import urllib.error
import urllib.request
from pathlib import Path
from urllib.parse import urlparse

REPO = Path(__file__).resolve().parents[2]
ARTIFACTS = REPO / "artifacts" / "e2e"
CHROMIUM = os.environ.get("ISORIG_CHROMIUM", "/usr/bin/chromium")
CHROMIUM_ARGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking",
                 "--disable-component-update", "--disable-sync", "--no-first-run"]
TOKEN = "e2e-operator-token"  # the service account's token: the tests' own API calls
OPERATOR = ("e2e-operator", "e2e-operator-password")  # the account a browser logs in as (role operator)
# Upper bounds of the waits on the service or the page: a wait ends as soon as the state it waits for is there, so
# a loaded machine makes a test slower, never wrong; a state that never comes still fails it, after this long.
WAIT_MS = 30000  # a page state (Playwright's wait_for_selector / wait_for_function)
WAIT_S = 30.0  # the least that poll() waits
RECORD_WAIT_S = 60.0  # the least that Server.wait_status waits for a record's status
# the first envelope check after a service starts runs in its check pool, which warms up first (11.6 s measured
# under load 10 on 2 CPUs): a wait for it ends as soon as it has answered
FIRST_CHECK_MS = 120000
LOCAL_HOSTS = {"127.0.0.1", "localhost", "[::1]", "::1"}


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class Server:
    """`isorig serve` in a subprocess on 127.0.0.1 with its own database; restartable on the same port."""

    def __init__(self, workdir: Path, viewer: bool = False, port: int | None = None, rig: str | None = None,
                 plant_set: tuple[str, ...] = (), database_url: str | None = None, rig_name: str | None = None):
        self.workdir = Path(workdir)
        self.workdir.mkdir(parents=True, exist_ok=True)
        self.port = port or free_port()
        self.viewer = viewer
        self.rig = rig  # None: the service's default (simulated); or udp://HOST:PORT
        self.plant_set = tuple(plant_set)  # the simulated rig unlike its rig file (isorig serve --plant-set)
        self.database_url = database_url  # None: its own SQLite file; several rigs' services may share one
        self.rig_name = rig_name  # None: the service's default (rig-1)
        self.proc: subprocess.Popen | None = None
        self.log_path = self.workdir / "serve.log"

    @property
    def url(self) -> str:
        return f"http://127.0.0.1:{self.port}"

    def env(self) -> dict:
        env = dict(os.environ)
        env.update({
            "ISORIG_DATABASE_URL": self.database_url or f"sqlite:///{self.workdir / 'isorig.db'}",
            "ISORIG_DATA_DIR": str(self.workdir),
            "ISORIG_OPERATOR_TOKEN": TOKEN,
            "ISORIG_VIEWER": "1" if self.viewer else "0",
            # no report warm-up in the background (2.8 s of CPU a start; the few tests that render a report pay it
            # there): test_report_warm_up.py tests it
            "ISORIG_REPORT_WARM_UP": "false",
            "PYTHONUNBUFFERED": "1",
        })
        env.pop("ISORIG_RIG_NAME", None)
        if self.rig_name:
            env["ISORIG_RIG_NAME"] = self.rig_name
        return env

    def add_account(self, name: str, password: str, role: str = "operator") -> None:
        """An account in the service's database (as `isorig user add` makes it), if it is not there yet."""
        from backend import accounts, db

        engine = db.make_engine(self.env()["ISORIG_DATABASE_URL"])
        try:
            db.upgrade(engine)
            with db.session_factory(engine)() as session:
                if accounts.find_user(session, name) is None:
                    accounts.add_user(session, name, role, password)
                    session.commit()
        finally:
            engine.dispose()

    def start(self, timeout_s: float = 60.0) -> Server:
        self.add_account(*OPERATOR)
        log = open(self.log_path, "ab")
        rig = ["--rig", self.rig] if self.rig else []
        rig += [a for item in self.plant_set for a in ("--plant-set", item)]
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "isorig", "serve", "--host", "127.0.0.1", "--port", str(self.port), *rig],
            cwd=REPO, env=self.env(), stdout=log, stderr=subprocess.STDOUT, start_new_session=True)
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            if self.proc.poll() is not None:
                raise RuntimeError(f"isorig serve exited with {self.proc.returncode}:\n{self.log_tail()}")
            try:
                with urllib.request.urlopen(f"{self.url}/api/health", timeout=2) as r:
                    if r.status == 200:
                        return self
            except (urllib.error.URLError, ConnectionError, TimeoutError, OSError):
                pass
            time.sleep(0.2)
        self.stop()
        raise RuntimeError(f"isorig serve did not answer /api/health within {timeout_s} s:\n{self.log_tail()}")

    def stop(self, timeout_s: float = 15.0) -> None:
        if self.proc is None or self.proc.poll() is not None:
            return
        self.proc.send_signal(signal.SIGINT)
        try:
            self.proc.wait(timeout_s)
        except subprocess.TimeoutExpired:
            os.killpg(self.proc.pid, signal.SIGKILL)
            self.proc.wait(5)

    def log_tail(self, n: int = 40) -> str:
        try:
            return "\n".join(self.log_path.read_text(errors="replace").splitlines()[-n:])
        except OSError:
            return ""

    # --- REST helpers (stdlib only) ----------------------------------------------------------------------
    def call(self, method: str, path: str, body: dict | None = None, token: bool = False):
        data = json.dumps(body).encode() if body is not None else None
        req = urllib.request.Request(f"{self.url}{path}", data=data, method=method)
        if data is not None:
            req.add_header("Content-Type", "application/json")
        if token:
            req.add_header("Authorization", f"Bearer {TOKEN}")
        try:
            with urllib.request.urlopen(req, timeout=30) as r:
                raw = r.read()
                return r.status, (json.loads(raw) if raw else None)
        except urllib.error.HTTPError as e:
            raw = e.read()
            try:
                return e.code, json.loads(raw)
            except ValueError:
                return e.code, raw.decode(errors="replace")

    def start_test(self, body: dict) -> int:
        status, rec = self.call("POST", "/api/tests", body, token=True)
        assert status == 201, (status, rec)
        status, started = self.call("POST", f"/api/tests/{rec['id']}/start", token=True)
        assert status == 200, (status, started)
        return rec["id"]

    def zero_table(self) -> None:
        """Bring the table back to zero when it rests off it (POST /api/rig/zero), as an operator must before the
        next test: the service starts no test with the table more than 2 mm from zero."""
        _, state = self.call("GET", "/api/rig/state")
        position = state.get("table_position_m")
        if state.get("status") == "idle" and position is not None and abs(position) > 0.001:
            code, move = self.call("POST", "/api/rig/zero", {"speed_m_per_s": 0.05, "isolator": "IUT_b",
                                                             "supply_bar": 70}, token=True)
            assert code == 201, (code, move)
            self.wait_status(move["id"], {"completed"})

    def wait_status(self, test_id: int, statuses: set[str], timeout_s: float = RECORD_WAIT_S) -> dict:
        """The record once its status is one of ``statuses`` (GET /api/tests/{id}); waits at least RECORD_WAIT_S."""
        timeout_s = max(timeout_s, RECORD_WAIT_S)
        deadline = time.monotonic() + timeout_s
        rec = None
        while time.monotonic() < deadline:
            _, rec = self.call("GET", f"/api/tests/{test_id}")
            if rec and rec.get("status") in statuses:
                return rec
            time.sleep(0.2)
        raise AssertionError(f"test {test_id} not in {statuses} after {timeout_s} s: {rec}")


class RigEmulator:
    """`isorig rig-emulator` (an emulated real-time rig on UDP) on a free loopback port; ``url`` is its address."""

    def __init__(self, *flags: str, isolator: str = "IUT_a", port: int = 0, watchdog_ms: float = 100.0):
        """``flags``: more options of ``isorig rig-emulator`` (e.g. ``--restart-after-s 0.6``). The watchdog is
        longer than the rig's 18 ms default: these tests look at the console, with chromium, the service, its
        worker and the emulator sharing two cores, where a host stall of 18 ms ends a run; the watchdog itself
        is tested in tests/backend (test_udp_rig.py)."""
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "isorig", "rig-emulator", "--port", str(port), "--isolator", isolator,
             "--watchdog-ms", f"{watchdog_ms:g}", *flags],
            cwd=REPO, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True, start_new_session=True)
        line = self.proc.stderr.readline()  # "isorig rig-emulator: udp://127.0.0.1:PORT, ..."
        match = re.search(r"udp://([\d.]+):(\d+)", line)
        if match is None:
            self.stop()
            raise RuntimeError(f"isorig rig-emulator did not start: {line}")
        self.url = f"udp://127.0.0.1:{match.group(2)}"
        # keep reading its stderr so it never blocks on a full pipe
        threading.Thread(target=self.proc.stderr.read, daemon=True).start()

    def stop(self) -> None:
        if self.proc.poll() is None:
            self.proc.terminate()
            try:
                self.proc.wait(10)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait(5)


def sine_test(amplitude_m=0.03, frequency_hz=0.5, cycles=4, speed=2.0, isolator="IUT_b", supply_bar=70.0,
              controller="servo", taper_cycles=1) -> dict:
    """A test's body for POST /api/tests; the rig's default controller (servo), as the console's form."""
    return {"isolator": isolator, "supply_bar": supply_bar, "controller": controller, "speed": speed,
            "profile": {"kind": "sine", "amplitude_m": amplitude_m, "frequency_hz": frequency_hz,
                        "cycles": cycles, "taper_cycles": taper_cycles}}


def chromium_available() -> bool:
    return Path(CHROMIUM).exists() or shutil.which(CHROMIUM) is not None


def launch(playwright):
    return playwright.chromium.launch(executable_path=CHROMIUM, args=CHROMIUM_ARGS)


# An exception in an async function of the page is an unhandled promise rejection, which the browser does not
# report as a page error: said as a console error, so that it fails the test as any other error does.
REJECTIONS = ("window.addEventListener('unhandledrejection', (e) => console.error('unhandled rejection: ' + "
              "(e.reason && e.reason.stack ? e.reason.stack : e.reason)));")


def log_in(context, base_url: str, account: tuple[str, str]) -> None:
    """Log the browser context in (POST /api/session: its login cookie lands in the context)."""
    r = context.request.post(f"{base_url}/api/session", data={"name": account[0], "password": account[1]})
    assert r.ok, r.text()


def watch_rejections(context) -> None:
    """Every page of this browser context reports unhandled promise rejections as console errors."""
    context.add_init_script(REJECTIONS)


# the check pool's routes (backend.checks): a check, an .AT2 file read, an earthquake test's figures
BUSY_ROUTES = ("/api/tests/check", "/api/ground-motions/read-at2", "/earthquake?points=")


class PageWatch:
    """Records every request URL, console error and page error of a page (and its frames)."""

    RESOURCE_STATUS = re.compile(r"^Failed to load resource: the server responded with a status of (\d+)")

    def __init__(self, page):
        self.allowed_status: set[int] = set()  # HTTP errors a test provokes on purpose (e.g. 422 refusals)
        self.allowed_patterns: list[str] = []  # console errors a test expects (e.g. while the server is down)
        self.requests: list[str] = []
        self.console_errors: list[str] = []
        self.page_errors: list[str] = []
        self.busy: list[tuple[int, str]] = []  # 503 answers: the check pool's "busy, ask again" is expected
        page.on("request", lambda r: self.requests.append(r.url))
        page.on("response", lambda r: self.busy.append((r.status, r.url)) if r.status == 503 else None)
        page.on("websocket", lambda ws: self.requests.append(ws.url))
        page.on("console", lambda m: self.console_errors.append(m.text) if m.type == "error" else None)
        page.on("pageerror", lambda e: self.page_errors.append(str(e)))

    def unexpected_errors(self) -> list[str]:
        out = list(self.page_errors)
        for text in self.console_errors:
            m = self.RESOURCE_STATUS.match(text)
            if m and int(m.group(1)) in self.allowed_status:
                continue
            if m and m.group(1) == "503" and self.busy and all(any(route in url for route in BUSY_ROUTES)
                                                                for _, url in self.busy):
                continue  # the heavy-check pool was busy (a loaded machine): the console asks again (setup.js)
            if any(re.search(p, text) for p in self.allowed_patterns):
                continue
            out.append(text)
        return out

    def foreign(self) -> list[str]:
        """Request URLs that leave the machine (anything but loopback, data: and blob: of the page)."""
        out = []
        for url in self.requests:
            p = urlparse(url)
            if p.scheme in ("data", "blob", "about"):
                continue
            host = p.hostname or ""
            if host not in LOCAL_HOSTS:
                out.append(url)
        return out


# --- the console's forms ------------------------------------------------------------------------------------
VIEWPORTS = [(1366, 768), (1920, 1080)]


def poll(predicate, timeout_s: float, what: str, interval_s: float = 0.1, shown=None):
    """Poll ``predicate`` until it returns something true (returned), else fail saying what was awaited (and what
    ``shown()`` returns then: what the page showed); waits at least WAIT_S (``timeout_s`` is how long it should
    take, not a window the service must meet)."""
    timeout_s = max(timeout_s, WAIT_S)
    deadline = time.monotonic() + timeout_s
    last = None
    while time.monotonic() < deadline:
        last = predicate()
        if last:
            return last
        time.sleep(interval_s)
    seen = f"; shown: {shown()!r}" if shown is not None else ""
    raise AssertionError(f"timed out after {timeout_s} s waiting for {what} (last: {last!r}{seen})")


def fill_identity(page, specimen: str = "E2E-SPEC-1") -> None:
    """What: the console's Start needs a specimen id (who is the logged-in account)."""
    page.fill("#f-specimen_id", specimen)


def wait_start_enabled(page, timeout_ms: int = WAIT_MS) -> None:
    page.wait_for_selector("#start:not([disabled])", timeout=max(timeout_ms, WAIT_MS))


def settle(page) -> None:
    """Wait until the page has laid out and painted what it has (two animation frames), e.g. after a resize."""
    page.evaluate("() => new Promise((done) => requestAnimationFrame(() => requestAnimationFrame(done)))")


def log_in_dialog(page, account: tuple[str, str]) -> None:
    """Answer the console's login dialog with (name, password)."""
    page.wait_for_selector("#login-dialog[open]", timeout=WAIT_MS)
    page.fill("#login-name", account[0])
    page.fill("#login-password", account[1])
    page.click("#login-ok")
    page.wait_for_selector("#login-dialog:not([open])", state="hidden", timeout=WAIT_MS)


def start_from_form(page, login: tuple[str, str] | None = None) -> str:
    """Start, read the confirmation (returned as text), confirm; log in if the console asks for it."""
    wait_start_enabled(page)
    page.click("#start")
    page.wait_for_selector("#confirm-dialog[open]", timeout=WAIT_MS)
    summary = page.inner_text("#confirm-body")
    for tick in page.query_selector_all("#confirm-body .warning-tick"):
        tick.check()
    page.click("#confirm-ok")
    if login is not None:
        log_in_dialog(page, login)
    return summary


class BusyPool:
    """A Playwright route handler that answers the first ``times`` requests as the service's check pool does when it
    is full (503 with ``Retry-After``), then lets requests through; ``refused_at`` holds when each was refused."""

    def __init__(self, times: int, retry_after_s: int, what: str = "check"):
        self.times = times
        self.retry_after_s = retry_after_s
        self.body = json.dumps({"detail": f"the service is busy with 2 other requests that {what}"})
        self.refused_at: list[float] = []  # time.monotonic() of each refusal

    def __call__(self, route) -> None:
        if len(self.refused_at) < self.times:
            self.refused_at.append(time.monotonic())
            route.fulfill(status=503, headers={"Retry-After": str(self.retry_after_s)},
                          content_type="application/json", body=self.body)
        else:
            route.continue_()


def started_test_id(page) -> int:
    """The id of the test this page's Start created ("Test #N started."), once the live view shows that test: the
    live view may still show the session's previous test for a moment after the hash changed."""
    said = poll(lambda: re.search(r"Test #(\d+) started", page.text_content("#setup-message") or ""), 20,
                "the start's answer", shown=lambda: page.text_content("#setup-message"))
    test_id = int(said.group(1))
    page.wait_for_function(f"window.__isorig.testId === {test_id}", timeout=WAIT_MS)
    return test_id


def hold_back_answer(page, url_ends: str, ms: int = 1500, method: str = "GET") -> None:
    """Make the page's answers to ``method`` requests whose URL ends with ``url_ends`` reach it ``ms`` later (as on
    a loaded service), so a newer request's answer comes first; ``window.__heldBackAsked`` turns true when such a
    request is sent, ``window.__heldBackAnswered`` once one held back has been handed to the page. Set after the
    page has loaded: a change of hash keeps it."""
    page.evaluate("""([ends, ms, method]) => {
      window.__heldBackAsked = false;
      window.__heldBackAnswered = false;
      const orig = window.fetch;
      window.fetch = async (url, opts) => {
        const held = String(url).endsWith(ends) && ((opts && opts.method) || 'GET').toUpperCase() === method;
        if (held) window.__heldBackAsked = true;
        const res = await orig(url, opts);
        if (held) {
          await new Promise((r) => setTimeout(r, ms));
          setTimeout(() => { window.__heldBackAnswered = true; }, 0);
        }
        return res;
      };
    }""", [url_ends, ms, method])


def record_checks(page) -> None:
    """Keep the bodies (in the order sent) and answers (in the order answered) of the page's envelope checks
    (window.__checks, window.__checkAnswers)."""
    page.evaluate("""() => {
      window.__checks = [];
      window.__checkAnswers = [];
      const orig = window.fetch;
      window.fetch = async (url, opts) => {
        const check = String(url).includes('/api/tests/check') && opts && opts.body;
        if (check) window.__checks.push(JSON.parse(opts.body)); // in the order sent
        const res = await orig(url, opts);
        if (check) res.clone().json().then((a) => window.__checkAnswers.push(a)).catch(() => {});
        return res;
      };
    }""")


def shots(page, artifacts: Path, name: str, full_page: bool = False) -> None:
    """Screenshots at both viewports, the larger first (the page ends at 1366x768)."""
    for width, height in reversed(VIEWPORTS):
        page.set_viewport_size({"width": width, "height": height})
        page.wait_for_function(f"window.innerWidth === {width} && window.innerHeight === {height}", timeout=WAIT_MS)
        settle(page)
        page.screenshot(path=str(artifacts / f"{name}_{width}x{height}.png"), full_page=full_page)
