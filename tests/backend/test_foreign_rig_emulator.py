"""A foreign rig (foreign_rigs: written from the physics, not from isorig's model) played by the rig emulator in
its own process, behind the rig protocol: the protocol holds, commissioning runs through UDP from what the lab
knows and either writes a rig file or refuses with its reasons, and a 2 mm test on it ends with the valve closed
and the rig disarmed, whatever became of it."""

from __future__ import annotations

import json
import subprocess

import pytest
from emulator import ISORIG, Emulator, simulate_on

from foreign_rigs import draw_rig
from sim.commission.foreign_campaign import start_rig_file_data

# real time against the rig emulator in its own process: scripts/test.sh runs these alone, after the others
pytestmark = pytest.mark.realtime

SEED = 3  # a single-rod, critically lapped 24 Hz valve, 940 kg, a soft rubber bearing


def isorig(*args: str, timeout_s: float = 240.0) -> subprocess.CompletedProcess:
    return subprocess.run([*ISORIG, *args], capture_output=True, text=True, timeout=timeout_s)


def start_rig_file(path, seed: int) -> None:
    """What the lab knows, as the start rig file it writes (RigParameters names, SI)."""
    path.write_text(json.dumps(start_rig_file_data(draw_rig(seed).lab_knows())))


@pytest.mark.strict_timing  # check-rig at an 18 ms watchdog
def test_a_foreign_rig_keeps_the_protocol(tmp_path):
    emulator = Emulator(tmp_path, "--foreign-rig", str(SEED), "--rig-protocol", "1", watchdog_ms=18.0)
    try:
        assert emulator.status()["plant"]["name"].startswith(f"foreign rig {SEED} (single-rod")
        check = isorig("check-rig", emulator.url, "--rig-protocol", "1", timeout_s=120)
        assert check.returncode == 0, check.stdout + check.stderr
    finally:
        emulator.stop()


def test_a_foreign_rig_commissioned_and_tested_through_udp(tmp_path):
    # the helper's 100 ms watchdog: this test is about commissioning and the stop paths on a loaded machine
    emulator = Emulator(tmp_path, "--foreign-rig", str(SEED), "--rig-protocol", "1")
    start = tmp_path / "start.json"
    start_rig_file(start, SEED)
    try:
        ident = isorig("identify", "rig", "--rig", emulator.url, "--rig-protocol", "1", "--supply-bar", "100",
                       "--isolator", "none", "--rig-file", str(start), "--out", str(tmp_path / "rig.json"))
        text = ident.stdout + ident.stderr
        assert ident.returncode in (0, 1), text
        if ident.returncode == 0:
            assert "verdict: trusted" in text and (tmp_path / "rig.json").exists()
            rig_file = tmp_path / "rig.json"
        else:  # refused: the reasons said, no rig file
            assert "verdict: NOT trusted" in text and not (tmp_path / "rig.json").exists(), text
            rig_file = start
        assert not emulator.fresh_status()["armed"]
        code, summary, text = simulate_on(emulator.url, tmp_path / "test", "--rig-protocol", "1", "--rig-file",
                                          str(rig_file), "--amplitude-m", "0.002", cycles=4, frequency_hz=1.0)
        assert code in (0, 1), text
        assert summary is not None and summary["status"] in ("completed", "aborted", "failed"), text
        if summary["status"] != "completed":
            assert summary["reason"], summary
    finally:
        status = emulator.stop()
    assert not status["armed"] and status["command_v"] == 0.0  # every ending leaves the valve closed
    assert status["counters"]["arms"] >= 2
