"""Crashes: the worker process killed mid-test, and the whole server killed and restarted on its database."""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import httpx
import pytest
from conftest import AUTH, TOKEN, create_and_start, make_settings, sine_test, wait_for, zero_table
from fastapi.testclient import TestClient

from backend.app import create_app

pytestmark = pytest.mark.slow  # services signalled and killed, seconds each: scripts/test.sh --quick leaves it out

LONG = {"speed": 1.0, "profile": {"frequency_hz": 2.0, "cycles": 40, "taper_cycles": 1}}  # 20 s


def alive(pid: int) -> bool:
    try:
        state = Path(f"/proc/{pid}/status").read_text()
    except OSError:
        return False
    return "\nState:\tZ" not in state


def wait_samples(client_get, test_id: int, min_time_s: float, timeout_s: float = 20.0) -> dict:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        rec = client_get(f"/api/tests/{test_id}").json()
        if rec["samples_stored"] > 0 and rec["time_s"] >= min_time_s:
            return rec
        time.sleep(0.05)
    raise AssertionError("no samples stored in time")


def test_killing_the_worker_aborts_the_test_and_keeps_its_data(client):
    test_id = create_and_start(client, **LONG)
    wait_samples(client.get, test_id, 0.8)
    pid = client.get("/api/rig").json()["state"]["worker_pid"]
    assert pid != os.getpid() and alive(pid)
    os.kill(pid, signal.SIGKILL)
    rec = wait_for(client, test_id, timeout_s=10)
    assert rec["status"] == "aborted"
    assert "exit code -9" in rec["reason"]
    assert 800 <= rec["samples_stored"] < 20000
    lines = client.get(f"/api/tests/{test_id}/data.csv").text.splitlines()
    assert len(lines) == 1 + rec["samples_stored"]
    # the rig is free again; the table rests where the killed test left it, so no test starts until the
    # operator brings it back to zero
    assert client.get("/api/rig").json()["state"]["status"] == "idle"
    if abs(client.get("/api/rig/state").json()["table_position_m"]) > 0.002:
        r = client.post("/api/tests?start=true", json=sine_test(), headers=AUTH)
        assert r.status_code == 409 and "move the table to zero first" in r.json()["detail"]
        zero_table(client)
    next_id = create_and_start(client)
    assert wait_for(client, next_id)["status"] == "completed"


def last_displacement_m(client_get, test_id: int) -> float:
    lines = client_get(f"/api/tests/{test_id}/data.csv").text.splitlines()
    header = lines[0].split(",")
    return float(lines[-1].split(",")[header.index("displacement_m")])


def test_sigterm_to_the_worker_stops_under_control_and_ctrl_c_does_not_reach_it(client):
    """Ctrl-C in the service's terminal reaches the worker too (one process group): it is the service's to
    handle, the test runs on. SIGTERM (its process group told to stop) brings the table back under control
    (issue 21: it used to stop at once, the table left mid-stroke); a second SIGTERM would end it at once."""
    test_id = create_and_start(client, **LONG)
    wait_samples(client.get, test_id, 0.5)
    pid = client.get("/api/rig").json()["state"]["worker_pid"]
    os.kill(pid, signal.SIGINT)
    before = wait_samples(client.get, test_id, 0.5)["time_s"]
    wait_samples(client.get, test_id, before + 0.5)  # still running after Ctrl-C
    assert alive(pid) and client.get(f"/api/tests/{test_id}").json()["status"] == "running"
    os.kill(pid, signal.SIGTERM)
    rec = wait_for(client, test_id, timeout_s=20)
    assert rec["status"] == "interrupted" and "told to stop" in rec["reason"], rec["reason"]
    assert "went back to 0 mm under control" in rec["reason"]
    assert rec["samples_stored"] >= 1000
    lines = client.get(f"/api/tests/{test_id}/data.csv").text.splitlines()
    assert len(lines) == 1 + rec["samples_stored"]
    assert abs(last_displacement_m(client.get, test_id)) < 0.001  # at rest where the test began
    assert any(e["values"].get("action") == "shutdown" for e in rec["events"] if e["kind"] == "operator")
    # the next test starts: the table is at zero
    assert wait_for(client, create_and_start(client))["status"] == "completed"


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def serve(data_dir, **popen) -> tuple[subprocess.Popen, str]:
    """``isorig serve`` on a free port in its own process (simulated rig): the process and its base URL."""
    port = free_port()
    # no report warm-up (2.8 s of CPU a start): nothing here renders a report (test_report_warm_up.py tests it)
    env = {**os.environ, "ISORIG_OPERATOR_TOKEN": TOKEN, "ISORIG_VIEWER": "0", "ISORIG_REPORT_WARM_UP": "false"}
    cmd = [sys.executable, "-m", "isorig", "serve", "--port", str(port), "--data-dir", str(data_dir),
           "--log-level", "warning"]
    server = subprocess.Popen(cmd, env=env, stdout=subprocess.DEVNULL, text=True, **popen)
    return server, f"http://127.0.0.1:{port}"


