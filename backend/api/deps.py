"""Shared route dependencies: a database session per request, who acts and the role a route needs, the app's
services."""

from __future__ import annotations

from collections.abc import Iterator
from typing import Annotated

from fastapi import Depends, Path, Request
from fastapi.security import HTTPAuthorizationCredentials
from sqlalchemy.orm import Session

from .. import accounts
from ..accounts import Actor
from ..auth import actor_of, bearer, require
from ..errors import ApiError

MAX_ID = 2**53  # ids beyond any database's integer range are simply not found

Credentials = Annotated[HTTPAuthorizationCredentials | None, Depends(bearer)]


def get_session(request: Request) -> Iterator[Session]:
    with request.app.state.sessions() as session:
        yield session


def operator(request: Request, credentials: Credentials) -> str:
    """The name of the acting account, which must hold the role operator or above."""
    return require(request, credentials, "operator").name


def approver(request: Request, credentials: Credentials) -> Actor:
    return require(request, credentials, "approver")


def admin(request: Request, credentials: Credentials) -> Actor:
    return require(request, credentials, "admin")


def anyone(request: Request, credentials: Credentials) -> str:
    """Who asks to end a test (stop, abort): the logged-in account, else anyone at a console, named by address.
    Ending a test only takes energy out of the rig, like an emergency stop button: it is never refused for a
    missing, stale or wrong credential."""
    try:
        actor = actor_of(request, credentials)
    except ApiError:
        actor = None
    if actor is not None and actor.role is not None:
        return actor.name
    host = request.client.host if request.client else "unknown address"
    return f"a console without login ({host})"


SessionDep = Annotated[Session, Depends(get_session)]
OperatorDep = Annotated[str, Depends(operator)]
ApproverDep = Annotated[Actor, Depends(approver)]
AdminDep = Annotated[Actor, Depends(admin)]
AnyoneDep = Annotated[str, Depends(anyone)]
TestId = Annotated[int, Path(ge=1, le=MAX_ID, description="test id")]


def acting_name(actor: str, given: str, field: str) -> str:
    """The name a record keeps for who acted (backend.accounts.acting_name); a person's account giving another
    name is 422 on that field."""
    try:
        return accounts.acting_name(actor, given, field)
    except accounts.AccountError as exc:
        raise ApiError(422, str(exc), field=field, value=given, limit=f"'{actor}' or left out") from None


def not_found(what: str) -> ApiError:
    return ApiError(404, f"{what} does not exist")
