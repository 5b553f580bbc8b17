"""``POST /api/rig/move`` and ``/api/rig/zero``: manual motion of the table when no test runs.

A move is recorded as a run of its own (profile kind ``move``): the same worker, loop, limits and stop paths
as a test, the valve closed at its end, the reason recorded. It starts where the table rests (the rig's own
reading for a UDP rig; the worker plans it again from the reading at arming) and follows a minimum-jerk target at
the asked peak speed (sim.motion); a stop holds the table where it is, and the move's guard (sim.motion.MoveGuard)
closes the valve on a table that runs away from it.
"""

from __future__ import annotations

from fastapi import APIRouter, Request

from sim.engine import Scenario
from sim.motion import check_move, move_target
from sim.rig import BAR_PA

from .. import store
from ..errors import ApiError
from ..safety import make_limits
from ..schemas import ERROR_RESPONSES, MoveIn, TestOut
from ..store import clean_json
from .deps import OperatorDep, SessionDep, acting_name
from .isolators import resolve_isolator

router = APIRouter(tags=["rig"])


def build_move(session, body: MoveIn, request: Request) -> dict:
    """The record of a manual move from where the table rests to ``body.position_m``; refusals name the field."""
    service = request.app.state.service
    running = service.running_test_id()
    if running is not None:
        raise ApiError(409, f"test {running} is running; the table moves by hand only when no test runs")
    start_m = service.resting_position_m()
    if start_m is None and service.driver != "simulated":
        raise ApiError(409, f"the rig at {service.driver} does not answer: its table position is unknown, so "
                            "nothing can move")
    start_m = start_m or 0.0
    rig = request.app.state.rig
    check_move(start_m, body.position_m, body.speed_m_per_s, rig.stroke_m)  # MotionError -> 422
    limits = make_limits(rig, body.limits.model_dump() if body.limits else None)
    if abs(body.position_m) > limits.displacement_m:
        raise ApiError(422, f"position_m = {body.position_m:g} m is beyond the displacement limit of "
                            f"{limits.displacement_m:g} m", "position_m", body.position_m,
                       f"within +-{limits.displacement_m:g} m")
    isolator = resolve_isolator(session, body.isolator)
    target = move_target(start_m, body.position_m, body.speed_m_per_s)
    scenario = Scenario(isolator, body.supply_bar * BAR_PA, [], "servo", {}, rig=rig,
                        vertical_load_n=body.vertical_load_n, history=target)
    scenario.validate()  # supply pressure, vertical load, the move within the envelope
    motion = {"start_m": start_m, "end_m": body.position_m, "speed_m_per_s": body.speed_m_per_s}
    job_scenario = {"isolator": isolator.to_dict(), "supply_pa": scenario.supply_pa,
                    "vertical_load_n": scenario.effective_vertical_load_n, "profile": [], "controller": "servo",
                    "controller_options": {}, "motion": motion,
                    "rig_changes": scenario.describe()["rig_changes"]}
    label = (f"manual move {start_m * 1e3:.2f} mm -> {body.position_m * 1e3:.2f} mm at "
             f"{body.speed_m_per_s * 1e3:g} mm/s")
    return {
        "label": label, "specimen_id": "", "operator_name": body.operator_name.strip(), "notes": "",
        "isolator": isolator.name, "supply_bar": body.supply_bar, "vertical_load_n": scenario.effective_vertical_load_n,
        "controller": "servo", "speed": 1.0, "driver": service.driver,
        "request": {**body.model_dump(mode="json"), "profile": {"kind": "move", **motion},
                    "job_scenario": job_scenario, "rig_name": request.app.state.rig_description.name,
                    "rig_file": clean_json(request.app.state.rig_description.to_dict())},
        "scenario": clean_json(scenario.describe()), "limits": limits.to_dict(),
        "duration_s": scenario.duration_s, "cycles_total": 0,
    }


def start_move(session, body: MoveIn, request: Request, actor: str) -> dict:
    fields = build_move(session, body, request)
    test = store.create_test(session, rig_name=request.app.state.service.rig_name, **fields)
    store.add_event(session, test.id, "operator", f"{fields['label']} requested by {actor}",
                    {"action": "move", **fields["request"]["profile"]}, actor=actor)
    session.commit()
    test_id = test.id
    try:
        request.app.state.service.start(test_id, actor)
    except BaseException:  # refused: leave no record of a move that never ran
        session.rollback()
        stale = store.get_test(session, test_id)
        if stale is not None and stale.status == "ready":
            store.delete_test(session, stale)
            session.commit()
        raise
    session.expire_all()
    return store.test_record(session, store.get_test(session, test_id))


@router.post("/api/rig/move", status_code=201, summary="Move the table to a position at a safe speed (role "
             "operator; only when no test runs)", responses=ERROR_RESPONSES)
def move(body: MoveIn, request: Request, session: SessionDep, actor: OperatorDep) -> TestOut:
    """Starts at once; the run is a record of its own (profile kind ``move``) with the same limits, stop and
    abort as a test: stop holds the table where it is. 409 while a test runs or when the rig does not answer."""
    body = body.model_copy(update={"operator_name": acting_name(actor, body.operator_name, "operator_name")})
    return start_move(session, body, request, actor)


@router.post("/api/rig/zero", status_code=201, summary="Return the table to zero at a safe speed (role operator)",
             responses=ERROR_RESPONSES)
def zero(body: MoveIn, request: Request, session: SessionDep, actor: OperatorDep) -> TestOut:
    """As ``/api/rig/move`` with ``position_m`` = 0."""
    name = acting_name(actor, body.operator_name, "operator_name")
    return start_move(session, body.model_copy(update={"position_m": 0.0, "operator_name": name}), request, actor)
