"""The excitation's default bounds, in a module of their own: ``isorig``'s parser shows them in its help, and
importing sim.commission.identify for them (the fit: scipy's signal, optimize and stats) cost every ``isorig``
command about a second of CPU before it started."""

DEFAULT_MAX_STROKE_M = 0.002
DEFAULT_MAX_VELOCITY_M_PER_S = 0.02
