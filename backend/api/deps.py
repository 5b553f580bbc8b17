"""Shared route dependencies: a database session per request, the operator check, the app's services."""

from __future__ import annotations

from collections.abc import Iterator
from typing import Annotated

from fastapi import Depends, Path, Request
from fastapi.security import HTTPAuthorizationCredentials
from sqlalchemy.orm import Session

from ..auth import bearer, require_operator
from ..errors import ApiError

MAX_ID = 2**53  # ids beyond any database's integer range are simply not found


def get_session(request: Request) -> Iterator[Session]:
    with request.app.state.sessions() as session:
        yield session


def operator(request: Request,
             credentials: Annotated[HTTPAuthorizationCredentials | None, Depends(bearer)]) -> str:
    return require_operator(request, credentials)


def anyone(request: Request,
           credentials: Annotated[HTTPAuthorizationCredentials | None, Depends(bearer)]) -> str:
    """Who asks to end a test (stop, abort): the operator with the token, else anyone at a console, named by
    address. Ending a test only takes energy out of the rig, like an emergency stop button: it is never refused
    for a missing or stale token."""
    try:
        return require_operator(request, credentials)
    except ApiError:
        host = request.client.host if request.client else "unknown address"
        return f"a console without the token ({host})"


SessionDep = Annotated[Session, Depends(get_session)]
OperatorDep = Annotated[str, Depends(operator)]
AnyoneDep = Annotated[str, Depends(anyone)]
TestId = Annotated[int, Path(ge=1, le=MAX_ID, description="test id")]


def not_found(what: str) -> ApiError:
    return ApiError(404, f"{what} does not exist")
