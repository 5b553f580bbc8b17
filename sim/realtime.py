"""Scheduling for the loops that run against a wall clock: the worker's control loop and the rig emulator."""

from __future__ import annotations

import os
import time
from contextlib import contextmanager

from .latency import LatencyHistogram


def raise_priority(rr_priority: int) -> str:
    """Ask the OS to schedule this thread (and the threads it starts) ahead of ordinary ones, as far as it allows:
    round-robin real-time priority ``rr_priority`` if permitted (root or CAP_SYS_NICE), else nice -10 where
    permitted, and then in any case a short time slice (``short_slice``: needs no privilege). Returns what was
    granted. The loops sleep between periods or chunks, so a real-time priority cannot starve the machine."""
    try:
        os.sched_setscheduler(0, os.SCHED_RR, os.sched_param(rr_priority))
        return f"SCHED_RR {rr_priority}"
    except (AttributeError, OSError):
        pass
    try:
        os.nice(-10)
        granted = "nice -10"
    except OSError:
        granted = "normal"
    slice_ = short_slice()
    return f"{granted}, {slice_}" if slice_ else granted


#: the time slice a loop without real-time priority asks for (the kernel's least): EEVDF (Linux 6.6+; a slice of
#: one's own since 6.12) gives a task that asks for a shorter slice an earlier deadline, so that when its
#: measurement arrives it preempts a CPU-bound process of the same nice at once instead of waiting for that
#: one's slice (~3 ms) to end. Measured beside two CPU hogs without CAP_SYS_NICE (a 1 ms sleep-and-work loop,
#: load 16-19): wakes later than 1 ms 2 100-2 277 times in 15 s with the default slice, 507-1 057 with 0.1 ms.
SHORT_SLICE_S = 1e-4
SYS_SCHED_SETATTR, SYS_SCHED_GETATTR = {"x86_64": (314, 315), "aarch64": (274, 275)}.get(os.uname().machine,
                                                                                       (None, None))
_SCHED_ATTR = "IIQiIQQQII"  # struct sched_attr, SCHED_ATTR_SIZE_VER1 (56 bytes)


def sched_slice_s() -> float | None:
    """This thread's time slice in s as the kernel reports it (``sched_getattr``'s runtime for a fair task, Linux
    6.12+; 0 on older kernels), or None where it cannot say (another machine)."""
    import ctypes
    import struct

    if SYS_SCHED_GETATTR is None:
        return None
    try:
        buf = ctypes.create_string_buffer(struct.calcsize(_SCHED_ATTR))
        if _libc().syscall(SYS_SCHED_GETATTR, 0, buf, len(buf), 0) != 0:
            return None
    except (OSError, AttributeError):
        return None
    return struct.unpack(_SCHED_ATTR, buf.raw)[5] * 1e-9


def _set_slice(slice_s: float) -> bool:
    """``sched_setattr``: SCHED_OTHER at this thread's nice with a time slice of ``slice_s`` (0: the kernel's
    default); True if the call succeeded."""
    import ctypes
    import struct

    if SYS_SCHED_SETATTR is None:
        return False
    attr = struct.pack(_SCHED_ATTR, struct.calcsize(_SCHED_ATTR), os.SCHED_OTHER, 0,
                       os.getpriority(os.PRIO_PROCESS, 0), 0, int(round(slice_s * 1e9)), 0, 0, 0, 0)
    try:
        return _libc().syscall(SYS_SCHED_SETATTR, 0, ctypes.create_string_buffer(attr, len(attr)), 0) == 0
    except (OSError, AttributeError):
        return False


def short_slice(slice_s: float = SHORT_SLICE_S) -> str | None:
    """Ask for a time slice of ``slice_s`` for this thread, keeping its policy (SCHED_OTHER) and nice: no
    privilege is needed. What was granted ("slice 0.1 ms"), or None where the kernel has no slice of one's own
    (it reports back another one)."""
    if os.sched_getscheduler(0) != os.SCHED_OTHER or not _set_slice(slice_s):
        return None
    got = sched_slice_s()
    if got is None or abs(got - slice_s) > 1e-6:
        return None
    return f"slice {got * 1e3:g} ms"


def current_priority() -> tuple:
    """This thread's scheduling (policy, its parameter, nice, time slice), to give back with
    ``restore_priority``."""
    return os.sched_getscheduler(0), os.sched_getparam(0), os.getpriority(os.PRIO_PROCESS, 0), sched_slice_s()


