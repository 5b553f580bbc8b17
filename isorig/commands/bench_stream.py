"""`isorig bench-stream`: measure the service's targets and print the figures.

Starts `isorig serve` in a subprocess on a temporary database, then
1. runs a test at speed 1 for ``--duration-s`` (default 300 s, the issue's 5 minutes) with ``--clients``
   websocket clients (default 10) attached; prints the control loop's pacing lateness (p50/p99/max, from the
   worker) and the sample-to-client latency (p50/p95/p99/max over every sample every client received: receive
   time minus the wall-clock time at the end of the sample's control period);
2. optionally (``--baseline``) the same test first without clients, to show the clients' effect on pacing;
3. stores a ``--storage-minutes`` (default 10) test run at ``--storage-speed`` (default 50x) and prints its
   stored size.
"""

from __future__ import annotations

import asyncio
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


def register(sub) -> None:
    p = sub.add_parser("bench-stream", help="measure pacing, websocket latency with many clients, storage size")
    p.add_argument("--duration-s", type=float, default=300.0, help="test time of the paced run (default 300)")
    p.add_argument("--clients", type=int, default=10, help="websocket clients during the paced run (default 10)")
    p.add_argument("--baseline", action="store_true", help="first run the same test without clients")
    p.add_argument("--storage-minutes", type=float, default=10.0, help="length of the storage test (default 10)")
    p.add_argument("--storage-speed", type=float, default=50.0, help="speed of the storage test (default 50)")
    p.add_argument("--database-url", default=None, help="database to measure on (default: temporary SQLite)")
    p.add_argument("--nice", type=int, default=0,
                   help="run the service and the clients at this nice value (e.g. -10: as on a dedicated machine; "
                        "needs root or CAP_SYS_NICE)")
    p.add_argument("--ws-deflate", action="store_true", help="serve with websocket per-message compression")
    p.add_argument("--json", action="store_true", help="print the figures as JSON")
    p.set_defaults(func=run)


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _percentiles(values) -> dict:
    import numpy as np

    a = np.asarray(values, dtype=float)
    if a.size == 0:
        return {"n": 0}
    return {"n": int(a.size), "p50_ms": float(np.percentile(a, 50)), "p95_ms": float(np.percentile(a, 95)),
            "p99_ms": float(np.percentile(a, 99)), "max_ms": float(a.max())}


class Service:
    def __init__(self, data_dir: str, database_url: str | None, nice: int = 0, deflate: bool = False,
                 rig: str | None = None):
        self.port = _free_port()
        self.token = secrets.token_urlsafe(16)
        self.base = f"http://127.0.0.1:{self.port}"
        env = {**os.environ, "ISORIG_OPERATOR_TOKEN": self.token, "ISORIG_VIEWER": "0",
               "ISORIG_WS_PER_MESSAGE_DEFLATE": "1" if deflate else "0"}
        cmd = [sys.executable, "-m", "isorig", "serve", "--port", str(self.port), "--data-dir", data_dir,
               "--log-level", "warning"]
        if database_url:
            cmd += ["--database-url", database_url]
        if rig:
            cmd += ["--rig", rig]
        self.process = subprocess.Popen(cmd, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                                        preexec_fn=(lambda: os.nice(nice)) if nice else None)

    def wait_up(self, http) -> None:
        import httpx

        deadline = time.monotonic() + 60
        while time.monotonic() < deadline:
            try:
                if http.get(f"{self.base}/api/health").status_code == 200:
                    return
            except httpx.TransportError:
                pass
            if self.process.poll() is not None:
                raise RuntimeError("isorig serve exited during start-up")
            time.sleep(0.1)
        raise RuntimeError("isorig serve did not come up within 60 s")

    def cpu_s(self) -> float:
        """CPU time (user + system) the service process has used so far (Linux /proc)."""
        try:
            fields = open(f"/proc/{self.process.pid}/stat").read().rsplit(")", 1)[1].split()
            return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")
        except (OSError, ValueError, IndexError):
            return float("nan")

    def stop(self) -> None:
        if self.process.poll() is None:
            self.process.send_signal(signal.SIGINT)
            try:
                self.process.wait(15)
            except subprocess.TimeoutExpired:
                self.process.kill()


