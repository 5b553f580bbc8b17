"""isorig simulation core: rig, isolator and controllers of the paper, a fast engine. No web imports."""

from ._numba_cache import configure as _configure_numba_cache

_configure_numba_cache()
