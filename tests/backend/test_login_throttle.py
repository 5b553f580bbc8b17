"""The login throttle (backend.auth.LoginThrottle, issue 33 item 3): a guess is counted before its password is
checked, so a parallel burst gets no more than the free guesses checked; delays grow per name and address, and
never lock the account's owner out at another address; only forgotten entries leave the table, and a full table
refuses a new address rather than forget a lockout.

The bursts run against the service served by uvicorn on loopback, in threads and from asyncio; a second address
is 127.0.0.2 (all of 127.0.0.0/8 is loopback on Linux)."""

from __future__ import annotations

import asyncio
import http.client
import json
import socket
import threading
import time

import httpx
import pytest
import uvicorn
from aio import run
from conftest import make_settings
from fastapi.testclient import TestClient

from backend import accounts
from backend.app import create_app
from backend.auth import LoginThrottle, ThrottleFull, address_key

PASSWORD = "correct horse battery"
WRONG = "not the password"
BURST = 30
LIMIT = 5  # LoginThrottle's free failures per name and address


class Served:
    """create_app served by uvicorn in a thread on 127.0.0.1 (its lifespan runs as under `isorig serve`)."""

    def __init__(self, tmp_path):
        self.app = create_app(make_settings(tmp_path))
        # the default rule with a longer first delay: a guess of a burst that a loaded machine serves late is
        # still refused, so only the counting is tested (at most LIMIT checked, whenever they arrive)
        self.app.state.login_throttle = LoginThrottle(limit=LIMIT, first_delay_s=30.0)
        with socket.socket() as s:
            s.bind(("127.0.0.1", 0))
            self.port = s.getsockname()[1]
        self.server = uvicorn.Server(uvicorn.Config(self.app, host="127.0.0.1", port=self.port, log_level="warning",
                                                    limit_concurrency=200))
        self.thread = threading.Thread(target=self.server.run, daemon=True, name="test-login-uvicorn")

    def __enter__(self) -> Served:
        self.thread.start()
        deadline = time.monotonic() + 60
        while not self.server.started:
            assert time.monotonic() < deadline and self.thread.is_alive(), "the service did not start"
            time.sleep(0.05)
        with self.app.state.sessions() as session:
            for name in ("otto", "anna"):
                accounts.add_user(session, name, "operator", PASSWORD)
            session.commit()
        return self

    def __exit__(self, *exc) -> None:
        self.server.should_exit = True
        self.thread.join(30)

    def log_in(self, name: str, password: str, source: str = "127.0.0.1") -> httpx.Response:
        with httpx.Client(base_url=f"http://127.0.0.1:{self.port}",
                          transport=httpx.HTTPTransport(local_address=source), timeout=60) as client:
            return client.post("/api/session", json={"name": name, "password": password})


@pytest.fixture(scope="module")
def served(tmp_path_factory):
    # production password hashes (not the suite's cheap ones, tests/conftest.py): a burst's guesses then overlap
    # for the ~0.2 s a check takes, as they would against a service, so a guess counted after its check is caught
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(accounts, "_hasher", accounts.password_hasher({}))
        with Served(tmp_path_factory.mktemp("login-throttle")) as s:
            yield s


def _post_login(port: int, name: str, password: str, barrier: threading.Barrier) -> int:
    conn = http.client.HTTPConnection("127.0.0.1", port, timeout=60)
    conn.connect()
    barrier.wait(30)
    conn.request("POST", "/api/session", body=json.dumps({"name": name, "password": password}),
                 headers={"Content-Type": "application/json"})
    status = conn.getresponse().status
    conn.close()
    return status


