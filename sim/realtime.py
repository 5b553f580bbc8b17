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
