"""The loop's period trace (issue 33 item 6): every stall of a real-time loop is kept with what ran before it, so a
piece of periodic work that overruns the period is found by name (sim.realtime.PeriodTrace, backend.worker)."""

from __future__ import annotations

import dataclasses
import gc
import os
import re
import subprocess
import sys
import time
from types import SimpleNamespace

import pytest

from backend.drivers import SimulatedRig
from backend.safety import default_limits
from backend.worker import Run, scenario_from_job
from isorig.commands.bench_rig import _without_sys_nice
from sim.isolator import PRESETS
from sim.profiles import SineProfile
from sim.realtime import SHORT_SLICE_S, PeriodTrace
from sim.rig import DEFAULT_RIG

P = 1e-3


def periods(trace, n, t0=0.0, sent0=0.0):
    """``n`` on-time periods from ``t0``: the rig sends at k ms, the loop waits from 0.3 ms before, answers 0.1 ms
    after; the rig's clock is the loop's."""
    for k in range(n):
        t = t0 + k * P
        trace.answered(t - 3e-4, t + 2e-5, t + 1e-4, int((sent0 + k * P) * 1e9), int((sent0 + k * P) * 1e9))
    return t0 + n * P


def test_on_time_periods_make_no_stall():
    trace = PeriodTrace(P)
    periods(trace, 100, t0=10.0, sent0=10.0)
    s = trace.summary()
    assert s["periods"] == 100 and s["stalls"] == 0 and s["stall_max_ms"] == 0.0 and s["rig_clock_shared"]


def test_a_piece_of_work_past_the_period_is_named():
    """The release after period 49 took 6 ms: the next answer is 6 ms late, and the trace says it was the release."""
    trace = PeriodTrace(P)
    t = periods(trace, 50, t0=10.0, sent0=10.0)
    written = t - P + 1e-4
    trace.lap("check", written + 2e-4)
    trace.lap("release", written + 6.2e-3)
    # the loop waits again at +6.2 ms; the rig's measurements of +1..+6 ms queued, the newest is taken at once
    trace.answered(written + 6.2e-3, written + 6.25e-3, written + 6.3e-3, int((t - 1e-4 + P) * 1e9),
                   int((t + 5 * P) * 1e9))
    s = trace.summary()
    assert s["stalls"] == 1 and s["stall_causes"] == {"work:release": 1}
    [stall] = s["longest_stalls"]
    assert stall["stall_ms"] == 5.3 and stall["pieces_ms"] == {"check": 0.2, "release": 6.0}
    assert s["ms"]["release"]["max"] == 6.0


def test_a_late_rig_and_a_loop_that_did_not_run_are_told_apart():
    trace = PeriodTrace(P)
    t = periods(trace, 10, t0=10.0, sent0=10.0)
    # the rig sent its next measurement 4 ms late; the loop was waiting and answered at once
    trace.answered(t - 3e-4, t + 4e-3 + 2e-5, t + 4e-3 + 1e-4, int((t + 4e-3) * 1e9), int((t + 4e-3) * 1e9))
    t = periods(trace, 10, t0=t + 5e-3, sent0=t + 5e-3)
    # on time from the rig, but the loop ran 3 ms after it arrived (the OS, another thread holding the lock)
    trace.answered(t - 3e-4, t + 3e-3, t + 3e-3 + 1e-4, int(t * 1e9), int(t * 1e9))
    assert trace.summary()["stall_causes"] == {"rig": 1, "woke late": 1}


def test_the_longest_stalls_are_kept_in_fixed_memory():
    trace = PeriodTrace(P)
    t = 0.0
    for i in range(100):
        trace.answered(t, t, t)
        t += P * (2 + i % 7)
    s = trace.summary()
    assert s["stalls"] == 99 and len(s["longest_stalls"]) == 20 and s["stall_max_ms"] == 7.0
    assert not s["rig_clock_shared"]


class RealtimeRig(SimulatedRig):
    """The simulated rig as if in real time: one period at a time, each answered (no compiled path)."""

    run_compiled = None

    def describe(self):
        return dataclasses.replace(super().describe(), realtime=True)