def restore_priority(saved: tuple) -> None:
    """Give back the scheduling ``current_priority`` saved (always permitted: it lowers, never raises). A
    process that runs a real-time loop and then goes on (a test suite, a script) must not leave it raised:
    every process it starts afterwards (a browser, a service) would inherit SCHED_RR and starve real loops, or
    a short time slice (``short_slice``), which setting the policy alone does not give back."""
    policy, param, nice, slice_s = saved
    try:
        os.sched_setscheduler(0, policy, param)
        os.setpriority(os.PRIO_PROCESS, 0, nice)
    except (AttributeError, OSError):
        pass
    if policy == os.SCHED_OTHER and slice_s is not None and sched_slice_s() != slice_s:
        # the kernel's default slice where the saved one was not short (it reads back as the default's value)
        _set_slice(slice_s if slice_s <= SHORT_SLICE_S else 0.0)


@contextmanager
def realtime_priority(rr_priority: int):
    """This process at ``raise_priority(rr_priority)`` for the ``with`` block (yields what was granted), its
    scheduling given back afterwards (``restore_priority``): a check or run that measures against a rig's clock
    must not be starved by ordinary processes, and its caller must not go on at real-time priority."""
    saved = current_priority()
    try:
        yield raise_priority(rr_priority)
    finally:
        restore_priority(saved)


MCL_CURRENT = 1  # <sys/mman.h>


def _libc():
    import ctypes
    import ctypes.util

    return ctypes.CDLL(ctypes.util.find_library("c") or None, use_errno=True)


def lock_memory() -> str:
    """Lock the pages this process has mapped now in RAM where permitted (``mlockall(MCL_CURRENT)``), so that
    the control period never waits for a page to come back from swap. Pages mapped later are not locked:
    with MCL_FUTURE every later allocation would be faulted in and locked at once, inside the loop, and a
    lock limit could make it fail. Returns what was granted: "current pages" or "not locked (why)"."""
    import ctypes
    import resource

    try:
        libc = _libc()
    except OSError as exc:
        return f"not locked (no C library: {exc})"
    if libc.mlockall(MCL_CURRENT) == 0:
        return "current pages"
    soft, _hard = resource.getrlimit(resource.RLIMIT_MEMLOCK)
    return f"not locked ({os.strerror(ctypes.get_errno())}; RLIMIT_MEMLOCK {soft} bytes)"


def unlock_memory() -> None:
    try:
        _libc().munlockall()
    except OSError:
        pass


class RealtimeSection:
    """The part of a run that answers a real-time rig: no garbage collector pause inside it and, where
    permitted, its memory locked.

    On entry the objects that exist are frozen (never scanned again) and the collector is off for the whole
    run: the loop's objects are freed by their reference counts, and what reference cycles leave (few: the
    loop makes none by design) waits for the end of the run. (A young-generation collection every ten periods,
    tried first, cost the service's worker up to 15 % of its periods on a loaded machine, though it takes
    microseconds on its own.) On exit the collector is on again and the memory unlocked (the frozen objects
    stay frozen). ``granted`` says what the OS allowed, for the record."""

    def __init__(self, lock: bool = True):
        self.lock = lock
        self.granted = "not entered"
        self._was_enabled = True

    def __enter__(self) -> RealtimeSection:
        import gc

        self._was_enabled = gc.isenabled()
        gc.freeze()
        gc.disable()
        memory = lock_memory() if self.lock else "not locked (not asked)"
        self.granted = f"collector off during the run; memory: {memory}"
        return self

    def __exit__(self, *_exc) -> None:
        import gc

        if self.lock:
            unlock_memory()
        if self._was_enabled:
            gc.enable()


#: a stall: the loop's answer came this many periods after the previous one, or later (one period late: a period
#: the rig missed)
STALL_PERIODS = 1.5
MAX_STALLS_KEPT = 20  # the longest stalls are kept with what ran before each


