"""Benchmark of accounts (issue 22 targets: a login < 300 ms, a request with a token < 5 ms extra), against a real
`isorig serve` on a free loopback port with its own SQLite database.

Prints: the time of a login (POST /api/session: argon2id verify, a session row), median and worst of N; and the
time of the same read (GET /api/session) without a credential, with an account's API token (its SHA-256 looked up)
and with the login cookie, medians over N requests on one keep-alive connection, and the extra of each.

    PYTHONPATH=. python scripts/bench_accounts.py [--logins 20] [--requests 500]
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


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--logins", type=int, default=20)
    ap.add_argument("--requests", type=int, default=500)
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
    finally:
        os.killpg(proc.pid, signal.SIGINT)
        proc.wait(30)
    return 0


if __name__ == "__main__":
    sys.exit(main())