def test_the_worker_names_the_work_that_overran_a_period():
    """On a rig in real time, a follow check that takes 100 ms once: the run's period trace keeps the stall it
    made, caused by the check (after the answer of a period, Run.after_answer); the collector never runs while
    the loop does."""
    job = {"test_id": 1, "rig": "simulated", "speed": 1.0,
           "scenario": {"isolator": PRESETS["IUT_a"].to_dict(), "supply_pa": 100e5,
                        "profile": [SineProfile(0.01, 2.0, 2, 1).to_dict()], "controller": "servo"},
           "limits": default_limits(DEFAULT_RIG).to_dict()}

    class Pipe:
        def send(self, _message):
            pass

        def poll(self, *_):
            return False

    run = Run(job, Pipe(), Pipe(), driver=RealtimeRig(scenario_from_job(job).isolator))
    checks = []
    judge = run.judge_following

    def slow_once(block):
        checks.append(len(block))
        if len(checks) == 20:
            time.sleep(0.1)
        return judge(block)

    run.judge_following = slow_once
    collections = []  # the collector's runs while the loop ran: none (sim.realtime.RealtimeSection)

    def collected(phase, info):
        if phase == "start" and run.trace.periods and not run.loop.done:
            collections.append(info["generation"])

    gc.callbacks.append(collected)
    try:
        status, _ = run.execute()
    finally:
        gc.callbacks.remove(collected)
    assert collections == []
    trace = run.pacing()["period_trace"]
    assert status == "completed" and len(checks) > 20
    assert trace["periods"] == run.loop.period
    # the one the check made (on a loaded machine the OS may add a longer one of its own)
    stalls = [r for r in trace["longest_stalls"] if r["pieces_ms"].get("check", 0.0) >= 100.0]
    assert stalls and all(r["cause"] == "work:check" and r["stall_ms"] >= 99.0 for r in stalls)


def _kernel_has_own_slices() -> bool:
    """Linux 6.12+ on x86_64 or aarch64: a fair task may ask for its own time slice (sched_setattr)."""
    release = tuple(int(x) for x in os.uname().release.split(".")[:2] if x.isdigit())
    return os.uname().machine in ("x86_64", "aarch64") and release >= (6, 12)


@pytest.mark.skipif(not _kernel_has_own_slices(), reason="a time slice of one's own needs Linux 6.12+")
def test_a_loop_without_cap_sys_nice_asks_for_a_short_slice_and_gives_it_back():
    """Without CAP_SYS_NICE (a container) neither SCHED_RR nor nice -10 is granted: the loop asks for the kernel's
    shortest time slice, which needs no privilege, so that its measurement preempts a CPU hog at once; a run in
    a process that goes on gives it back (sim.realtime.realtime_priority)."""
    code = ("import os\nfrom sim.realtime import realtime_priority, sched_slice_s\nbefore = sched_slice_s()\n"
            "with realtime_priority(10) as granted:\n    inside = sched_slice_s()\n"
            "print(granted, before, inside, sched_slice_s(), os.sched_getscheduler(0), sep='|')")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True,
                         preexec_fn=_without_sys_nice).stdout.strip()
    granted, before, inside, after, policy = out.split("|")
    assert granted.startswith(("normal", "nice")) and granted.endswith(", slice 0.1 ms")
    assert float(inside) == SHORT_SLICE_S and float(after) == float(before) > SHORT_SLICE_S
    assert int(policy) == os.SCHED_OTHER


@pytest.mark.realtime  # a rig emulator and a CPU hog beside: run alone, after the others (scripts/test.sh)
@pytest.mark.strict_timing
def test_bench_rig_prints_the_longest_stall_its_cause_and_the_periods_lost(capsys):
    """``isorig bench-rig --parts watchdog --host-priority none``: the host runs without CAP_SYS_NICE (its
    priority says so), and each test's longest stall is printed with its cause and the periods lost."""
    from isorig.cli import main

    assert main(["bench-rig", "--parts", "watchdog", "--tests", "1", "--test-s", "4", "--cpu-hogs", "1",
                 "--host-priority", "none"]) == 0
    out = capsys.readouterr().out
    assert re.search(r"^\s+1\s+\w+\s+\d+\s+[\d.]+.*normal, slice 0\.1 ms$", out, re.M) or \
        not _kernel_has_own_slices() and re.search(r"^\s+1\s+\w+.*normal$", out, re.M)
    assert re.search(r"test 1: longest stall [\d.]+ ms: (no stall|[\w: ]+; busy [\d.]+ ms)", out)
    assert re.search(r"longest stall [\d.]+ ms \[target: no period lost\]: \d+ period\(s\) lost by the host, \d+ "
                     r"missed by the rig; host priority none", out)
    # the machine's floor beside it: a loop that does nothing, at the same priority
    floor = re.search(r"\[floor\] a loop that does nothing but wake every 1 ms, at the host's priority \(normal[^)]*\) "
                      r"beside the same hogs, ([\d.]+) s: wake lateness p99 [\d.]+ ms, max [\d.]+ ms; \d+ stall\(s\), "
                      r"longest [\d.]+ ms, \d+ period\(s\) lost; the machine's steal time ([\d.]+|-) ms", out)
    assert floor and 3.9 < float(floor.group(1)) < 6, out