def _create(http, svc: Service, cycles: int, speed: float) -> int:
    body = {"isolator": "IUT_a", "supply_bar": 100, "controller": "pid", "speed": speed,
            "profile": {"kind": "sine", "amplitude_m": 0.02, "frequency_hz": 1.0, "cycles": cycles,
                        "taper_cycles": 1}, "label": "bench-stream"}
    r = http.post(f"{svc.base}/api/tests", json=body, headers={"Authorization": f"Bearer {svc.token}"})
    r.raise_for_status()
    return r.json()["id"]


async def _paced_run(svc: Service, http, duration_s: float, clients: int) -> dict:
    import httpx
    import websockets

    test_id = _create(http, svc, max(2, int(round(duration_s))), 1.0)
    cpu0, wall0 = svc.cpu_s(), time.monotonic()
    received: list[list[tuple[float, list[float]]]] = [[] for _ in range(clients)]
    sockets = [await websockets.connect(f"ws://127.0.0.1:{svc.port}/ws/tests/{test_id}", max_size=None)
               for _ in range(clients)]
    for ws in sockets:
        json.loads(await ws.recv())  # hello

    async def listen(i, ws):
        async for text in ws:
            now = time.time()
            msg = json.loads(text)
            if msg["type"] == "samples":
                received[i].append((now, [row[0] for row in msg["rows"]]))
            elif msg["type"] == "status" and msg["status"] not in ("ready", "running"):
                return

    tasks = [asyncio.create_task(listen(i, ws)) for i, ws in enumerate(sockets)]
    r = await asyncio.to_thread(http.post, f"{svc.base}/api/tests/{test_id}/start",
                                headers={"Authorization": f"Bearer {svc.token}"})
    r.raise_for_status()
    api_ms, api_failures = [], 0
    while True:
        t_req = time.monotonic()
        try:
            record = (await asyncio.to_thread(http.get, f"{svc.base}/api/tests/{test_id}")).json()
        except httpx.TransportError:
            api_failures += 1
            continue
        api_ms.append((time.monotonic() - t_req) * 1e3)
        if record["status"] not in ("ready", "running"):
            break
        await asyncio.sleep(0.5)
    if tasks:
        await asyncio.wait(tasks, timeout=10)
    server_cpu = {"cpu_s": svc.cpu_s() - cpu0, "wall_s": time.monotonic() - wall0}
    server_cpu["share_of_one_cpu"] = server_cpu["cpu_s"] / server_cpu["wall_s"]
    for ws in sockets:
        await ws.close()
    wall_t0 = datetime.fromisoformat(record["started_at"]).timestamp()
    latencies = []
    per_client_samples = []
    for batches in received:
        count = 0
        for recv_time, times in batches:
            for t in times:
                latencies.append((recv_time - (wall_t0 + t + 1e-3)) * 1e3)
            count += len(times)
        per_client_samples.append(count)
    return {"test_id": test_id, "status": record["status"], "reason": record.get("reason"),
            "events": [e["message"] for e in (record.get("events") or []) if e.get("kind") in ("rig_fault",
                                                                                              "limit_trip")],
            "test_time_s": record["time_s"],
            "samples_stored": record["samples_stored"], "clients": clients,
            "samples_per_client": per_client_samples, "pacing": record["summary"].get("pacing", {}),
            "latency": _percentiles(latencies), "server_cpu": server_cpu,
            "api_get_during_run": {**_percentiles(api_ms), "failures": api_failures}}


def _storage_run(svc: Service, http, minutes: float, speed: float) -> dict:
    from sim.samples import N_FIELDS

    cycles = int(round(minutes * 60))
    test_id = _create(http, svc, cycles, speed)
    http.post(f"{svc.base}/api/tests/{test_id}/start", headers={"Authorization": f"Bearer {svc.token}"})
    while True:
        record = http.get(f"{svc.base}/api/tests/{test_id}").json()
        if record["status"] not in ("ready", "running"):
            break
        time.sleep(0.5)
    stored = record["summary"]["storage_bytes"]
    return {"test_id": test_id, "status": record["status"], "minutes": record["time_s"] / 60,
            "samples": record["samples_stored"], "columns": N_FIELDS, "speed": speed, "storage_bytes": stored,
            "storage_mb": stored / 1e6, "raw_float64_mb": record["samples_stored"] * N_FIELDS * 8 / 1e6}


