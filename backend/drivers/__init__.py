"""Rig drivers: the seam between the worker's control loop and a rig (simulated or real). See base.py."""

from .base import Measurement, RigDriver
from .simulated import SimulatedRig

DRIVERS = {"simulated": SimulatedRig}


def make_driver(name: str) -> RigDriver:
    if name not in DRIVERS:
        raise ValueError(f"unknown rig driver {name!r}; available: {', '.join(DRIVERS)}")
    return DRIVERS[name]()


__all__ = ["DRIVERS", "Measurement", "RigDriver", "SimulatedRig", "make_driver"]
