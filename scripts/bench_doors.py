"""Benchmark of the service's doors (issue 21, part 5), against a real `isorig serve` on a free loopback port.

Prints: the largest legitimate bodies (what max_body_bytes is sized for), a 100 MB body (Content-Length and
chunked) answered 413 and /api/health meanwhile, four parallel 200 000-sample history checks (answers, time,
/api/health meanwhile, the service's RSS before, at peak and after, the check workers' peak), cross-site
refusals, and 100 immediate abort -> re-start pairs (how many 409).

    PYTHONPATH=. python scripts/bench_doors.py [--pairs 100] [--samples 200000]
"""

from __future__ import annotations

import argparse
import http.client
import json
import os
import select
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
TOKEN = "bench-doors-token"
AUTH = {"Authorization": f"Bearer {TOKEN}"}


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def rss_mb(pid: int) -> float:
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024
    except OSError:
        pass
    return 0.0


def pss_mb(pid: int) -> float:
    """Proportional set size: a page shared by n processes counts 1/n in each (forked workers share most)."""
    try:
        for line in Path(f"/proc/{pid}/smaps_rollup").read_text().splitlines():
            if line.startswith("Pss:"):
                return int(line.split()[1]) / 1024
    except OSError:
        pass
    return 0.0


def descendants(pid: int) -> list[int]:
    out = []
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                fields = (entry / "stat").read_text().rsplit(")", 1)[1].split()
            except OSError:
                continue
            if int(fields[1]) == pid:
                out.append(int(entry.name))
    return out + [d for c in out for d in descendants(c)]


class Service:
    def __init__(self, workdir: Path):
        self.port = free_port()
        self.workdir = workdir
        env = {**os.environ, "ISORIG_DATA_DIR": str(workdir), "ISORIG_OPERATOR_TOKEN": TOKEN, "ISORIG_VIEWER": "0",
               "PYTHONPATH": str(REPO)}
        self.log = open(workdir / "serve.log", "ab")
        self.proc = subprocess.Popen([sys.executable, "-m", "isorig", "serve", "--host", "127.0.0.1", "--port",
                                      str(self.port), "--log-level", "warning"], cwd=REPO, env=env,
                                     stdout=self.log, stderr=subprocess.STDOUT, start_new_session=True)
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline:
            try:
                if self.request("GET", "/api/health")[0] == 200:
                    return
            except OSError:
                time.sleep(0.2)
        raise RuntimeError("isorig serve did not start")

    def request(self, method: str, path: str, body=None, headers: dict | None = None, timeout: float = 120.0):
        conn = http.client.HTTPConnection("127.0.0.1", self.port, timeout=timeout)
        data = json.dumps(body).encode() if isinstance(body, (dict, list)) else body
        hdrs = dict(headers or {})
        if isinstance(body, (dict, list)):
            hdrs.setdefault("Content-Type", "application/json")
        conn.request(method, path, body=data, headers=hdrs)
        r = conn.getresponse()
        raw = r.read()
        conn.close()
        try:
            return r.status, json.loads(raw) if raw else None, {k.lower(): v for k, v in r.getheaders()}
        except ValueError:
            return r.status, raw[:200], {k.lower(): v for k, v in r.getheaders()}

    def stop(self) -> None:
        self.proc.send_signal(signal.SIGINT)
        try:
            self.proc.wait(20)
        except subprocess.TimeoutExpired:
            os.killpg(self.proc.pid, signal.SIGKILL)
            self.proc.wait(5)


class HealthProbe:
    """/api/health every 50 ms in a thread: the longest answer while something else happens."""

    def __init__(self, service: Service):
        self.service = service
        self.worst_s = 0.0
        self.count = 0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)

    def _run(self):
        while not self._stop.is_set():
            t0 = time.perf_counter()
            try:
                self.service.request("GET", "/api/health", timeout=60)
            except OSError:
                pass
            self.worst_s = max(self.worst_s, time.perf_counter() - t0)
            self.count += 1
            time.sleep(0.05)

    def __enter__(self):
        self._thread.start()
        return self

    def __exit__(self, *exc):
        self._stop.set()
        self._thread.join()


