"""The lab's settings (backend.lab): read by anyone, changed by an admin; every report uses them."""

from __future__ import annotations

from typing import Literal

from fastapi import APIRouter, Request, Response
from pydantic import Field

from .. import lab, store
from ..errors import ApiError
from ..schemas import ERROR_RESPONSES, StrictModel
from .deps import AdminDep, SessionDep, not_found

router = APIRouter(tags=["lab"])


class LabIn(StrictModel):
    """What an admin changes; a field left out stays as it is."""

    name: str | None = Field(None, max_length=200, description="the lab's name, at the top of every report")
    address: str | None = Field(None, max_length=500, description="its address (lines separated by newlines or ';')")
    units: Literal["lab", "si"] | None = Field(None, description="what a console shows until a person chooses: lab "
                                               "(mm, kN, kN/mm) or si (m, N, N/m); the CSV and the API stay SI")


class LogoIn(StrictModel):
    data_base64: str | None = Field(description="a PNG or JPEG of at most 1 MiB, base64; null removes the logo",
                                    max_length=lab.LOGO_MAX_BYTES * 3)  # the clear refusal comes from backend.lab


def _answer(request: Request, session) -> dict:
    return lab.describe(session, request.app.state.settings)


@router.get("/api/lab", summary="The lab: name, address, logo, default units, and who set them")
def get_lab(request: Request, session: SessionDep) -> dict:
    return _answer(request, session)


@router.put("/api/lab", summary="Change the lab's name, address or default units (role admin)",
            responses=ERROR_RESPONSES)
def put_lab(body: LabIn, request: Request, session: SessionDep, actor: AdminDep) -> dict:
    try:
        lab.update(session, actor.name, body.name, body.address, body.units)
    except lab.LabError as exc:
        raise ApiError(422, str(exc), field=exc.field) from None
    store.add_event(session, None, "admin", f"lab settings changed by {actor.name}",
                    body.model_dump(exclude_none=True), actor=actor.name)
    session.commit()
    return _answer(request, session)


@router.put("/api/lab/logo", summary="Set (or remove, null) the lab's logo: PNG or JPEG, at most 1 MiB (role admin)",
            responses=ERROR_RESPONSES)
def put_logo(body: LogoIn, request: Request, session: SessionDep, actor: AdminDep) -> dict:
    try:
        lab.set_logo(session, actor.name, body.data_base64)
    except lab.LabError as exc:
        raise ApiError(422, str(exc), field=exc.field) from None
    store.add_event(session, None, "admin", f"lab logo {'removed' if body.data_base64 is None else 'set'} by "
                    f"{actor.name}", {}, actor=actor.name)
    session.commit()
    return _answer(request, session)


@router.get("/api/lab/logo", summary="The lab's stored logo", response_class=Response, responses=ERROR_RESPONSES)
def get_logo(session: SessionDep) -> Response:
    row = lab.row(session)
    if row is None or row.logo is None:
        raise not_found("a stored lab logo")
    return Response(row.logo, media_type=row.logo_type, headers={"Cache-Control": "no-cache",
                                                                 "X-Content-Type-Options": "nosniff"})
