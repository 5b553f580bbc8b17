"""Scheduling for the loops that run against a wall clock: the worker's control loop and the rig emulator."""

from __future__ import annotations

import os


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


MCL_CURRENT, MCL_FUTURE = 1, 2  # <sys/mman.h>


def _libc():
    import ctypes
    import ctypes.util

    return ctypes.CDLL(ctypes.util.find_library("c") or None, use_errno=True)


def lock_memory() -> str:
    """Lock this process's pages in RAM where permitted (``mlockall``), so that no page fault in the control
    period waits for the disk. Future pages too only when no lock limit can make a later allocation fail
    (CAP_IPC_LOCK, i.e. root, or an unlimited RLIMIT_MEMLOCK); else only the pages mapped now, if they fit the
    limit. Returns what was granted: "current and future pages", "current pages" or "not locked (why)"."""
    import resource

    soft, _hard = resource.getrlimit(resource.RLIMIT_MEMLOCK)
    future = os.geteuid() == 0 or soft == resource.RLIM_INFINITY
    try:
        libc = _libc()
    except OSError as exc:
        return f"not locked (no C library: {exc})"
    if libc.mlockall(MCL_CURRENT | (MCL_FUTURE if future else 0)) == 0:
        return "current and future pages" if future else "current pages"
    import ctypes

    return f"not locked ({os.strerror(ctypes.get_errno())}; RLIMIT_MEMLOCK {soft} bytes)"


def unlock_memory() -> None:
    try:
        _libc().munlockall()
    except OSError:
        pass


class RealtimeSection:
    """The part of a run that answers a real-time rig: no garbage collector pause inside it and, where
    permitted, its memory locked.

    On entry the objects that exist are frozen (never scanned again) and the automatic collector is off;
    ``slack()`` runs a young-generation collection where the loop has time to spare (right after a command is
    sent, the rig's next period still under way), so garbage cycles cannot pile up over a long test. On exit
    the collector is on again and the memory unlocked (the frozen objects stay frozen). ``granted`` says what
    the OS allowed, for the record."""

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
        self.granted = f"collector off in the period; memory: {memory}"
        return self

    @staticmethod
    def slack() -> None:
        import gc

        gc.collect(0)

    def __exit__(self, *_exc) -> None:
        import gc

        if self.lock:
            unlock_memory()
        if self._was_enabled:
            gc.enable()