def send_big_body(port: int, n_bytes: int, chunked: bool) -> tuple[str, float, int]:
    """Send a POST of n_bytes to /api/tests/check, watching for the answer while sending; returns (status line,
    seconds to the answer, bytes sent by then)."""
    sock = socket.create_connection(("127.0.0.1", port))
    head = (f"POST /api/tests/check HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\nContent-Type: application/json\r\n"
            + ("Transfer-Encoding: chunked\r\n" if chunked else f"Content-Length: {n_bytes}\r\n") + "\r\n")
    t0 = time.perf_counter()
    sock.sendall(head.encode())
    block = b"[" + b"0," * 32767 + b"0"  # 64 KiB of JSON-ish
    sent = 0
    sock.setblocking(False)
    answer = b""
    while True:
        readable, writable, _ = select.select([sock], [sock] if sent < n_bytes else [], [], 5.0)
        if readable:
            try:
                chunk = sock.recv(65536)
            except ConnectionResetError:
                break
            answer += chunk
            if b"\r\n\r\n" in answer or not chunk:
                break
        elif writable:
            piece = block if not chunked else f"{len(block):x}\r\n".encode() + block + b"\r\n"
            try:
                sent += sock.send(piece)
            except (BlockingIOError, BrokenPipeError, ConnectionResetError):
                pass
        elif not readable and not writable:
            break
    elapsed = time.perf_counter() - t0
    sock.close()
    return answer.split(b"\r\n", 1)[0].decode(errors="replace"), elapsed, sent


def raw_post(port: int, path: str, data: bytes, timeout_s: float = 600.0) -> tuple[int, dict, bytes]:
    """POST data as JSON, reading the answer while sending: a server that answers before reading the body (413,
    503) and closes is heard, not seen as a reset. Returns (status, headers, body)."""
    sock = socket.create_connection(("127.0.0.1", port))
    sock.sendall((f"POST {path} HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\nContent-Type: application/json\r\n"
                  f"Content-Length: {len(data)}\r\n\r\n").encode())
    sock.setblocking(False)
    view, sent, answer = memoryview(data), 0, b""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        readable, writable, _ = select.select([sock], [sock] if sent < len(data) else [], [], 1.0)
        if readable:
            try:
                chunk = sock.recv(1 << 20)
            except ConnectionResetError:
                break
            if not chunk:
                break
            answer += chunk
            head, sep, body = answer.partition(b"\r\n\r\n")
            if sep:
                headers = {k.strip().lower(): v.strip() for k, _c, v in
                           (line.decode().partition(":") for line in head.split(b"\r\n")[1:])}
                if len(body) >= int(headers.get("content-length", "0")):
                    sock.close()
                    return int(head.split()[1]), headers, body
        elif writable:
            try:
                sent += sock.send(view[sent:sent + (1 << 20)])
            except (BlockingIOError, BrokenPipeError, ConnectionResetError):
                pass
    sock.close()
    head = answer.split(b"\r\n", 1)[0]
    return (int(head.split()[1]) if head else 0), {}, b""


def history_body(n: int, kind: str = "history") -> dict:
    dt = 0.005
    t = np.arange(n) * dt
    acc = 0.8 * np.sin(2 * np.pi * 0.7 * t) * np.exp(-((t - t[-1] / 2) / (t[-1] / 5)) ** 2)
    return {"isolator": "IUT_a", "supply_bar": 100, "controller": "servo", "speed": 1.0,
            "profile": {"kind": kind, "ground_motion": {"time_s": (t + 0.0).tolist(),
                                                        "acceleration_m_per_s2": acc.tolist(), "units": "m/s2"},
                        "scale": 0.3}}