class PeriodTrace:
    """Where the periods of a real-time loop went, in fixed memory (histograms, the longest stalls).

    Per period: how long the loop waited for the rig's measurement (``wait``), took to answer it (``answer``:
    read, step, write), and its own work after the answer until it waited again (``busy``), split into named
    pieces by ``lap(kind)``. With the rig's send time on this machine's monotonic clock (a rig on loopback,
    e.g. the emulator), also the measurement's age at the answer. An answer more than ``STALL_PERIODS`` after
    the previous one is a stall, kept (the longest ``MAX_STALLS_KEPT``) with its cause, the largest share of
    the gap: ``work:<kind>`` (the loop's own work since the last answer, by its largest piece), ``rig`` (the rig
    sent late), ``woke late`` (the measurement was there and the loop waiting, but it did not run: the OS, another
    thread holding the interpreter's lock), ``answer`` (reading, stepping and writing took that long).

    ``cpu_clock`` (default ``time.thread_time``, read once a period, ~2 us): the loop thread's own CPU time, so that
    each stall also says whether the loop was computing (``cpu_ms``) or off its CPU while it could have run
    (``off_cpu_ms``: preempted by the OS, or blocked on something other than the rig's measurement; the gap less
    its CPU time and less the time it waited for a measurement the rig had not sent yet); the period's CPU time is
    the ``cpu`` kind. None: no CPU figures."""

    def __init__(self, period_s: float, cpu_clock=time.thread_time):
        self.period_s = period_s
        self.cpu_clock = cpu_clock
        self.cpu_s: float | None = None  # the loop thread's CPU time at the last answer
        self.off_cpu_stalls = 0  # stalls in which the loop was off its CPU longer than it computed
        self.ms: dict[str, LatencyHistogram] = {}
        self.pieces: dict[str, float] = {}  # kind -> ms since the last answer
        self.periods = 0
        self.written: float | None = None  # perf_counter of the last answer
        self.mark = 0.0  # the end of the last lap
        self.sent_s: float | None = None  # the rig's send time of the last answered measurement
        self.same_clock: bool | None = None
        self.stalls: list[dict] = []
        self.stall_count = 0
        self.causes: dict[str, int] = {}

    def _add(self, kind: str, ms: float) -> None:
        h = self.ms.get(kind)
        if h is None:
            h = self.ms[kind] = LatencyHistogram()
        h.add(ms)

    def lap(self, kind: str, now: float | None = None) -> None:
        """The loop's work since the last lap (or answer) was ``kind`` (``now``: time.perf_counter())."""
        if self.written is None:  # before the first answer: start-up, not a period's work
            return
        now = time.perf_counter() if now is None else now
        ms = (now - self.mark) * 1e3
        self.mark = now
        self.pieces[kind] = self.pieces.get(kind, 0.0) + ms
        self._add(kind, ms)

    def answered(self, wait_from: float, got: float, written: float, first_sent_ns: int | None = None,
                 sent_ns: int | None = None) -> None:
        """One period: the loop waited from ``wait_from``, had the measurement at ``got`` and wrote its answer at
        ``written`` (time.perf_counter); ``first_sent_ns``/``sent_ns``: the rig's send time of the first and of the
        newest measurement this wait took (time.perf_counter_ns on loopback), where known."""
        self.periods += 1
        cpu_s = self.cpu_clock() if self.cpu_clock is not None else None
        self._add("wait", (got - wait_from) * 1e3)
        self._add("answer", (written - got) * 1e3)
        if self.same_clock is None and sent_ns is not None:  # a rig on this machine: its clock is ours
            self.same_clock = 0 <= got - sent_ns * 1e-9 < 1.0
        first_s = sent_s = None
        if self.same_clock and sent_ns is not None:
            sent_s = sent_ns * 1e-9
            first_s = first_sent_ns * 1e-9 if first_sent_ns is not None else sent_s
            self._add("age", (written - sent_s) * 1e3)
        if self.written is not None:
            if wait_from > self.mark:
                self.pieces["other"] = self.pieces.get("other", 0.0) + (wait_from - self.mark) * 1e3
            busy_s = wait_from - self.written
            self._add("busy", busy_s * 1e3)
            gap_s = written - self.written
            cpu_gap_s = None
            if cpu_s is not None and self.cpu_s is not None:
                cpu_gap_s = cpu_s - self.cpu_s
                self._add("cpu", cpu_gap_s * 1e3)
            if gap_s > STALL_PERIODS * self.period_s:
                self._stall(gap_s, busy_s, wait_from, got, written, first_s, cpu_gap_s)
        self.pieces = {}
        self.written = self.mark = written
        self.sent_s = sent_s
        self.cpu_s = cpu_s

    def _stall(self, gap_s, busy_s, wait_from, got, written, first_s, cpu_gap_s=None) -> None:
        # the cause: the largest of the loop's own work, the rig's own lateness, the wait for the loop to run
        # once the measurement was there, and the answer itself
        work = max(self.pieces, key=self.pieces.get) if self.pieces else "other"
        shares = {f"work:{work}": busy_s, "answer": written - got}
        if first_s is not None:
            shares["woke late"] = got - max(first_s, wait_from)
            if self.sent_s is not None:
                shares["rig"] = first_s - self.sent_s - self.period_s
        cause = max(shares, key=shares.get)
        self.stall_count += 1
        self.causes[cause] = self.causes.get(cause, 0) + 1
        record = {"period": self.periods, "at_s": round(written, 6),  # the monotonic clock: to set beside the rig's
                  "stall_ms": round((gap_s - self.period_s) * 1e3, 3), "cause": cause,
                  "busy_ms": round(busy_s * 1e3, 3), "wait_ms": round((got - wait_from) * 1e3, 3),
                  "answer_ms": round((written - got) * 1e3, 3),
                  "pieces_ms": {k: round(v, 3) for k, v in self.pieces.items()}}
        if first_s is not None:
            record["woke_after_ms"] = round((got - first_s) * 1e3, 3)
            if self.sent_s is not None:
                record["rig_gap_ms"] = round((first_s - self.sent_s) * 1e3, 3)
        if cpu_gap_s is not None:
            # waiting for a measurement not sent yet is neither: the rig's time (all the wait, on another clock)
            blocked_s = (min(max(first_s - wait_from, 0.0), got - wait_from) if first_s is not None
                         else got - wait_from)
            off_s = max(0.0, gap_s - cpu_gap_s - blocked_s)
            record["cpu_ms"] = round(cpu_gap_s * 1e3, 3)
            record["off_cpu_ms"] = round(off_s * 1e3, 3)
            if off_s > cpu_gap_s:
                self.off_cpu_stalls += 1
        self.stalls.append(record)
        if len(self.stalls) > MAX_STALLS_KEPT:
            self.stalls.remove(min(self.stalls, key=lambda r: r["stall_ms"]))

    def summary(self) -> dict:
        """The figures, for a run's record: periods, stalls (count, longest, by cause, the longest kept with
        what ran before each) and each kind's p99 and max in ms."""
        longest = sorted(self.stalls, key=lambda r: -r["stall_ms"])
        return {"periods": self.periods, "stalls": self.stall_count, "stalls_off_cpu": self.off_cpu_stalls,
                "stall_max_ms": longest[0]["stall_ms"] if longest else 0.0, "stall_causes": dict(self.causes),
                "rig_clock_shared": bool(self.same_clock), "longest_stalls": longest,
                "ms": {k: {"n": h.n, "mean": round(h.mean_ms, 4), "p99": round(h.percentile_ms(99), 3),
                           "max": round(h.max_ms, 3)}
                       for k, h in self.ms.items()}}


