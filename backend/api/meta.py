"""``/api/health`` and ``/api/rig``: is the service up, what rig, which envelope and limits, what runs now."""

from __future__ import annotations

from fastapi import APIRouter, Request

from sim.controllers import DEFAULT_CONTROLLER, describe_controllers
from sim.profiles import MAX_CYCLES, MAX_FREQUENCY_HZ
from sim.rig import BAR_PA, DEFAULT_RIG, LITRE_PER_MIN_M3_S

from ..safety import default_limits, hard_limits

router = APIRouter(tags=["rig"])


@router.get("/api/health", summary="Service health")
def health(request: Request) -> dict:
    engine = request.app.state.engine
    return {"status": "ok", "schema_version": 1, "database": engine.url.get_backend_name(),
            "rig": request.app.state.service.state()["status"]}


@router.get("/api/rig/link", summary="The link to the rig: live figures during a test, else a probe")
def rig_link(request: Request) -> dict:
    """Simulated rig: always connected. UDP rig: while a test runs, its round trip (p50, p99), measurements
    received and lost, packets rejected, the rig's missed commands and the last sequence; when idle, one
    HELLO to the rig (connected or not, round trip, armed)."""
    return request.app.state.service.link_health()


@router.get("/api/rig", summary="Rig parameters, envelope, limits and state")
def rig(request: Request) -> dict:
    rig = DEFAULT_RIG
    service = request.app.state.service
    return {
        "driver": service.driver,
        "rig": service.rig_info(),
        "link": service.link_health(),
        "parameters": rig.describe(),
        "envelope": {
            "stroke_m": rig.stroke_m,
            "supply_bar_min": rig.min_supply_pa / BAR_PA,
            "supply_bar_max": rig.max_supply_pa / BAR_PA,
            "max_force_n": rig.max_force_n(rig.max_supply_pa),
            "vertical_load_n_default": rig.vertical_load_n,
            "max_vertical_load_n": rig.max_vertical_load_n,
            "pump_max_flow_l_per_min": rig.pump_max_flow_m3_per_s / LITRE_PER_MIN_M3_S,
            "command_limit_v": rig.command_limit_v,
            "max_frequency_hz": MAX_FREQUENCY_HZ,
            "max_cycles": MAX_CYCLES,
            "max_test_duration_s": request.app.state.settings.max_test_duration_s,
            "max_speed": request.app.state.settings.max_speed,
        },
        "limits_default": default_limits(rig).to_dict(),
        "limits_max": hard_limits(rig).to_dict(),
        "controllers": describe_controllers(),
        "default_controller": DEFAULT_CONTROLLER,
        "state": service.state(),
    }
