"""The service's helper processes end with it, kill -9 included (issue 33, item 4).

Left alone they did not: a check worker (backend.checks) waits on its call queue, whose write end it holds itself,
so it never sees the service go; the forkserver ends only when every process it forked has let go of its "alive"
pipe (each holds one), and the resource tracker only when every holder of its pipe has: kill -9 of the service left
all three behind, re-parented to init, about 440 MB each time.

``exit_with(pid)``, called early in such a process, ends it (``os._exit``) as soon as the process ``pid`` ends: a
daemon thread waits on the process's pidfd (Linux 5.3+; polls every half second on an older kernel). Each check
worker calls it in its initializer, with the service's pid (forkserver or spawn alike). The rig worker needs none:
it notices its closed pipe, stops and ends (tests/backend/test_crash.py). With those gone the rest follows by
itself: the forkserver reads EOF on its "alive" pipe and ends, then the resource tracker reads EOF on its own
(tests/backend/test_nothing_left_behind.py: none left within 5 s; 3 of 4 were before).

Not ``prctl(PR_SET_PDEATHSIG)``: the kernel sends that signal when the *thread* that forked the process ends, and
the forkserver is started from a short-lived thread (``RigService.prepare``), a pool's workers from a request's
thread when the start method is spawn: they would be killed while the service runs. Elsewhere than on Linux,
``exit_with`` does nothing.
"""

from __future__ import annotations

import os
import select
import sys
import threading
import time

POLL_S = 0.5  # a kernel without pidfd_open: how often the watch looks
PR_SET_PDEATHSIG = 1  # linux/prctl.h


def end_with_parent(parent: int, signum: int) -> None:
    """Called first thing in a child forked from a thread that lives as long as its parent (a command's main
    thread; not the service's helpers, above): the kernel sends it ``signum`` when the parent dies
    (``prctl(PR_SET_PDEATHSIG)``, Linux), and it exits at once if ``parent`` is gone already (it died before the
    prctl took effect: the child was handed to another). Elsewhere only the second."""
    if sys.platform.startswith("linux"):
        try:
            import ctypes

            ctypes.CDLL(None, use_errno=True).prctl(PR_SET_PDEATHSIG, int(signum), 0, 0, 0)
        except (OSError, AttributeError):
            pass  # no prctl: the caller's own checks (a closed pipe) still end it
    if os.getppid() != parent:
        os._exit(1)


def exit_with(pid: int) -> bool:
    """End this process when the process ``pid`` ends (at once if it already has); False where not supported."""
    if not sys.platform.startswith("linux") or pid <= 1:
        return False
    fd = None
    try:
        fd = os.pidfd_open(pid)
    except ProcessLookupError:
        os._exit(1)  # gone already: nobody is left to ask this process for anything
    except (OSError, AttributeError):
        pass  # no pidfd (kernel < 5.3): poll
    threading.Thread(target=_watch, args=(pid, fd), daemon=True, name="isorig-exit-with-service").start()
    return True


def _watch(pid: int, fd: int | None) -> None:
    if fd is not None:
        while not select.select([fd], [], [])[0]:  # readable once the process has ended
            pass
    else:
        while _alive(pid):
            time.sleep(POLL_S)
    os._exit(1)


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True
