"""A rig emulator in its own process (``isorig rig-emulator``) for the tests, and ``isorig simulate --rig`` runs."""

from __future__ import annotations

import json
import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

ISORIG = [sys.executable, "-m", "isorig"]


class Emulator:
    """``isorig rig-emulator`` on a free UDP port (or ``port``), with its status file; stop() ends it."""

    def __init__(self, tmp_path: Path, *flags: str, port: int = 0, isolator: str = "IUT_a", name: str = "emulator",
                 watchdog_ms: float = 100.0):
        """``watchdog_ms``: longer than a rig's 18 ms default. CI runs these tests at normal priority (a container
        without CAP_SYS_NICE) beside other work, where the host can stall for 18 ms; what a test here checks is
        the link, the faults and the record. The 18 ms watchdog itself is checked by tests/backend/
        test_check_rig.py, and the host's lateness by ``isorig bench-rig``."""
        self.status_file = tmp_path / f"{name}-status.json"
        self.watchdog_ms = watchdog_ms
        self.proc = subprocess.Popen([*ISORIG, "rig-emulator", "--port", str(port), "--isolator", isolator,
                                     "--status-file", str(self.status_file), "--watchdog-ms", f"{watchdog_ms:g}",
                                     *flags],
                                    stderr=subprocess.PIPE, stdout=subprocess.DEVNULL, text=True)
        line = self.proc.stderr.readline()
        match = re.search(r"udp://([\d.]+):(\d+)", line)
        if match is None:
            self.proc.kill()
            raise AssertionError(f"the emulator did not start: {line}{self.proc.stderr.read()}")
        self.port = int(match.group(2))
        self.url = f"udp://127.0.0.1:{self.port}"
        forging = re.search(r"forging port (\d+)", line)  # --tap-port: the tap's port for forged datagrams
        self.forge_port = int(forging.group(1)) if forging else None
        try:
            self.status()  # the status file exists once the loop runs
        except (OSError, ValueError):
            self.proc.kill()  # never left running: a stray emulator's loop disturbed every real-time test after it
            self.proc.wait(5)
            raise

    def status(self, timeout_s: float = 10.0) -> dict:
        deadline = time.monotonic() + timeout_s
        while True:
            try:
                return json.loads(self.status_file.read_text())
            except (OSError, ValueError):
                if time.monotonic() > deadline:
                    raise
                time.sleep(0.05)

    def fresh_status(self, timeout_s: float = 5.0) -> dict:
        """The status as the emulator wrote it after this call (it rewrites its file twice a second; the machine's
        monotonic clock is one for every process): a quarter of a second on average, where a fixed 0.6 s sleep was
        31 times 0.6 s of the real-time tests."""
        asked = time.monotonic()
        deadline = asked + timeout_s
        while True:
            status = self.status()
            if status.get("written_monotonic_s", 0.0) > asked or time.monotonic() > deadline:
                return status
            time.sleep(0.02)

    def kill(self) -> None:
        self.proc.send_signal(signal.SIGKILL)
        self.proc.wait(5)

    def stop(self) -> dict:
        if self.proc.poll() is None:
            self.proc.terminate()
            self.proc.wait(10)
        return self.status()


def simulate_on(url: str, out: Path, *args: str, cycles: int = 3, frequency_hz: float = 2.0,
                wait: bool = True, **popen):
    """``isorig simulate --rig url`` (IUT_a, 100 bar, 10 mm): (exit code, summary, stdout), or the process."""
    cmd = [*ISORIG, "simulate", "--rig", url, "--out", str(out), "--isolator", "IUT_a", "--supply-bar", "100",
           "--amplitude-m", "0.01", "--frequency-hz", str(frequency_hz), "--cycles", str(cycles), *args]
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    if not wait:
        return subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=env, **popen)
    proc = subprocess.run(cmd, capture_output=True, text=True, env=env, timeout=120)
    summary_file = out / "summary.json"
    summary = json.loads(summary_file.read_text()) if summary_file.exists() else None
    return proc.returncode, summary, proc.stdout + proc.stderr


def read_record(out: Path) -> dict:
    """The columns of a timeseries.csv by name."""
    from sim.metrics import read_csv_columns

    return read_csv_columns(out / "timeseries.csv", required=("time_s", "voltage_v", "flags"),
                            optional=("target_m", "displacement_m", "measured_displacement_m"))
