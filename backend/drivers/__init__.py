"""Rig drivers: the seam between the worker's loop and a rig (simulated or real). See base.py.

A rig is named by a URL-like string: ``simulated`` (the default) or ``udp://HOST:PORT`` (a real-time I/O
target or ``isorig rig-emulator`` speaking docs/rig-protocol.md).
"""

from __future__ import annotations

from .base import ArmConditions, Channel, CommandRefused, RigDescription, RigDriver, RigFault, check_command
from .simulated import SimulatedRig

SIMULATED = "simulated"


def rig_kind(rig: str) -> str:
    """``simulated`` or ``udp``; a clear error for anything else."""
    if rig == SIMULATED:
        return SIMULATED
    if rig.startswith("udp://"):
        from .udp import parse_udp_url

        parse_udp_url(rig)
        return "udp"
    raise ValueError(f"unknown rig {rig!r}; allowed: 'simulated' or 'udp://HOST:PORT'")


__all__ = ["SIMULATED", "ArmConditions", "Channel", "CommandRefused", "RigDescription", "RigDriver", "RigFault",
           "SimulatedRig", "check_command", "rig_kind"]
