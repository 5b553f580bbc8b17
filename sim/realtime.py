"""Scheduling for the loops that run against a wall clock: the worker's control loop and the rig emulator."""

from __future__ import annotations

import os
from contextlib import contextmanager


def raise_priority(rr_priority: int) -> str:
    """Ask the OS to schedule this process ahead of ordinary ones, as far as it allows: round-robin real-time
    priority ``rr_priority`` if permitted (root or CAP_SYS_NICE), else nice -10, else nothing. Returns what
    was granted. The loops sleep between periods or chunks, so a real-time priority cannot starve the machine."""
    try:
        os.sched_setscheduler(0, os.SCHED_RR, os.sched_param(rr_priority))
        return f"SCHED_RR {rr_priority}"
    except (AttributeError, OSError):
        pass
    try:
        os.nice(-10)
        return "nice -10"
    except OSError:
        return "normal"


def current_priority() -> tuple:
    """This process's scheduling (policy, its parameter, nice), to give back with ``restore_priority``."""
    return os.sched_getscheduler(0), os.sched_getparam(0), os.getpriority(os.PRIO_PROCESS, 0)


def restore_priority(saved: tuple) -> None:
    """Give back the scheduling ``current_priority`` saved (always permitted: it lowers, never raises). A
    process that runs a real-time loop and then goes on (a test suite, a script) must not leave it raised:
    every process it starts afterwards (a browser, a service) would inherit SCHED_RR and starve real loops."""
    policy, param, nice = saved
    try:
        os.sched_setscheduler(0, policy, param)
        os.setpriority(os.PRIO_PROCESS, 0, nice)
    except (AttributeError, OSError):
        pass


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