def test_the_bare_loop_counts_a_stall_and_the_periods_it_lost(monkeypatch):
    """sim.realtime.bare_loop, the floor under any loop's period: a wake 10 ms late is one stall of 10 ms that lost
    10 periods, and the other wakes are on time. On a clock the test keeps (a real one, in the parallel tier beside
    other work, lost 67 periods in 0.3 s in a CI run)."""
    import sim.realtime as rt

    clock = {"now": 0.0, "sleeps": 0}

    def sleep(s):
        clock["sleeps"] += 1
        clock["now"] += s + (0.010 if clock["sleeps"] == 50 else 0.0)

    monkeypatch.setattr(rt, "time", SimpleNamespace(perf_counter=lambda: clock["now"], sleep=sleep))
    floor = rt.bare_loop(P, 0.3)
    assert floor["stalls"] == 1 and floor["stall_max_ms"] == pytest.approx(10.0, abs=1e-6), floor
    assert floor["lost_periods"] == 10 and floor["lateness_max_ms"] == pytest.approx(10.0, abs=1e-6), floor
    assert floor["periods"] == 300 - 10 and floor["lateness_p99_ms"] < 0.1, floor
    assert floor["steal_ms"] is None or floor["steal_ms"] >= 0


class FakeCpu:
    """A thread CPU clock the test sets: ``now`` s."""

    def __init__(self):
        self.now = 0.0

    def __call__(self):
        return self.now


def test_a_stall_says_whether_the_loop_computed_or_was_off_its_cpu():
    """Two 5 ms stalls of the answer: in one the loop computed all the while (its CPU clock went on), in the other
    it ran 0.1 ms and was off its CPU the rest (preempted); only the second counts as the OS's."""
    cpu = FakeCpu()
    trace = PeriodTrace(P, cpu_clock=cpu)
    t = 10.0
    for k in range(10):
        cpu.now += 1e-4
        trace.answered(t + k * P - 3e-4, t + k * P + 2e-5, t + k * P + 1e-4, int((t + k * P) * 1e9),
                       int((t + k * P) * 1e9))
    t += 10 * P
    cpu.now += 5.7e-3  # the loop computed all the 6 ms gap but the 0.3 ms it waited for the rig to send
    trace.answered(t - 3e-4, t + 2e-5, t + 5.1e-3, int(t * 1e9), int(t * 1e9))
    t += 6 * P
    cpu.now += 1e-4  # the answer took 5 ms of wall time, 0.1 ms of CPU
    trace.answered(t - 3e-4, t + 2e-5, t + 5.1e-3, int(t * 1e9), int(t * 1e9))
    s = trace.summary()
    assert s["stalls"] == 2 and s["stall_causes"] == {"answer": 2} and s["stalls_off_cpu"] == 1
    computed, preempted = sorted(s["longest_stalls"], key=lambda r: r["period"])
    assert computed["cpu_ms"] == pytest.approx(5.7, abs=1e-3) and computed["off_cpu_ms"] < 1e-3
    assert preempted["cpu_ms"] == pytest.approx(0.1, abs=1e-3)
    # the gap less the CPU less the time it waited for a measurement not sent yet (0.3 ms before it was sent)
    assert preempted["off_cpu_ms"] == pytest.approx(6.0 - 0.1 - 0.3, abs=1e-3)
    assert s["ms"]["cpu"]["max"] == pytest.approx(5.7, abs=0.011)


def test_without_a_cpu_clock_the_stalls_have_no_cpu_figures():
    trace = PeriodTrace(P, cpu_clock=None)
    t = periods(trace, 10, t0=10.0, sent0=10.0)
    trace.answered(t - 3e-4, t + 4e-3, t + 4.1e-3, int(t * 1e9), int(t * 1e9))
    [stall] = trace.summary()["longest_stalls"]
    assert "cpu_ms" not in stall and "cpu" not in trace.summary()["ms"]
