"""The rig emulator's fault injection (sim.emulator.server.Faults): the outage that stands for a stalled host."""

from __future__ import annotations

import math
import subprocess
import sys

import pytest

from sim.emulator.server import Faults


def test_an_outage_repeats_from_its_interval_and_lasts_its_length():
    faults = Faults(outage_every_s=0.7, outage_ms=15.0)
    assert not faults.outage(None)  # not armed: no test time
    assert [faults.outage(t) for t in (0.0, 0.01, 0.699)] == [False] * 3  # the first comes after one interval
    assert [faults.outage(t) for t in (0.7, 0.714, 1.4, 1.41, 2.1049)] == [True] * 5
    assert [faults.outage(t) for t in (0.7151, 1.0, 1.416, 2.116)] == [False] * 4
    assert not Faults().outage(5.0)  # none asked


@pytest.mark.parametrize("every_s, ms", [(0.0, 10.0), (-1.0, 10.0), (math.nan, 10.0), (0.7, 0.0), (0.01, 15.0),
                                         (0.7, math.inf)])
def test_an_outage_that_cannot_be_is_refused_with_what_is_allowed(every_s, ms):
    with pytest.raises(ValueError, match="interval must be a time > 0 s and the outage a time > 0 ms shorter"):
        Faults(outage_every_s=every_s, outage_ms=ms).check()


@pytest.mark.parametrize("flags, words", [(("--outage-every-s", "0.01", "--outage-ms", "15"),
                                           "an outage of 15.0 ms every 0.01 s"),
                                          (("--outage-ms", "15"), "--outage-ms needs --outage-every-s")])
def test_the_emulators_outage_flags_are_checked_at_the_door(flags, words):
    out = subprocess.run([sys.executable, "-m", "isorig", "rig-emulator", "--port", "0", *flags],
                         capture_output=True, text=True, timeout=60)
    assert out.returncode == 2 and "Traceback" not in out.stderr
    assert words in out.stderr


def test_a_status_file_that_cannot_be_written_is_refused_at_start(tmp_path):
    """The emulator ran on for an hour without a status file whose folder was missing (its writer thread died): the
    start now says so and nothing runs."""
    out = subprocess.run([sys.executable, "-m", "isorig", "rig-emulator", "--port", "0", "--status-file",
                          str(tmp_path / "missing" / "status.json")], capture_output=True, text=True, timeout=60)
    assert out.returncode == 2 and "Traceback" not in out.stderr
    assert f"its folder {tmp_path / 'missing'} does not exist or cannot be written" in out.stderr


def test_the_start_line_says_the_outages(tmp_path):
    """What the emulator plays is said when it starts: a lab reading its log sees the outages it asked for."""
    proc = subprocess.Popen([sys.executable, "-m", "isorig", "rig-emulator", "--port", "0", "--outage-every-s", "0.7",
                             "--outage-ms", "15"], stderr=subprocess.PIPE, stdout=subprocess.DEVNULL, text=True)
    try:
        line = proc.stderr.readline()
    finally:
        proc.kill()
        proc.wait(5)
    assert "udp://127.0.0.1:" in line and "OUTAGES of 15 ms every 0.7 s while armed" in line, line
