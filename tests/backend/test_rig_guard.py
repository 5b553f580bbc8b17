"""One host at a time, and nothing starts blind: against the rig emulator in its own process.

A second host's ARM while a test runs is dropped by the rig (``busy``), and the host side refuses to start a
test or a move while the rig says it is armed or does not answer (where its table is is then unknown).
"""

from __future__ import annotations

import socket
import subprocess
import time

from emulator import ISORIG, Emulator, simulate_on

from backend.drivers.udp import start_position_problem
from sim.emulator import protocol as proto


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
    emulator = Emulator(tmp_path)
    first = None
    try:
        first = simulate_on(emulator.url, tmp_path / "first", cycles=8, frequency_hz=1.0, wait=False)
        armed = wait_armed(emulator)
        # the host side: neither a test nor a move starts while the rig is armed
        problem = start_position_problem(emulator.url, timeout_s=0.5)
        assert problem is not None and "armed" in problem and "nothing moved" in problem
        move = subprocess.run([*ISORIG, "move", "--rig", emulator.url, "--position-m", "0.01"],
                              capture_output=True, text=True, timeout=60)
        assert move.returncode == 2 and "armed" in move.stderr and "Traceback" not in move.stderr, move.stderr
        # the rig side: an ARM of another session is dropped, the running test keeps the rig
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
            for _ in range(3):
                sock.sendto(proto.encode(proto.ARM, armed["session"] + 1, 0, 0, 100e5, 1.25e5),
                            ("127.0.0.1", emulator.port))
                time.sleep(0.05)
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
