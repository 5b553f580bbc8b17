"""Imported once by the worker's forkserver: loads the worker code and the engine's compiled kernels, so
every worker forked from it starts without import or compile time (a test starts within ~0.1 s).

Ctrl-C in the service's terminal reaches its whole process group, the forkserver too: the forkserver and every
process forked from it (the rig worker, the check pool's workers) ignore SIGINT, the service stops them. The
forkserver is started with SIGINT blocked (RigService.prepare), so a Ctrl-C during these imports waits here and
is dropped, not a KeyboardInterrupt traceback in the service's terminal (issue 34)."""

import signal

signal.signal(signal.SIGINT, signal.SIG_IGN)
signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT})

from sim.engine import warm_up  # noqa: E402

from . import worker  # noqa: E402, F401

warm_up()