def at2_text(n: int) -> str:
    values = 0.05 * np.sin(np.arange(n) * 0.01)
    lines = ["PEER NGA STRONG MOTION DATABASE RECORD", "bench record", "ACCELERATION TIME SERIES IN UNITS OF G",
             f"NPTS=  {n}, DT=   .0050 SEC"]
    lines += ["".join(f"{v:15.7E}" for v in values[i:i + 5]) for i in range(0, n, 5)]
    return "\n".join(lines) + "\n"


def raw_ws_status(port: int, host: str, origin: str | None) -> str:
    sock = socket.create_connection(("127.0.0.1", port), timeout=5)
    head = (f"GET /ws/live HTTP/1.1\r\nHost: {host}\r\nUpgrade: websocket\r\nConnection: Upgrade\r\n"
            "Sec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==\r\nSec-WebSocket-Version: 13\r\n"
            + (f"Origin: {origin}\r\n" if origin else "") + "\r\n")
    sock.sendall(head.encode())
    line = sock.recv(4096).split(b"\r\n", 1)[0].decode(errors="replace")
    sock.close()
    return line


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--pairs", type=int, default=100, help="abort -> re-start pairs")
    ap.add_argument("--samples", type=int, default=200_000, help="samples of the inline histories checked")
    ap.add_argument("--big-mb", type=float, default=100.0, help="size of the oversized body, MB")
    args = ap.parse_args()

    print("== the largest legitimate bodies (what max_body_bytes is sized for)")
    body = history_body(200_000)
    print(f"  200 000-sample inline ground motion, as JSON: {len(json.dumps(body)) / 1e6:.2f} MB")
    text = at2_text(200_000)
    print(f"  200 000-sample .AT2 file: {len(text) / 1e6:.2f} MB; its read-at2 request: "
          f"{len(json.dumps({'filename': 'x.AT2', 'text': text})) / 1e6:.2f} MB")

    with tempfile.TemporaryDirectory(prefix="isorig-bench-doors-") as tmp:
        service = Service(Path(tmp))
        try:
            pid = service.proc.pid
            print(f"== service pid {pid} on port {service.port}, RSS {rss_mb(pid):.0f} MB at start")
            n = int(args.big_mb * 1e6)
            for chunked in (False, True):
                with HealthProbe(service) as probe:
                    time.sleep(0.2)
                    status, elapsed, sent = send_big_body(service.port, n, chunked)
                    time.sleep(0.3)
                how = "chunked" if chunked else "Content-Length"
                print(f"== {args.big_mb:g} MB body ({how}): '{status}' after {elapsed:.3f} s, {sent / 1e6:.1f} MB "
                      f"sent by then; /api/health worst {probe.worst_s * 1e3:.0f} ms over {probe.count} calls")

            db = Path(tmp) / "isorig.db"
            print(f"== database file mode {oct(db.stat().st_mode & 0o777)}, directory "
                  f"{oct(Path(tmp).stat().st_mode & 0o777)} (a directory given: left as it was)")

            print("== cross-site")
            code, _b, _h = service.request("POST", "/api/tests/1/abort", b"x",
                                           {"Origin": "http://evil.example", "Content-Type": "text/plain"})
            print(f"  text/plain POST .../abort from http://evil.example: {code}")
            code, _b, _h = service.request("POST", "/api/tests/1/abort", None, {"Origin": "http://evil.example"})
            print(f"  body-less POST .../abort from http://evil.example: {code}")
            code, b, _h = service.request("GET", "/api/tests", None, {"Host": "evil.example"})
            print(f"  GET /api/tests with Host: evil.example: {code} {b['detail'][:90] if b else ''}...")
            print(f"  /ws/live from http://evil.example: {raw_ws_status(service.port, f'127.0.0.1:{service.port}', 'http://evil.example')}")
            print(f"  /ws/live from its own origin: "
                  f"{raw_ws_status(service.port, f'127.0.0.1:{service.port}', f'http://127.0.0.1:{service.port}')}")

            print(f"== four parallel {args.samples}-sample history checks (check_workers 1, check_queue 1)")
            body = history_body(args.samples)
            before = rss_mb(pid)
            peak = {"service": before, "workers": 0.0}
            done = threading.Event()

            def watch():
                while not done.is_set():
                    peak["service"] = max(peak["service"], rss_mb(pid))
                    workers = sum(pss_mb(d) for d in descendants(pid))
                    peak["workers"] = max(peak["workers"], workers)
                    time.sleep(0.1)

            watcher = threading.Thread(target=watch, daemon=True)
            watcher.start()
            with HealthProbe(service) as probe:
                t0 = time.perf_counter()

                data = json.dumps(body).encode()

                def one(i):
                    time.sleep(i * 0.05)
                    s = time.perf_counter()
                    code, h, raw = raw_post(service.port, "/api/tests/check", data)
                    detail = json.loads(raw).get("detail", "") if raw else ""
                    return code, time.perf_counter() - s, detail[:80], h.get("retry-after")

                with ThreadPoolExecutor(4) as ex:
                    results = list(ex.map(one, range(4)))
                total = time.perf_counter() - t0
            done.set()
            watcher.join()
            time.sleep(1.0)
            after = rss_mb(pid)
            for code, took, detail, retry in results:
                print(f"  {code} in {took:.1f} s" + (f" (Retry-After {retry}: {detail}...)" if code != 200 else
                                                     f" ({detail})"))
            print(f"  all answered in {total:.1f} s; /api/health worst {probe.worst_s * 1e3:.0f} ms over "
                  f"{probe.count} calls")
            print(f"  service RSS: {before:.0f} MB before, {peak['service']:.0f} MB peak, {after:.0f} MB after; "
                  f"its children (forkserver, idle and busy check workers; PSS) peak {peak['workers']:.0f} MB, "
                  f"{sum(pss_mb(d) for d in descendants(pid)):.0f} MB after")

            print(f"== {args.pairs} immediate abort -> re-start pairs")
            # 1 mm: wherever an abort finds the table, it is within the start tolerance (2 mm) of zero, so a 409
            # could only be 'test N is running'
            sine = {"isolator": "IUT_a", "supply_bar": 100, "controller": "servo", "speed": 1.0,
                    "profile": {"kind": "sine", "amplitude_m": 0.001, "frequency_hz": 0.5, "cycles": 50,
                                "taper_cycles": 1}}
            conflicts, statuses, abort_s = 0, {}, []
            code, rec, _h = service.request("POST", "/api/tests?start=true", sine, AUTH)
            assert code == 201, rec
            for _ in range(args.pairs):
                s = time.perf_counter()
                code, ended, _h = service.request("POST", f"/api/tests/{rec['id']}/abort")
                abort_s.append(time.perf_counter() - s)
                statuses[(code, ended.get("status"))] = statuses.get((code, ended.get("status")), 0) + 1
                code, rec, _h = service.request("POST", "/api/tests?start=true", sine, AUTH)
                if code == 409:
                    conflicts += 1
                    print(f"  409: {rec['detail']}")
                    time.sleep(1.0)
                    code, rec, _h = service.request("POST", "/api/tests?start=true", sine, AUTH)
                assert code == 201, rec
            service.request("POST", f"/api/tests/{rec['id']}/abort")
            print(f"  409s: {conflicts} of {args.pairs}; abort answers: "
                  + ", ".join(f"{n}x {c} {s}" for (c, s), n in statuses.items())
                  + f"; abort took median {np.median(abort_s) * 1e3:.0f} ms, max {max(abort_s) * 1e3:.0f} ms")
        finally:
            service.stop()
    return 0


if __name__ == "__main__":
    sys.exit(main())
