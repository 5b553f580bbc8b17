"""One host at a time, and nothing starts blind: against the rig emulator in its own process.

A second host's ARM while a test runs is dropped by the rig (``busy``), and the host side refuses to start a
test or a move while the rig says it is armed or does not answer (where its table is is then unknown).
"""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import time

import pytest
from emulator import ISORIG, Emulator, simulate_on

from backend.drivers.udp import start_position_problem
from sim.emulator import protocol as proto

# real time against the rig emulator in its own process: scripts/test.sh runs these alone, after the others
pytestmark = pytest.mark.realtime


def wait_armed(emulator: Emulator, timeout_s: float = 30.0) -> dict:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        status = emulator.status()
        if status["armed"]:
            return status
        time.sleep(0.1)
    raise AssertionError(f"the emulator was never armed: {emulator.status()}")


def free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


def test_a_second_host_cannot_take_over_a_rig_that_runs_a_test(tmp_path):
    """The checks run while the first test runs: its 16 s outlast them on a loaded machine (a clean-clone run with
    two CPU hogs beside took so long to start `isorig move` that an 8 s test had ended before the foreign ARMs)."""
    emulator = Emulator(tmp_path)
    first = None
    try:
        first = simulate_on(emulator.url, tmp_path / "first", cycles=16, frequency_hz=1.0, wait=False)
        armed = wait_armed(emulator)
        # the rig side: an ARM of another session is dropped, the running test keeps the rig
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
            for _ in range(3):
                sock.sendto(proto.encode(proto.ARM, armed["session"] + 1, 0, 0, 100e5, 1.25e5),
                            ("127.0.0.1", emulator.port))
                time.sleep(0.05)
        # the host side: neither a test nor a move starts while the rig is armed
        problem = start_position_problem(emulator.url, timeout_s=0.5)
        assert problem is not None and "armed" in problem and "nothing moved" in problem
        move = subprocess.run([*ISORIG, "move", "--rig", emulator.url, "--position-m", "0.01"],
                              capture_output=True, text=True, timeout=60)
        still = emulator.fresh_status()
        assert still["armed"] and still["session"] == armed["session"], "the first test ended before the checks"
        assert move.returncode == 2 and "armed" in move.stderr and "Traceback" not in move.stderr, move.stderr
        out, _ = first.communicate(timeout=120)
        assert first.returncode == 0, out
        status = emulator.fresh_status()
        assert status["rejected"].get("busy", 0) >= 3, status["rejected"]
        assert status["counters"]["arms"] == 1 and not status["armed"]
        assert "completed" in out
    finally:
        if first is not None and first.poll() is None:
            first.kill()
        emulator.stop()


def test_a_rig_that_does_not_answer_starts_nothing(tmp_path):
    url = f"udp://127.0.0.1:{free_udp_port()}"
    problem = start_position_problem(url, timeout_s=0.2)
    assert problem is not None and "unknown" in problem and "nothing moved" in problem
    code, summary, out = simulate_on(url, tmp_path / "run", cycles=2)
    assert code == 2 and summary is None and "unknown" in out and "Traceback" not in out, out


def test_the_first_reading_after_arming_sends_no_command_to_a_table_off_zero(tmp_path):
    """The probe before a start can be raced (a lost answer, another host): the worker's own check on the
    first armed reading is the one that holds. Run past the probe, straight to the worker."""
    from isorig.commands.rig_run import rig_job, run_job
    from sim.engine import Scenario

    emulator = Emulator(tmp_path)
    try:
        moved = subprocess.run([*ISORIG, "move", "--rig", emulator.url, "--position-m", "0.01",
                                "--speed-m-per-s", "0.02"], capture_output=True, text=True, timeout=60)
        assert moved.returncode == 0, moved.stdout + moved.stderr
        at = emulator.fresh_status()["position_m"]
        assert abs(at - 0.01) < 1e-3
        _run, sent, status, reason, _wall = run_job(rig_job(emulator.url, Scenario.sine("IUT_a", 100, 0.01, 1.0, 3)))
        assert status == "failed" and "at arming" in reason and "no command was sent" in reason, reason
        assert len(sent.samples()) == 0
        after = emulator.fresh_status()
        assert after["position_m"] == pytest.approx(at, abs=2e-5) and not after["armed"]
        assert after["counters"]["disarms"] == 2  # the move's and this run's
    finally:
        emulator.stop()


def test_sigterm_to_the_worker_brings_the_table_home_and_disarms_the_rig_before_the_watchdog_has_to(tmp_path):
    from conftest import create_and_start, make_settings, wait_for
    from fastapi.testclient import TestClient

    from backend.app import create_app

    emulator = Emulator(tmp_path)
    try:
        with TestClient(create_app(make_settings(tmp_path, rig=emulator.url))) as client:
            test_id = create_and_start(client, speed=1.0, profile={"frequency_hz": 1.0, "cycles": 10})
            deadline = time.monotonic() + 30
            while client.get(f"/api/tests/{test_id}").json()["samples_stored"] < 500:
                assert time.monotonic() < deadline
                time.sleep(0.05)
            os.kill(client.get("/api/rig").json()["state"]["worker_pid"], signal.SIGTERM)
            rec = wait_for(client, test_id)
            # a controlled stop home (issue 21), then the worker disarms the rig itself
            assert rec["status"] == "interrupted" and "told to stop" in rec["reason"], rec["reason"]
            assert rec["samples_stored"] >= 500
        status = emulator.fresh_status()
        assert status["counters"]["disarms"] == 1 and not status["watchdog_trips"] and not status["armed"]
        assert abs(status["position_m"]) < 0.001  # the table is back where the test began
    finally:
        emulator.stop()
