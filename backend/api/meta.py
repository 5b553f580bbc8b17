"""``/api/health``, ``/api/rig`` and ``/api/rigs``: is the service up, which rig it drives (by name), which
envelope and limits, what runs now; the rigs on record in the shared database."""

from __future__ import annotations

from fastapi import APIRouter, Request

from sim.controllers import DEFAULT_CONTROLLER, describe_controllers
from sim.motion import DEFAULT_SPEED_M_PER_S, HOLD_S, MAX_DURATION_S, MAX_SPEED_M_PER_S, MIN_SPEED_M_PER_S
from sim.profiles import MAX_CYCLES, MAX_FREQUENCY_HZ
from sim.rig import BAR_PA, LITRE_PER_MIN_M3_S

from .. import store
from ..safety import ACTIONS, UNITS, default_limits, hard_limits
from ..settings import MIN_SPEED

router = APIRouter(tags=["rig"])


@router.get("/api/health", summary="Service health")
def health(request: Request) -> dict:
    engine = request.app.state.engine
    service = request.app.state.service
    return {"status": "ok", "schema_version": 1, "database": engine.url.get_backend_name(),
            "rig": service.state()["status"], "rig_name": service.rig_name}


@router.get("/api/rigs", summary="The rigs with tests on record (several services may share the database) and "
            "the one this service drives")
def rigs(request: Request) -> dict:
    """``this``: this service's rig; ``on_record``: every rig name the tests carry (History filters by them)."""
    this = request.app.state.service.rig_name
    with request.app.state.sessions() as session:
        names = store.rig_names(session)
    return {"this": this, "on_record": sorted({*names, this})}


@router.get("/api/rig/link", summary="The link to the rig: live figures during a test, else a probe")
def rig_link(request: Request) -> dict:
    """Simulated rig: always connected. UDP rig: while a test runs, its round trip (p50, p99), measurements
    received and lost, packets rejected, the rig's missed commands and the last sequence; when idle, one
    HELLO to the rig (connected or not, round trip, armed)."""
    return request.app.state.service.link_health()


@router.get("/api/rig/state", summary="The rig now: status, running test, table position, supply pressure, "
            "vertical load, limits in force, last event")
def rig_state(request: Request) -> dict:
    """``status``: running, stopping (a stop, an abort or a limit trip is ending the test), idle,
    not_connected or faulted (a UDP rig that does not answer, or reports a fault). ``table_position_m`` comes
    from ``position_source``: live, the end of the last test, or the rig's answer to a probe."""
    state = request.app.state.service.rig_state()
    with request.app.state.sessions() as session:
        state["last_event"] = store.last_event(session, request.app.state.service.rig_name)  # this rig's
    state["rig_file"] = rig_file_brief(request)
    return store.clean_json(state)


def rig_file_brief(request: Request) -> dict:
    """The rig file in force in a few words (the strip asks every 2 s: every console sees a rig applied from
    another one): name, where it comes from, when it was commissioned, the simulated plant's changes."""
    described = request.app.state.rig_description
    commissioning = described.to_dict()["commissioning"] or {}
    origin = request.app.state.rig_origin
    return {"name": described.name, "source": described.source, "how": origin.get("how"),
            "commissioned": commissioning.get("date"), "applied_at": origin.get("at"),
            "applied_by": origin.get("by"), "commissioning_id": origin.get("commissioning_id"),
            "plant_changes": request.app.state.service.rig_info().get("plant_changes") or {}}


@router.get("/api/rig", summary="Rig parameters, envelope, limits and state")
def rig(request: Request) -> dict:
    rig = request.app.state.rig
    service = request.app.state.service
    return {
        "rig_name": service.rig_name,  # the rig this service drives (--rig-name)
        "driver": service.driver,
        "rig": service.rig_info(),
        "link": service.link_health(),
        "parameters": rig.describe(),
        # name, description, source, what it changes, its commissioning; where it comes from (in_force)
        "rig_file": {**request.app.state.rig_description.to_dict(), "in_force": request.app.state.rig_origin},
        "envelope": {
            "stroke_m": rig.stroke_m,
            "supply_bar_min": rig.min_supply_pa / BAR_PA,
            "supply_bar_max": rig.max_supply_pa / BAR_PA,
            "max_force_n": rig.max_force_n(rig.max_supply_pa),
            "max_pull_force_n": rig.max_pull_force_n(rig.max_supply_pa),
            "vertical_load_n_default": rig.vertical_load_n,
            "max_vertical_load_n": rig.max_vertical_load_n,
            "pump_max_flow_l_per_min": rig.pump_max_flow_m3_per_s / LITRE_PER_MIN_M3_S,
            "command_limit_v": rig.command_limit_v,
            "max_frequency_hz": MAX_FREQUENCY_HZ,
            "max_cycles": MAX_CYCLES,
            "max_test_duration_s": request.app.state.settings.max_test_duration_s,
            "min_speed": MIN_SPEED,
            "max_speed": request.app.state.settings.max_speed,
        },
        "manual_motion": {"min_speed_m_per_s": MIN_SPEED_M_PER_S, "max_speed_m_per_s": MAX_SPEED_M_PER_S,
                          "default_speed_m_per_s": DEFAULT_SPEED_M_PER_S, "hold_s": HOLD_S,
                          "max_duration_s": MAX_DURATION_S},
        "limits_default": default_limits(rig).to_dict(),
        "limits_max": hard_limits(rig).to_dict(),
        "limit_actions": ACTIONS,
        "limit_units": UNITS,
        "controllers": describe_controllers(),
        "default_controller": DEFAULT_CONTROLLER,
        "state": service.state(),
    }
