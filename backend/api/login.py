"""Logging in and out of the console: ``POST /api/session`` (name, password) sets the login cookie, ``GET``
says who is logged in, ``DELETE`` logs out (backend.auth, backend.accounts)."""

from __future__ import annotations

import math

from fastapi import APIRouter, Request, Response
from pydantic import BaseModel, Field

from .. import accounts
from ..auth import SESSION_COOKIE, ThrottleFull, actor_of
from ..errors import ApiError
from ..schemas import ERROR_RESPONSES
from .deps import Credentials, SessionDep

router = APIRouter(tags=["accounts"])


class LoginIn(BaseModel):
    name: str = Field(min_length=1, max_length=64, description="the account's name")
    password: str = Field(min_length=1, max_length=1024)


class WhoOut(BaseModel):
    name: str | None = Field(description="the logged-in account, null when nobody is")
    role: str | None = Field(description="viewer, operator, approver or admin")
    via: str = Field(description="session (the console's login), token (an API token), service-token "
                                 "(ISORIG_OPERATOR_TOKEN) or none")


@router.post("/api/session", summary="Log in: the login cookie for the console (HttpOnly, SameSite=Strict)",
             responses=ERROR_RESPONSES)
def log_in(body: LoginIn, request: Request, response: Response, session: SessionDep) -> WhoOut:
    throttle = request.app.state.login_throttle
    address = request.client.host if request.client else ""
    try:
        wait = throttle.admit(body.name, address)  # the guess is counted here, before its password is checked
    except ThrottleFull as full:
        raise ApiError(503, "too many addresses are guessing passwords right now (the login throttle's table is "
                            f"full): try again in {math.ceil(full.wait_s)} s",
                       headers={"Retry-After": str(math.ceil(full.wait_s))}) from None
    if wait > 0:
        raise ApiError(429, f"too many failed logins from your address: try again in "
                            f"{math.ceil(wait)} s (each wrong password doubles the wait, up to "
                            f"{throttle.max_delay_s / 60:.0f} min)", headers={"Retry-After": str(math.ceil(wait))})
    done = accounts.log_in(session, body.name, body.password)
    if done is None:
        throttle.failed(body.name, address)
        session.commit()
        raise ApiError(401, "wrong name or password, or the account is disabled (an admin can set a new password: "
                            "`isorig user password NAME`)")
    user, secret = done
    session.commit()
    throttle.succeeded(body.name, address)
    response.set_cookie(SESSION_COOKIE, secret, max_age=int(accounts.SESSION_LIFETIME.total_seconds()),
                        httponly=True, samesite="strict", secure=request.url.scheme == "https", path="/")
    return WhoOut(name=user.name, role=user.role, via="session")


@router.get("/api/session", summary="Who is logged in (name null: nobody)")
def who(request: Request, credentials: Credentials) -> WhoOut:
    try:
        actor = actor_of(request, credentials)
    except ApiError:  # an ended login is nobody, not an error, for this question
        actor = accounts.NOBODY
    return WhoOut(name=actor.name or None, role=actor.role, via=actor.via)


@router.delete("/api/session", status_code=204, summary="Log out: the login ends now, on the server too")
def log_out(request: Request, session: SessionDep) -> Response:
    secret = request.cookies.get(SESSION_COOKIE)
    if secret:
        accounts.log_out(session, secret)
        session.commit()
    response = Response(status_code=204)
    response.delete_cookie(SESSION_COOKIE, path="/", httponly=True, samesite="strict")
    return response
