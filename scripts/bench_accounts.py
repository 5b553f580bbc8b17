"""Benchmark of accounts (issue 22 targets: a login < 300 ms, a request with a token < 5 ms extra), against a real
`isorig serve` on a free loopback port with its own SQLite database.

Prints: the time of a login (POST /api/session: argon2id verify, a session row), median and worst of N; and the
time of the same read (GET /api/session) without a credential, with an account's API token (its SHA-256 looked up)
and with the login cookie, medians over N requests on one keep-alive connection, and the extra of each. Then the
login throttle (issue 33): how many of a parallel burst of wrong guesses at one name were checked (the rest 429),
the wait asked before each further guess from that address (waiting it out each time), and whether the account's
owner logs in meanwhile from another address (127.0.0.2; all of 127.0.0.0/8 is loopback on Linux).

    PYTHONPATH=. python scripts/bench_accounts.py [--logins 20] [--requests 500] [--burst 30] [--steps 4]
"""

from __future__ import annotations

import argparse
import http.client
import json
import os
import signal
import socket
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
PASSWORD = "bench-accounts-password"


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def add_account(url: str, name: str) -> str:
    """An operator account and an API token for it, as `isorig user add` / `user token` make them."""
    from backend import accounts, db

    engine = db.make_engine(url)
    db.upgrade(engine)
    with db.session_factory(engine)() as session:
        accounts.add_user(session, name, "operator", PASSWORD)
        token = accounts.new_token(session, name)
        session.commit()
    engine.dispose()
    return token


def timed(conn, method: str, path: str, body=None, headers=None) -> tuple[float, int, http.client.HTTPResponse]:
    data = json.dumps(body).encode() if body is not None else None
    hdrs = {"Content-Type": "application/json"} if data else {}
    hdrs.update(headers or {})
    t0 = time.perf_counter()
    conn.request(method, path, body=data, headers=hdrs)
    r = conn.getresponse()
    r.read()
    return (time.perf_counter() - t0) * 1e3, r.status, r


def login(port: int, password: str, source: str, barrier: threading.Barrier | None = None) -> tuple[int, str]:
    """(status, Retry-After) of one POST /api/session as "bench" from the loopback address ``source``."""
    conn = http.client.HTTPConnection("127.0.0.1", port, timeout=60, source_address=(source, 0))
    conn.connect()
    if barrier is not None:
        barrier.wait(30)
    conn.request("POST", "/api/session", body=json.dumps({"name": "bench", "password": password}),
                 headers={"Content-Type": "application/json"})
    r = conn.getresponse()
    r.read()
    conn.close()
    return r.status, r.getheader("retry-after") or ""


def throttle_figures(port: int, burst: int, steps: int) -> None:
    """A burst of wrong guesses from 127.0.0.3, its delays, and the owner at 127.0.0.2 meanwhile."""
    barrier = threading.Barrier(burst)
    answers: list[int] = []
    threads = [threading.Thread(target=lambda: answers.append(login(port, "wrong", "127.0.0.3", barrier)[0]))
               for _ in range(burst)]
    t0 = time.perf_counter()
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    print(f"login throttle: a burst of {burst} parallel wrong guesses at one name from one address: "
          f"{answers.count(401)} checked (401), {answers.count(429)} refused 429 unchecked, in "
          f"{time.perf_counter() - t0:.2f} s  [limit: 5 checked]")
    waits = []
    for _ in range(steps):
        status, retry = login(port, "wrong", "127.0.0.3")
        if status == 429:
            waits.append(int(retry))
            time.sleep(int(retry))
            status, retry = login(port, "wrong", "127.0.0.3")
        assert status == 401, status
    print(f"  waits asked before each further guess from that address (each waited out): {waits} s "
          "(doubling, at most 300 s)")
    t0 = time.perf_counter()
    status, _ = login(port, PASSWORD, "127.0.0.2")
    same, retry = login(port, PASSWORD, "127.0.0.3")
    print(f"  meanwhile the owner from another address: {status} in {(time.perf_counter() - t0) * 1e3:.0f} ms; "
          f"the right password from the guessing address: {same} (Retry-After {retry or '-'} s)")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--logins", type=int, default=20)
    ap.add_argument("--requests", type=int, default=500)
    ap.add_argument("--burst", type=int, default=30, help="parallel wrong guesses at one name")
    ap.add_argument("--steps", type=int, default=4, help="further guesses, each after the wait asked")
    args = ap.parse_args()
    work = Path(tempfile.mkdtemp(prefix="isorig-bench-accounts-"))
    url = f"sqlite:///{work / 'isorig.db'}"
    token = add_account(url, "bench")
    port = free_port()
    env = dict(os.environ, ISORIG_DATA_DIR=str(work), ISORIG_DATABASE_URL=url, ISORIG_VIEWER="0")
    proc = subprocess.Popen([sys.executable, "-m", "isorig", "serve", "--host", "127.0.0.1", "--port", str(port)],
                            cwd=REPO, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                            start_new_session=True)
    try:
        conn = http.client.HTTPConnection("127.0.0.1", port, timeout=30)
        for _ in range(300):
            try:
                if timed(conn, "GET", "/api/health")[1] == 200:
                    break
            except OSError:
                conn = http.client.HTTPConnection("127.0.0.1", port, timeout=30)
                time.sleep(0.2)
        logins, cookie = [], ""
        for i in range(args.logins + 1):
            ms, status, r = timed(conn, "POST", "/api/session", {"name": "bench", "password": PASSWORD})
            assert status == 200, status
            cookie = r.getheader("set-cookie").split(";", 1)[0]
            if i:  # the first one pays the imports
                logins.append(ms)
        cases = {"no credential": {}, "API token": {"Authorization": f"Bearer {token}"},
                 "login cookie": {"Cookie": cookie}}
        times: dict[str, list[float]] = {k: [] for k in cases}
        for _ in range(args.requests):  # interleaved: the machine's noise falls on every case alike
            for name, headers in cases.items():
                ms, status, _ = timed(conn, "GET", "/api/session", headers=headers)
                assert status == 200, (name, status)
                times[name].append(ms)
        print(f"login (POST /api/session, argon2id): median {statistics.median(logins):.1f} ms, worst "
              f"{max(logins):.1f} ms over {len(logins)}  [target < 300 ms]")
        base = statistics.median(times["no credential"])
        for name, values in times.items():
            med = statistics.median(values)
            extra = "" if name == "no credential" else f", extra {med - base:+.2f} ms  [target < 5 ms]"
            print(f"GET /api/session, {name:14s}: median {med:.2f} ms, p95 "
                  f"{sorted(values)[int(0.95 * len(values))]:.2f} ms over {len(values)}{extra}")
        throttle_figures(port, args.burst, args.steps)
    finally:
        os.killpg(proc.pid, signal.SIGINT)
        proc.wait(30)
    return 0


if __name__ == "__main__":
    sys.exit(main())
