"""A loop that keeps its period (issue 33 item 6): the rig emulator, late for a tick, keeps its period from there
instead of sending the next measurement right after the late one (a period the host could not have answered)."""

from __future__ import annotations

import socket
import sys
import threading
import time

import pytest

from sim.emulator import protocol as proto
from sim.emulator.server import SLIP_PERIODS, EmulatorConfig, RigEmulator
from sim.isolator import PRESETS

P = 1e-3


class LateRig(RigEmulator):
    """The emulator, woken ``late_s`` late for the ticks in ``late_at`` (counted from ARM)."""

    def __init__(self, config, late_at, late_s):
        super().__init__(config)
        self.late_at, self.late_s = set(late_at), late_s

    def _pump_until(self, due):
        super()._pump_until(due)
        if self.armed and self.sequence + 1 in self.late_at:
            end = time.perf_counter() + self.late_s
            while time.perf_counter() < end:  # busy: as a process the OS did not run
                pass


@pytest.mark.realtime  # an emulator on the wall clock: run alone (scripts/test.sh)
@pytest.mark.strict_timing
@pytest.mark.parametrize("late_periods", [0.8, 1.6])
def test_a_late_tick_does_not_send_the_next_measurement_at_once(late_periods):
    """Ticks 200, 400 and 600 wake ``late_periods`` late: each measurement still leaves at least half a period
    after the one before (on the old grid the next one followed 0.2 ms after, or at once), numbered on by one,
    and the emulator counts the slips."""
    rig = LateRig(EmulatorConfig(PRESETS["IUT_a"], 0, watchdog_s=0.1), (200, 400, 600), late_periods * P)
    switch = sys.getswitchinterval()
    sys.setswitchinterval(1e-4)  # the rig's thread and this one share the interpreter
    server = threading.Thread(target=rig.serve, daemon=True)
    got = []
    try:
        server.start()
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as host:
            host.connect(("127.0.0.1", rig.port))
            host.settimeout(1.0)
            session = 4242
            host.send(proto.encode(proto.ARM, session, 0, 0, 100e5, 1e5))
            while len(got) < 700:
                m = proto.decode(host.recv(256))
                if m.kind != proto.MEASUREMENT or m.session != session:
                    continue
                got.append(m)
                host.send(proto.encode(proto.COMMAND, session, m.sequence, 0, 0.0))
            host.send(proto.encode(proto.DISARM, session, 0, 0))
    finally:
        rig.stop()
        server.join(5)
        sys.setswitchinterval(switch)
        rig.close()
    assert [m.sequence for m in got] == list(range(700))
    gaps_ms = {m.sequence: (m.time_ns - prev.time_ns) / 1e6 for prev, m in zip(got, got[1:], strict=False)}
    for k in (200, 400, 600):
        # the late tick's measurement left late; the next one a period after it, not on the old grid
        assert gaps_ms[k] > (1 + late_periods - 0.2) and gaps_ms[k + 1] > SLIP_PERIODS, (k, gaps_ms[k], gaps_ms[k + 1])
    counters = rig.status()["counters"]
    assert counters["ticks_slipped"] >= 3
    assert (counters["overruns"] >= 3) == (late_periods >= 1.0) or counters["overruns"] >= 3


def test_the_latency_histogram_keeps_the_exact_mean():
    """sim.latency.LatencyHistogram: the mean is the values' (not the 10 us bins'), NaN and negatives counted as 0,
    as in every other figure of it."""
    import math

    import numpy as np

    from sim.latency import LatencyHistogram

    values = np.random.default_rng(3).exponential(0.3, 5000)
    h = LatencyHistogram()
    assert math.isnan(h.mean_ms)
    for v in values:
        h.add(float(v))
    h.add(float("nan"))
    h.add(-1.0)
    assert h.n == 5002 and h.mean_ms == pytest.approx(values.sum() / 5002, rel=1e-12)


def test_the_bench_hogs_die_with_the_bench():
    """isorig bench-rig's CPU hogs are killed when the bench ends however it ends: a bench killed by SIGKILL left
    two spinning in their own sessions, loading every measurement after it."""
    import os
    import signal
    import subprocess

    code = ("import time\nfrom isorig.commands.bench_rig import CpuHogs\nwith CpuHogs(1) as hogs:\n"
            "    print(hogs.processes[0].pid, flush=True)\n    time.sleep(60)\n")
    bench = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, text=True)
    hog = int(bench.stdout.readline())
    try:
        os.kill(hog, 0)  # spinning
        bench.kill()
        bench.wait(10)
        end = time.monotonic() + 10
        while time.monotonic() < end:
            try:
                os.waitpid(hog, os.WNOHANG)  # not our child: ECHILD; its parent's exit reparents it
            except ChildProcessError:
                pass
            try:
                os.kill(hog, 0)
            except ProcessLookupError:
                break
            if open(f"/proc/{hog}/stat").read().split(") ")[1][0] == "Z":  # killed, not yet reaped
                break
            time.sleep(0.05)
        else:
            pytest.fail(f"the hog {hog} still runs 10 s after its bench was killed")
    finally:
        try:
            os.kill(hog, signal.SIGKILL)
        except ProcessLookupError:
            pass


@pytest.mark.parametrize("how", ["computes", "sleeps"])
def test_the_stall_that_trips_the_watchdog_is_told(how):
    """The stall that ends a test is answered by no command, so neither the period trace nor the command gaps see
    it: the driver keeps it when the rig's last measurement says it disarmed itself (the watchdog), with the loop's
    work before the wait split into its CPU time and the time it was off its CPU (UdpRig.stall_at_fault)."""
    from backend.drivers import ArmConditions, RigFault
    from backend.drivers.udp import UdpRig
    from sim.measurement import STATUS_ARMED, STATUS_WATCHDOG

    rig = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    rig.bind(("127.0.0.1", 0))
    rig.settimeout(2.0)
    go = threading.Event()

    def measurement(session, seq, status):
        return proto.encode(proto.MEASUREMENT, session, seq, time.perf_counter_ns(), 0.0, 0.0, 0.0, 100e5, status,
                            0, 0, 0, 0, 1_000_000)

    def play():
        data, host = rig.recvfrom(256)
        session = proto.decode(data).session
        rig.sendto(measurement(session, 0, STATUS_ARMED), host)
        rig.recvfrom(256)  # the command for period 0
        go.wait(5)
        rig.sendto(measurement(session, 1, STATUS_WATCHDOG), host)

    player = threading.Thread(target=play, daemon=True)
    player.start()
    driver = UdpRig("127.0.0.1", rig.getsockname()[1], timeout_s=1.0)
    try:
        driver.arm(ArmConditions(100e5))
        driver.write(0.0)
        if how == "computes":
            end = time.thread_time() + 0.03
            while time.thread_time() < end:  # 30 ms of the loop's own CPU time
                pass
        else:
            time.sleep(0.03)  # 30 ms off its CPU
        go.set()
        with pytest.raises(RigFault, match="disarmed itself"):
            driver.wait_next_period()
        fatal = driver.link_stats()["stall_at_fault"]
    finally:
        driver.disarm(success=False)
        player.join(5)
        rig.close()
    assert fatal["after_last_command_ms"] >= fatal["busy_ms"] >= 30.0
    if how == "computes":
        assert fatal["cpu_ms"] >= 30.0 and fatal["busy_off_cpu_ms"] < fatal["busy_ms"] - 25.0
    else:
        assert fatal["cpu_ms"] < 10.0 and fatal["busy_off_cpu_ms"] >= 20.0
    assert fatal["rig_sent_after_command_ms"] >= 30.0  # the rig's own send time, on this clock
