"""``GET /api/protocols``: the shipped test protocols, for the console's choice and its confirmation."""

from __future__ import annotations

import math

from fastapi import APIRouter

from sim.protocols import SHIPPED_PROTOCOLS, load_protocol

router = APIRouter(tags=["protocols"])


def describe_protocol(name: str) -> dict:
    """A shipped protocol as data (the file format, sim.protocols) with what it asks of the rig: each level's
    amplitude in m, the peak displacement and velocity, the cycles and the duration."""
    protocol = load_protocol(name)
    blocks = protocol.blocks
    out = protocol.to_dict()
    out["levels"] = [{**level, "amplitude_m": b.amplitude_m, "duration_s": b.duration_s,
                      "peak_velocity_m_per_s": 2 * math.pi * b.frequency_hz * b.amplitude_m}
                     for level, b in zip(out["levels"], blocks, strict=True)]
    out["peak_displacement_m"] = max(b.reach_m for b in blocks)
    out["peak_velocity_m_per_s"] = max(level["peak_velocity_m_per_s"] for level in out["levels"])
    out["cycles_total"] = sum(b.cycles for b in blocks)
    out["duration_s"] = protocol.duration_s
    return out


@router.get("/api/protocols", summary="The shipped test protocols: levels, acceptance rules, peak motion, duration")
def list_protocols() -> list[dict]:
    return [describe_protocol(name) for name in SHIPPED_PROTOCOLS]
