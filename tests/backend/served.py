"""`isorig serve` in a process of its own for the tests: start it on a port, wait until it answers, end it."""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import time

import httpx
from conftest import TOKEN

# a shared test machine: no real-time priority, no 3D view, no report warm-up (seconds of CPU)
ENV = {"ISORIG_OPERATOR_TOKEN": TOKEN, "ISORIG_VIEWER": "0", "ISORIG_WORKER_REALTIME": "false",
       "ISORIG_REPORT_WARM_UP": "false"}


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def serve(port: int, *args: str) -> subprocess.Popen:
    """``isorig serve --port PORT ARGS`` (simulated rig), its stderr piped (text), in its own session."""
    cmd = [sys.executable, "-m", "isorig", "serve", "--port", str(port), "--log-level", "warning", *args]
    return subprocess.Popen(cmd, env={**os.environ, **ENV}, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                            text=True, start_new_session=True)


def wait_up(server: subprocess.Popen, base: str, timeout_s: float = 60.0) -> None:
    deadline = time.monotonic() + timeout_s
    with httpx.Client(base_url=base, timeout=5) as http:
        while True:
            assert server.poll() is None, f"the service exited ({server.returncode}): {server.stderr.read()[-3000:]}"
            try:
                if http.get("/api/health").status_code == 200:
                    return
            except httpx.TransportError:
                pass
            assert time.monotonic() < deadline, "the service did not come up"
            time.sleep(0.1)


def stop(server: subprocess.Popen) -> None:
    """SIGTERM to the service (it ends its test and exits), SIGKILL to its group if it does not within 30 s."""
    if server.poll() is None:
        server.send_signal(signal.SIGTERM)
        try:
            server.wait(30)
        except subprocess.TimeoutExpired:
            os.killpg(server.pid, signal.SIGKILL)
            server.wait(10)
    if server.stderr is not None:
        server.stderr.close()