def test_a_burst_in_threads_gets_no_more_than_the_free_guesses_checked(served):
    barrier = threading.Barrier(BURST)
    statuses: list[int] = []
    threads = [threading.Thread(target=lambda: statuses.append(_post_login(served.port, "otto", WRONG, barrier)))
               for _ in range(BURST)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(120)
    assert len(statuses) == BURST
    checked = statuses.count(401)
    assert 1 <= checked <= LIMIT and statuses.count(429) == BURST - checked, statuses


def test_a_burst_from_asyncio_gets_no_more_than_the_free_guesses_checked(served):
    async def burst() -> list[int]:
        limits = httpx.Limits(max_connections=BURST)
        async with httpx.AsyncClient(base_url=f"http://127.0.0.1:{served.port}", limits=limits, timeout=60,
                                     transport=httpx.AsyncHTTPTransport(local_address="127.0.0.3")) as client:
            answers = await asyncio.gather(*(client.post("/api/session", json={"name": "anna", "password": WRONG})
                                             for _ in range(BURST)))
        return [r.status_code for r in answers]

    statuses = run(burst())
    checked = statuses.count(401)
    assert 1 <= checked <= LIMIT and statuses.count(429) == BURST - checked, statuses


def test_guesses_from_one_address_never_lock_the_owner_out_at_another(served):
    for _ in range(LIMIT):
        assert served.log_in("otto", WRONG, source="127.0.0.4").status_code == 401
    slowed = served.log_in("otto", PASSWORD, source="127.0.0.4")  # the guessing address waits, even when right
    assert slowed.status_code == 429 and int(slowed.headers["retry-after"]) >= 1
    assert "try again in" in slowed.json()["detail"]
    r = served.log_in("otto", PASSWORD, source="127.0.0.5")  # the owner, at their own console
    assert r.status_code == 200, r.text
    assert r.json()["name"] == "otto"


def test_delays_double_per_failure_up_to_the_cap_and_are_forgotten():
    now = [0.0]
    t = LoginThrottle(limit=5, first_delay_s=1.0, max_delay_s=300.0, forget_s=900.0, clock=lambda: now[0])
    for _ in range(5):
        assert t.admit("otto", "10.0.0.1") == 0.0
        t.failed("otto", "10.0.0.1")
    waits = []
    for _ in range(12):
        wait = t.admit("otto", "10.0.0.1")
        waits.append(wait)
        now[0] += wait
        assert t.admit("otto", "10.0.0.1") == 0.0  # after the wait, one guess
        t.failed("otto", "10.0.0.1")
    assert waits == [1, 2, 4, 8, 16, 32, 64, 128, 256, 300, 300, 300]
    assert t.admit("otto", "10.0.0.2") == 0.0  # another address is not slowed
    t.succeeded("otto", "10.0.0.2")
    now[0] += 900.0
    assert t.admit("otto", "10.0.0.1") == 0.0  # 15 min without a guess: forgotten


def test_a_right_password_takes_its_guess_back():
    t = LoginThrottle(limit=5, address_limit=20, clock=lambda: 0.0)
    for i in range(50):  # a shared console: fifty good logins, several names, one address
        assert t.admit(f"user{i % 7}", "10.0.0.1") == 0.0
        t.succeeded(f"user{i % 7}", "10.0.0.1")
    assert t.admit("otto", "10.0.0.1") == 0.0


def test_one_address_guessing_many_names_is_slowed():
    t = LoginThrottle(limit=5, address_limit=20, clock=lambda: 0.0)
    for i in range(20):
        assert t.admit(f"name{i}", "10.0.0.1") == 0.0
    assert t.admit("name99", "10.0.0.1") == 1.0
    assert t.admit("name99", "10.0.0.2") == 0.0


def test_a_full_table_keeps_its_lockouts_and_refuses_a_new_address():
    now = [0.0]
    t = LoginThrottle(limit=5, forget_s=900.0, clock=lambda: now[0])
    for _ in range(5):
        t.admit("otto", "10.0.0.1")
        t.failed("otto", "10.0.0.1")
    for i in range(12_000):  # a flood of names from other addresses (each two entries): more than the old 10 000
        now[0] += 1e-5  # all within the 1 s delay
        t.admit(f"n{i}", f"10.1.{i // 250}.{i % 250}")
    assert t.admit("otto", "10.0.0.1") > 0  # still slowed: nothing live was dropped
    small = LoginThrottle(limit=5, forget_s=900.0, max_entries=10, clock=lambda: now[0])
    for _ in range(5):
        small.admit("otto", "10.0.0.1")
    for i in range(4):
        small.admit("x", f"10.2.0.{i}")
    assert len(small) == 10
    with pytest.raises(ThrottleFull) as full:
        small.admit("y", "10.3.0.1")
    assert 0 < full.value.wait_s <= 900.0
    assert small.admit("otto", "10.0.0.1") > 0
    now[0] += 900.0  # the flood is forgotten after forget_s; so is otto's count, its last delay long over
    assert small.admit("y", "10.3.0.1") == 0.0


def test_a_full_table_is_a_clear_503(tmp_path):
    with TestClient(create_app(make_settings(tmp_path))) as c:
        c.app.state.login_throttle = LoginThrottle(max_entries=2)
        assert c.post("/api/session", json={"name": "a", "password": WRONG}).status_code == 401
        r = c.post("/api/session", json={"name": "b", "password": WRONG})
        assert r.status_code == 503 and int(r.headers["retry-after"]) >= 1
        assert r.json()["detail"].startswith("too many addresses are guessing passwords")


def test_addresses_are_counted_by_machine():
    assert address_key("2001:db8::1") == address_key("2001:db8::ffff") == "2001:db8::/64"
    assert address_key("::ffff:10.0.0.1") == "10.0.0.1"
    assert address_key("10.0.0.1") == "10.0.0.1"
    assert address_key("testclient") == "testclient"
