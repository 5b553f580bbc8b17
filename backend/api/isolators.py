"""Isolators: the presets of sim.isolator and user-defined ones (validated, stored)."""

from __future__ import annotations

from fastapi import APIRouter, Path
from fastapi.responses import Response

from sim.isolator import PRESETS, Isolator, isolator_from_dict

from .. import store
from ..errors import ApiError
from ..schemas import ERROR_RESPONSES, IsolatorIn, IsolatorOut
from .deps import OperatorDep, SessionDep, not_found

router = APIRouter(tags=["isolators"])


def _out(iso: Isolator | dict, source: str) -> dict:
    data = iso.to_dict() if isinstance(iso, Isolator) else dict(iso)
    return {**data, "source": source}


def resolve_isolator(session, name: str) -> Isolator:
    """A preset or a stored user isolator by name, or ApiError 422 naming the field."""
    if name in PRESETS:
        return PRESETS[name]
    definition = store.get_user_isolator(session, name)
    if definition is None:
        users = [d["name"] for d in store.list_user_isolators(session)]
        raise ApiError(422, f"isolator {name!r} is unknown; presets: {', '.join(PRESETS)}"
                            + (f"; user isolators: {', '.join(users)}" if users else ""),
                       "isolator", name, "a preset or a user isolator name")
    return isolator_from_dict(definition)


@router.get("/api/isolators", summary="All isolators: presets and user-defined")
def list_isolators(session: SessionDep) -> list[IsolatorOut]:
    out = [_out(iso, "preset") for iso in PRESETS.values()]
    out += [_out(d, "user") for d in store.list_user_isolators(session)]
    return out


@router.post("/api/isolators", status_code=201, summary="Add a user isolator (role operator)",
             responses=ERROR_RESPONSES)
def create_isolator(body: IsolatorIn, session: SessionDep, actor: OperatorDep) -> IsolatorOut:
    iso = isolator_from_dict(body.model_dump())  # ranges: IsolatorError -> 422
    if iso.name in PRESETS:
        raise ApiError(409, f"isolator name {iso.name!r} is a preset; choose another name", "name", iso.name)
    if store.get_user_isolator(session, iso.name) is not None:
        raise ApiError(409, f"a user isolator named {iso.name!r} exists already", "name", iso.name)
    store.add_user_isolator(session, iso.to_dict())
    store.add_event(session, None, "operator", f"user isolator {iso.name!r} added by {actor}",
                    {"action": "create_isolator", "isolator": iso.to_dict()}, actor=actor)
    session.commit()
    return _out(iso, "user")


@router.delete("/api/isolators/{name}", status_code=204, summary="Delete a user isolator (role operator)",
               responses=ERROR_RESPONSES)
def delete_isolator(name: str, session: SessionDep, actor: OperatorDep) -> Response:
    """Presets cannot be deleted; a user isolator can (the records of its tests keep their own copy)."""
    if name in PRESETS:
        raise ApiError(409, f"isolator {name!r} is a preset (the paper's or a shipped example); only user "
                            "isolators can be deleted", "name", name)
    if not store.delete_user_isolator(session, name):
        raise not_found(f"isolator {name!r}")
    store.add_event(session, None, "operator", f"user isolator {name!r} deleted by {actor}",
                    {"action": "delete_isolator", "name": name}, actor=actor)
    session.commit()
    return Response(status_code=204)


@router.get("/api/isolators/{name}", summary="One isolator", responses=ERROR_RESPONSES)
def get_isolator(session: SessionDep, name: str = Path(max_length=64)) -> IsolatorOut:
    if name in PRESETS:
        return _out(PRESETS[name], "preset")
    definition = store.get_user_isolator(session, name)
    if definition is None:
        raise not_found(f"isolator {name!r}")
    return _out(definition, "user")
