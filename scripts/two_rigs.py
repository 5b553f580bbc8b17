"""Two rigs, one PostgreSQL database: two `isorig serve` processes (simulated rigs, --rig-name rig-a and rig-b,
their own ports and data directories) run a test each AT THE SAME TIME; prints the figures.

    python scripts/two_rigs.py                      # a throwaway PostgreSQL server (tests/backend/pg_server.py)
    python scripts/two_rigs.py --database-url postgresql+psycopg://user:pw@host/db
    python scripts/two_rigs.py --json               # the figures as JSON (tests/backend/test_two_rigs.py)

Checked, per rig: the test completed; every sample is stored (samples_stored equals the samples its duration
holds at the 1 kHz control rate, and the sample chunks in the database hold that many rows); both services' History
lists both tests, each with its rig's name; both rigs were seen running at the same moment (GET /api/rig/state of
each), and for how long the two tests overlapped. Exit code 0 if every check holds, 1 otherwise.
"""

from __future__ import annotations

import argparse
import json
import os
import secrets
import signal
import socket
import subprocess
import sys
import tempfile
import time
from datetime import datetime
from pathlib import Path

import httpx

ROOT = Path(__file__).resolve().parent.parent
CONTROL_PERIOD_S = 1.0e-3  # sim.loop.CONTROL_PERIOD_S: one sample per period
RIGS = ("rig-a", "rig-b")


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class Service:
    """One `isorig serve` process driving the simulated rig ``rig_name``."""

    def __init__(self, rig_name: str, database_url: str, data_dir: Path, token: str):
        self.rig_name = rig_name
        self.port = free_port()
        self.base = f"http://127.0.0.1:{self.port}"
        self.log = open(data_dir.parent / f"{rig_name}.log", "wb")  # noqa: SIM115 (closed in stop())
        env = {**os.environ, "ISORIG_OPERATOR_TOKEN": token,
               "PYTHONPATH": os.pathsep.join(p for p in (str(ROOT), os.environ.get("PYTHONPATH", "")) if p)}
        self.process = subprocess.Popen(
            [sys.executable, "-m", "isorig", "serve", "--rig-name", rig_name, "--port", str(self.port),
             "--database-url", database_url, "--data-dir", str(data_dir), "--log-level", "warning"],
            stdout=self.log, stderr=subprocess.STDOUT, env=env, cwd=ROOT)
        self.http = httpx.Client(base_url=self.base, timeout=30.0, headers={"Authorization": f"Bearer {token}"})

    def wait_up(self, timeout_s: float = 90.0) -> None:
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            if self.process.poll() is not None:
                raise RuntimeError(f"isorig serve --rig-name {self.rig_name} exited ({self.process.returncode}); "
                                   f"see {self.log.name}")
            try:
                health = self.http.get("/api/health").json()
                if health.get("rig_name") != self.rig_name:
                    raise RuntimeError(f"the service on port {self.port} names the rig {health.get('rig_name')!r}")
                return
            except httpx.TransportError:
                time.sleep(0.2)
        raise RuntimeError(f"isorig serve --rig-name {self.rig_name} did not answer within {timeout_s:.0f} s")

    def stop(self) -> None:
        if self.process.poll() is None:
            self.process.send_signal(signal.SIGTERM)  # the service's controlled shutdown
            try:
                self.process.wait(40)
            except subprocess.TimeoutExpired:
                self.process.kill()
                self.process.wait(5)
        self.http.close()
        self.log.close()


def test_body(rig_name: str, cycles: int) -> dict:
    """A real-time (speed 1) sine test: 0.5 Hz, ``cycles`` cycles, 10 mm on IUT_a."""
    return {"isolator": "IUT_a", "supply_bar": 100, "controller": "servo", "speed": 1.0,
            "label": f"two rigs: {rig_name}", "operator_name": "two_rigs.py",
            "profile": {"kind": "sine", "amplitude_m": 0.01, "frequency_hz": 0.5, "cycles": cycles,
                        "taper_cycles": 1}}


def chunk_rows(database_url: str, test_ids: list[int]) -> dict[int, tuple[int, int]]:
    """Per test: (sample chunks, rows they hold), read from the database itself."""
    from sqlalchemy import bindparam, create_engine, text

    query = text("SELECT test_id, count(*), coalesce(sum(n_rows), 0) FROM sample_chunks WHERE test_id IN :ids "
                 "GROUP BY test_id").bindparams(bindparam("ids", expanding=True))
    engine = create_engine(database_url)
    try:
        with engine.connect() as conn:
            rows = conn.execute(query, {"ids": test_ids}).all()
    finally:
        engine.dispose()
    return {int(t): (int(n), int(r)) for t, n, r in rows}


