"""Issue 33, item 4: kill -9 of the service left its forkserver, resource tracker and check worker alive (about
440 MB each time, re-parented to init, piling up). Every process the service starts must end with it."""

from __future__ import annotations

import os
import signal
import subprocess
import time

import httpx
import psutil
import pytest
from conftest import AUTH, sine_test
from test_crash import LONG, serve, wait_samples, wait_up

pytestmark = pytest.mark.slow  # a real service killed, its processes counted: scripts/test.sh --quick leaves it out


def gone(process: psutil.Process) -> bool:
    try:
        return not process.is_running() or process.status() == psutil.STATUS_ZOMBIE
    except psutil.NoSuchProcess:
        return True


def describe(process: psutil.Process) -> str:
    try:
        return f"{process.pid} {' '.join(process.cmdline())[:160]}"
    except psutil.Error:
        return str(process.pid)


@pytest.mark.parametrize("method", ["forkserver", "spawn"])
def test_kill_9_of_the_service_leaves_none_of_its_processes(tmp_path, monkeypatch, method):
    """The service with a check worker and a test running, killed with SIGKILL: within 5 s none of the processes
    it had started is left (on the code before the fix: the forkserver, the check worker and the resource
    tracker were, 3 of 4)."""
    monkeypatch.setenv("ISORIG_WORKER_START_METHOD", method)
    server, base = serve(tmp_path, stderr=subprocess.DEVNULL, start_new_session=True)
    descendants: list[psutil.Process] = []
    try:
        with httpx.Client(base_url=base, timeout=30) as http:
            wait_up(http, timeout_s=60)
            # a check that fits runs its first cycle in the check pool: its worker processes exist from here on
            check = http.post("/api/tests/check", json=sine_test())
            assert check.status_code == 200 and check.json()["ok"], check.text
            assert "prediction" in check.json() and not check.json()["prediction"].startswith("not run")
            # and a test running: the rig worker too
            test_id = http.post("/api/tests", json=sine_test(**LONG), headers=AUTH).json()["id"]
            assert http.post(f"/api/tests/{test_id}/start", headers=AUTH).status_code == 200
            wait_samples(http.get, test_id, 0.5)
            worker_pid = http.get("/api/rig").json()["state"]["worker_pid"]
        descendants = psutil.Process(server.pid).children(recursive=True)
        pids = {p.pid for p in descendants}
        names = "\n".join(describe(p) for p in descendants)
        # the resource tracker, the rig worker, at least one check worker, and the forkserver they were forked from
        assert worker_pid in pids and len(descendants) >= (4 if method == "forkserver" else 3), names
        assert (method == "forkserver") == any("forkserver" in describe(p) for p in descendants), names
        assert any("resource_tracker" in describe(p) for p in descendants), names
        server.send_signal(signal.SIGKILL)
        server.wait(10)
        deadline = time.monotonic() + 5
        while time.monotonic() < deadline and not all(gone(p) for p in descendants):
            time.sleep(0.1)
        left = [describe(p) for p in descendants if not gone(p)]
        assert not left, f"{len(left)} of the service's {len(descendants)} processes outlived it:\n" + "\n".join(left)
    finally:
        if server.poll() is None:
            server.kill()
            server.wait(10)
        for p in descendants:  # whatever outlived it goes now, not with the next test run
            if not gone(p):
                try:
                    p.kill()
                except psutil.Error:
                    pass
        try:
            os.killpg(server.pid, signal.SIGKILL)
        except OSError:
            pass
