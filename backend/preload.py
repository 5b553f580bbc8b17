"""Imported once by the worker's forkserver: loads the worker code and the engine's compiled kernels, so
every worker forked from it starts without import or compile time (a test starts within ~0.1 s)."""

from sim.engine import warm_up

from . import worker  # noqa: F401

warm_up()