def run(database_url: str, cycles: int, work: Path) -> dict:
    token = secrets.token_urlsafe(24)
    services = [Service(name, database_url, work / name, token) for name in RIGS]
    try:
        for s in services:
            s.wait_up()
        started = {}
        for s in services:  # created and started at once (start=true), one right after the other
            r = s.http.post("/api/tests", params={"start": "true"}, json=test_body(s.rig_name, cycles))
            if r.status_code != 201:
                raise RuntimeError(f"{s.rig_name}: the test was refused: {r.status_code} {r.text}")
            started[s.rig_name] = r.json()["id"]
        both_running_s = 0.0  # how long both rigs' states said "running" their own test, polled
        last = time.monotonic()
        final: dict[str, dict] = {}
        deadline = time.monotonic() + 2.0 * cycles / 0.5 + 60.0
        while len(final) < len(services) and time.monotonic() < deadline:
            states = {s.rig_name: s.http.get("/api/rig/state").json() for s in services}
            now = time.monotonic()
            if all(st["status"] == "running" and st["test_id"] == started[name] for name, st in states.items()):
                both_running_s += now - last
            last = now
            for s in services:
                if s.rig_name not in final:
                    record = s.http.get(f"/api/tests/{started[s.rig_name]}").json()
                    if record["status"] not in ("ready", "running"):
                        final[s.rig_name] = record
            time.sleep(0.1)
        if len(final) < len(services):
            raise RuntimeError(f"the tests did not end in time: {sorted(set(RIGS) - set(final))} still running")
        chunks = chunk_rows(database_url, list(started.values()))
        history = {s.rig_name: {t["id"]: t["rig_name"] for t in s.http.get("/api/tests").json()} for s in services}
    finally:
        for s in services:
            s.stop()
    def at(text: str) -> float:
        return datetime.fromisoformat(text).timestamp()

    overlap_s = (min(at(r["ended_at"]) for r in final.values()) - max(at(r["started_at"]) for r in final.values()))
    rigs = {}
    for name, record in final.items():
        expected = round(record["duration_s"] / CONTROL_PERIOD_S)
        n_chunks, rows = chunks.get(record["id"], (0, 0))
        rigs[name] = {"test_id": record["id"], "rig_name": record["rig_name"], "status": record["status"],
                      "duration_s": record["duration_s"], "samples_expected": expected,
                      "samples_stored": record["samples_stored"], "chunks": n_chunks, "chunk_rows": rows,
                      "cycles_done": record["cycles_done"], "cycles_total": record["cycles_total"]}
    checks = {
        "completed": all(r["status"] == "completed" for r in rigs.values()),
        "each record names its rig": all(r["rig_name"] == name for name, r in rigs.items()),
        "every sample stored": all(r["samples_stored"] == r["samples_expected"] == r["chunk_rows"]
                                   for r in rigs.values()),
        "every cycle stored": all(r["cycles_done"] == r["cycles_total"] for r in rigs.values()),
        "each History lists both, with their rig": all(
            all(listed.get(r["test_id"]) == name for name, r in rigs.items()) for listed in history.values()),
        "both ran at the same time": both_running_s > 0 and overlap_s > 0,
    }
    return {"database": database_url.split("://")[0], "rigs": rigs, "overlap_s": round(overlap_s, 3),
            "both_running_seen_s": round(both_running_s, 3), "checks": checks, "ok": all(checks.values())}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--database-url", help="a PostgreSQL URL (postgresql+psycopg://...); default: a throwaway "
                    "server started here from the installed PostgreSQL binaries")
    ap.add_argument("--cycles", type=int, default=5, help="sine cycles per test at 0.5 Hz, real time (default 5: "
                    "10 s)")
    ap.add_argument("--json", action="store_true", help="print the figures as JSON")
    args = ap.parse_args(argv)
    server = None
    url = args.database_url
    with tempfile.TemporaryDirectory(prefix="isorig-two-rigs-") as tmp:
        if url is None:
            sys.path.insert(0, str(ROOT / "tests" / "backend"))
            from pg_server import PostgresServer, find_bindir

            bindir = find_bindir()
            if bindir is None:
                print("two_rigs.py: no PostgreSQL server binaries found (apt-get install postgresql) and no "
                      "--database-url given", file=sys.stderr)
                return 2
            server = PostgresServer(bindir).start()
            url = server.database()
        try:
            out = run(url, args.cycles, Path(tmp))
        finally:
            if server is not None:
                server.stop()
    if args.json:
        print(json.dumps(out, indent=2))
    else:
        print(f"two rigs on one {out['database']} database: the tests overlapped {out['overlap_s']:.2f} s; both "
              f"rigs seen running at once for {out['both_running_seen_s']:.2f} s")
        for name, r in out["rigs"].items():
            print(f"  {name}: test {r['test_id']} {r['status']}, {r['duration_s']:g} s: samples stored "
                  f"{r['samples_stored']} of {r['samples_expected']} expected, {r['chunks']} chunks holding "
                  f"{r['chunk_rows']} rows; cycles {r['cycles_done']}/{r['cycles_total']}")
        for check, ok in out["checks"].items():
            print(f"  [{'ok' if ok else 'FAILED'}] {check}")
    return 0 if out["ok"] else 1


if __name__ == "__main__":
    sys.exit(main())