def steal_s() -> float | None:
    """The machine's steal time so far in s, all CPUs (``/proc/stat``): how long a hypervisor ran something else
    while this virtual machine's CPUs had work; None where the system does not say."""
    try:
        with open("/proc/stat") as f:
            fields = f.readline().split()
        return int(fields[8]) / os.sysconf("SC_CLK_TCK")
    except (OSError, IndexError, ValueError):
        return None


def steal_ms_since(start_s: float | None) -> float | None:
    """The machine's steal time since ``steal_s()`` gave ``start_s``, in ms (None where either is unknown)."""
    end_s = steal_s()
    return None if start_s is None or end_s is None else round((end_s - start_s) * 1e3, 1)


def bare_loop(period_s: float, duration_s: float) -> dict:
    """A loop that does nothing but sleep until each period is due, as the control loop waits for its measurement:
    how late the OS woke it (p99 and max, ms), its stalls (a wake more than ``STALL_PERIODS`` after the one
    before) and the periods they lost, and the machine's steal time over the run. At the control loop's priority,
    beside the same load, it is the floor under any loop's period on this machine: what no change to the loop's
    own work can remove."""
    lateness = LatencyHistogram()
    steal_start = steal_s()
    start = last = time.perf_counter()
    due, stalls, lost, longest = start, 0, 0, 0.0
    while last - start < duration_s:
        due += period_s
        now = time.perf_counter()
        if due > now:
            time.sleep(due - now)
        now = time.perf_counter()
        lateness.add(max(0.0, now - due) * 1e3)
        gap = now - last
        if gap > STALL_PERIODS * period_s:
            stalls += 1
            lost += int(round(gap / period_s)) - 1
            longest = max(longest, (gap - period_s) * 1e3)
            due = now  # like the rig after an overrun: no catching up
        last = now
    steal = steal_ms_since(steal_start)
    return {"seconds": round(last - start, 3), "periods": lateness.n,
            "lateness_p99_ms": round(lateness.percentile_ms(99), 3), "lateness_max_ms": round(lateness.max_ms, 3),
            "stalls": stalls, "lost_periods": lost, "stall_max_ms": round(longest, 3), "steal_ms": steal}
