"""isorig simulation core: rig, isolator and controllers of the paper, a fast engine. No web imports."""