def run(args) -> int:
    import httpx

    from isorig.cli import UsageError

    if args.duration_s < 2 or args.clients < 0 or args.storage_minutes <= 0:
        raise UsageError("isorig bench-stream: --duration-s >= 2, --clients >= 0, --storage-minutes > 0")
    results: dict = {"load_average_start": os.getloadavg(), "cpus": os.cpu_count(), "nice": args.nice,
                     "ws_deflate": args.ws_deflate}
    if args.nice:
        try:
            os.nice(args.nice)
        except OSError as exc:
            raise UsageError(f"isorig bench-stream: --nice {args.nice} not permitted: {exc.strerror}") from None
    with tempfile.TemporaryDirectory(prefix="isorig-bench-") as data_dir:
        svc = Service(data_dir, args.database_url, args.nice, args.ws_deflate)
        try:
            with httpx.Client(timeout=30) as http:
                svc.wait_up(http)
                print(f"service up on {svc.base}; paced runs of {args.duration_s:g} s ...", file=sys.stderr)
                if args.baseline:
                    results["baseline_no_clients"] = asyncio.run(_paced_run(svc, http, args.duration_s, 0))
                results["paced"] = asyncio.run(_paced_run(svc, http, args.duration_s, args.clients))
                print(f"storage run: {args.storage_minutes:g} min at {args.storage_speed:g}x ...", file=sys.stderr)
                results["storage"] = _storage_run(svc, http, args.storage_minutes, args.storage_speed)
        finally:
            svc.stop()
    results["load_average_end"] = os.getloadavg()
    if args.json:
        print(json.dumps(results, indent=2))
        return 0
    for key in ("baseline_no_clients", "paced"):
        if key not in results:
            continue
        r = results[key]
        p = r["pacing"]
        nan = float("nan")
        print(f"[{key}] test {r['test_id']} {r['status']}, {r['test_time_s']:.1f} s at speed 1, "
              f"{r['clients']} websocket clients")
        print(f"  pacing lateness per 20 ms chunk: p50 {p.get('lateness_p50_ms', nan):.3f} ms, "
              f"p99 {p.get('lateness_p99_ms', nan):.3f} ms, max {p.get('lateness_max_ms', nan):.3f} ms "
              f"({p.get('late_over_2ms', 0)} of {p.get('chunks', 0)} chunks later than 2 ms)  [target p99 < 2 ms]")
        if "server_arrival_p95_ms" in p:
            print(f"  chunk arrival at the server (newest sample): p50 {p['server_arrival_p50_ms']:.1f} ms, "
                  f"p95 {p['server_arrival_p95_ms']:.1f} ms, max {p['server_arrival_max_ms']:.1f} ms")
        c = r["server_cpu"]
        print(f"  service process CPU: {c['cpu_s']:.1f} s over {c['wall_s']:.1f} s "
              f"({100 * c['share_of_one_cpu']:.0f} % of one CPU; the worker is a separate process)")
        a = r["api_get_during_run"]
        print(f"  GET /api/tests/{{id}} while streaming: p50 {a.get('p50_ms', nan):.1f} ms, "
              f"max {a.get('max_ms', nan):.1f} ms over {a['n']} requests, {a['failures']} timed out (30 s)")
        lat = r["latency"]
        if lat.get("n"):
            print(f"  sample-to-client latency over {lat['n']} samples: p50 {lat['p50_ms']:.1f} ms, "
                  f"p95 {lat['p95_ms']:.1f} ms, p99 {lat['p99_ms']:.1f} ms, max {lat['max_ms']:.1f} ms  "
                  f"[target p95 < 50 ms]; samples per client {min(r['samples_per_client'])}-"
                  f"{max(r['samples_per_client'])} of {r['samples_stored']}")
    print(f"machine: {results['cpus']} CPUs, load average {results['load_average_start'][0]:.1f} at start, "
          f"{results['load_average_end'][0]:.1f} at end; service and clients at nice {args.nice}; "
          f"websocket compression {'on' if args.ws_deflate else 'off'}")
    s = results["storage"]
    print(f"[storage] {s['minutes']:.1f} min at 1 kHz ({s['samples']} samples x {s['columns']} columns): "
          f"{s['storage_mb']:.1f} MB stored (raw float64 {s['raw_float64_mb']:.1f} MB)  [target < 30 MB]")
    return 0