def wait_up(http, timeout_s: float = 30.0) -> None:
    deadline = time.monotonic() + timeout_s
    while True:
        try:
            if http.get("/api/health").status_code == 200:
                return
        except httpx.TransportError:
            pass
        assert time.monotonic() < deadline, "server did not come up"
        time.sleep(0.1)


def test_server_killed_mid_test_restarts_with_the_test_interrupted(tmp_path):
    server, base = serve(tmp_path, stderr=subprocess.DEVNULL)
    try:
        with httpx.Client(base_url=base, timeout=10) as http:
            wait_up(http)
            test_id = http.post("/api/tests", json=sine_test(**LONG), headers=AUTH).json()["id"]
            assert http.post(f"/api/tests/{test_id}/start", headers=AUTH).status_code == 200
            before = wait_samples(http.get, test_id, 1.5)
            worker_pid = http.get("/api/rig").json()["state"]["worker_pid"]
            t_seen = http.get(f"/api/tests/{test_id}").json()["time_s"]
        server.send_signal(signal.SIGKILL)
        server.wait(10)
    finally:
        if server.poll() is None:
            server.kill()
    # the orphaned worker notices the broken pipe and ends
    deadline = time.monotonic() + 10
    while alive(worker_pid) and time.monotonic() < deadline:
        time.sleep(0.1)
    assert not alive(worker_pid)
    # restart on the same database
    with TestClient(create_app(make_settings(tmp_path))) as client:
        rec = client.get(f"/api/tests/{test_id}").json()
        assert rec["status"] == "interrupted"
        assert "running" in rec["reason"]
        assert rec["samples_stored"] >= before["samples_stored"]
        assert rec["time_s"] >= t_seen - 1.0  # at most about a second lost
        assert rec["events"][-1]["kind"] == "status"
        lines = client.get(f"/api/tests/{test_id}/data.csv").text.splitlines()
        assert len(lines) == 1 + rec["samples_stored"]
        # and the restarted service runs tests
        assert wait_for(client, create_and_start(client))["status"] == "completed"


def test_service_shutdown_marks_the_running_test_interrupted(tmp_path):
    settings = make_settings(tmp_path)
    with TestClient(create_app(settings)) as client:
        test_id = create_and_start(client, **LONG)
        wait_samples(client.get, test_id, 0.3)
    # leaving the block runs the lifespan shutdown: the worker is stopped and the test recorded as interrupted
    with TestClient(create_app(settings)) as client:
        rec = client.get(f"/api/tests/{test_id}").json()
        assert rec["status"] == "interrupted" and "told to stop" in rec["reason"], rec["reason"]
        assert rec["samples_stored"] >= 300
        assert abs(last_displacement_m(client.get, test_id)) < 0.001  # brought back before the service ended


@pytest.mark.parametrize("how", ["SIGTERM to the service", "SIGINT to its process group",
                                 "SIGTERM to its process group"])
def test_a_service_told_to_stop_brings_the_table_back_and_records_why_before_it_exits(tmp_path, how):
    """Issue 21: SIGTERM (docker stop) or Ctrl-C mid-test left the table at 18-30 mm. The service now stops the
    test under control, brings the table back to where the test began, records how it ended, then exits."""
    server, base = serve(tmp_path, stderr=subprocess.PIPE, start_new_session=True)
    body = sine_test(isolator="IUT_b", supply_bar=70, speed=1.0,
                     profile={"amplitude_m": 0.03, "frequency_hz": 0.5, "cycles": 20, "taper_cycles": 1})
    try:
        with httpx.Client(base_url=base, timeout=10) as http:
            wait_up(http, timeout_s=60)
            test_id = http.post("/api/tests", json=body, headers=AUTH).json()["id"]
            assert http.post(f"/api/tests/{test_id}/start", headers=AUTH).status_code == 200
            wait_samples(http.get, test_id, 2.0, timeout_s=30)  # mid-stroke, well away from zero
        sig = signal.SIGINT if "SIGINT" in how else signal.SIGTERM
        if "group" in how:
            os.killpg(server.pid, sig)
        else:
            server.send_signal(sig)
        code = server.wait(40)
        log = server.stderr.read()
    finally:
        if server.poll() is None:
            os.killpg(server.pid, signal.SIGKILL)
            server.wait(10)
    assert code in (0, -sig, 128 + sig), (code, log[-2000:])
    with TestClient(create_app(make_settings(tmp_path))) as client:
        rec = client.get(f"/api/tests/{test_id}").json()
        assert rec["status"] == "interrupted" and "told to stop" in rec["reason"], (rec["reason"], log[-2000:])
        y_end = last_displacement_m(client.get, test_id)
        assert abs(y_end) < 0.001, y_end  # at rest within 1 mm of where the test began, before the exit
        assert rec["events"][-1]["kind"] == "status"  # the end was recorded by the service itself

