"""Commissioning the rig through the service (backend.commissioning): start the run, read the result, download
the rig file, make it the service's rig (backend.rig_in_force)."""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Body, Request
from fastapi.responses import JSONResponse

from sim.errors import FieldError

from .. import commissioning, rig_in_force, store
from ..errors import ApiError, _jsonable
from ..schemas import ERROR_RESPONSES, ApplyRigIn, CommissioningIn, TestOut
from .deps import OperatorDep, SessionDep, TestId, acting_name, not_found

router = APIRouter(tags=["commissioning"])


def _commissioning_or_404(session, test_id: int):
    test = store.get_test(session, test_id)
    if test is None or not commissioning.is_commissioning(test):
        raise not_found(f"commissioning {test_id}" + (" (it is a test, not a commissioning)" if test else ""))
    return test


@router.post("/api/commissioning", status_code=201, summary="Commission the rig: a bounded excitation about "
             "where the table rests, then a fit of the rig's parameters (role operator)", responses=ERROR_RESPONSES)
def start(body: CommissioningIn, request: Request, session: SessionDep, actor: OperatorDep) -> TestOut:
    """Starts at once; recorded as a run of its own (profile kind ``commissioning``), streamed, stoppable and
    abortable like a test. 409 while a test runs or when a UDP rig does not answer; 422 names a bound outside
    what commissioning takes. Once the run ends, ``GET /api/commissioning/{id}`` says ``fitting``, then the
    result."""
    body = body.model_copy(update={"operator_name": acting_name(actor, body.operator_name, "operator_name")})
    return commissioning.start(session, body, request, actor)


@router.post("/api/commissioning/check", summary="What a commissioning would do, without starting it (no login)",
             responses=ERROR_RESPONSES)
def check(body: CommissioningIn, request: Request, session: SessionDep) -> dict:
    """Always 200: ``ok``, and either what would move (``start_m``, ``duration_s``, ``limits``,
    ``vertical_load_n``, ``what``) or the refusal (``detail``, ``field``, ``value``, ``limit``) that
    ``POST /api/commissioning`` would answer with now. Nothing is created."""
    try:
        fields = commissioning.build(session, body, request)
    except FieldError as exc:
        return {"ok": False, "detail": str(exc), "field": exc.field, "value": _jsonable(exc.value),
                "limit": exc.limit}
    except ApiError as exc:
        return {"ok": False, "detail": exc.detail, "field": exc.field, "value": _jsonable(exc.value),
                "limit": exc.limit, "status": exc.status}
    profile = fields["request"]["profile"]
    return {"ok": True, "detail": "the commissioning can start", "start_m": profile["start_m"],
            "duration_s": fields["duration_s"], "limits": fields["limits"],
            "vertical_load_n": fields["vertical_load_n"], "isolator": fields["isolator"], "what": profile["what"],
            "speed": fields["speed"], "wall_s": fields["duration_s"] / fields["speed"]}


@router.get("/api/commissioning/{test_id}", summary="A commissioning: its state (running, fitting, trusted, "
            "not_trusted, fit_failed), the fitted values against the declared ones, the frequency response",
            responses=ERROR_RESPONSES)
def get_result(test_id: TestId, session: SessionDep) -> dict:
    return commissioning.result(session, _commissioning_or_404(session, test_id))


@router.get("/api/commissioning/{test_id}/rig.json", summary="The commissioned rig file (only when trusted)",
            response_class=JSONResponse, responses=ERROR_RESPONSES)
def rig_json(test_id: TestId, session: SessionDep) -> JSONResponse:
    data = commissioning.rig_file_of(_commissioning_or_404(session, test_id))
    return JSONResponse(data, headers={"Content-Disposition":
                                       f'attachment; filename="commissioned-rig-{test_id}.json"'})


@router.post("/api/commissioning/{test_id}/apply", summary="Make the commissioned rig file the service's rig "
             "(role operator; only a trusted one, only when no test runs)", responses=ERROR_RESPONSES)
def apply(test_id: TestId, request: Request, session: SessionDep, actor: OperatorDep,
          body: Annotated[ApplyRigIn | None, Body()] = None) -> dict:
    """Writes the rig file into the data directory and switches the rig the next tests and ``GET /api/rig``
    use; it stays in force across a restart unless the service is started with ``--rig-file`` (the answer's
    ``in_force.note`` says so). 409 for a commissioning that is not trusted (with its reasons), of another rig,
    or while a run goes on."""
    test = _commissioning_or_404(session, test_id)
    rig_name = request.app.state.service.rig_name
    if test.rig_name != rig_name:  # another rig's identification is not this rig's
        raise ApiError(409, f"commissioning {test_id} identified the rig {test.rig_name!r}; this service drives the "
                            f"rig {rig_name!r}: apply it from the service of {test.rig_name!r}", "rig_name",
                       test.rig_name, rig_name)
    running = request.app.state.service.running_test_id()
    if running is not None:
        raise ApiError(409, f"test {running} is running; the service's rig changes only when no test runs")
    data = commissioning.rig_file_of(test)
    by = acting_name(actor, body.operator_name if body else "", "operator_name")
    described, origin = rig_in_force.apply(request.app.state.settings, data, test_id, by)
    request.app.state.rig_description = described
    request.app.state.rig = described.parameters
    request.app.state.rig_origin = origin
    c = dict((test.summary or {}).get("commissioning") or {})
    c["applied"] = {"at": origin["at"], "by": by, "path": origin["path"]}
    test.summary = {**(test.summary or {}), "commissioning": c}
    message = f"rig file '{described.name}' of commissioning {test_id} made the service's rig by {by}"
    values = {"action": "apply_rig", "path": origin["path"], "name": described.name, "by": by}
    store.add_event(session, test_id, "operator", message, values, actor=actor)
    session.commit()
    request.app.state.service.publish_event(test_id, None, "operator", message, values)
    return {"rig_file": described.to_dict(), "in_force": origin,
            "commissioning": commissioning.result(session, test)}
