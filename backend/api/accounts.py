"""The lab's accounts from the console (role admin): list, add, role, password, disable, enable, API tokens.

The same rules as ``isorig user`` (backend.accounts: names, roles, a password of at least 10 characters, a new
password ends the account's logins, disabling ends its logins and tokens at once), plus one the command does not
need: an admin does not disable their own account nor change their own role here (another admin does, or
``isorig user`` on the service's machine), so the console can never lock out the admin using it.

A password left out is made here and answered once, like a new API token; neither is ever stored (only their
hashes) nor logged, and answers that carry one say ``Cache-Control: no-store``. Every change is an ``admin`` event
of the audit log naming the admin and the account. The service's doors (backend.doors) refuse a cross-site
request before any of these routes sees it.
"""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Path, Response
from pydantic import Field
from sqlalchemy import func, select

from .. import accounts, store
from ..errors import ApiError
from ..models import Credential, UserAccount, as_utc, utcnow
from ..schemas import ERROR_RESPONSES, StrictModel
from .deps import AdminDep, SessionDep

router = APIRouter(tags=["accounts"])

AccountName = Annotated[str, Path(max_length=64, description="the account's name")]
NO_STORE = {"Cache-Control": "no-store"}


class AccountIn(StrictModel):
    name: str = Field(max_length=64, description=accounts.NAME_RULE)
    role: str = Field(max_length=16, description="viewer, operator, approver or admin")
    password: str | None = Field(None, description=f"at least {accounts.PASSWORD_MIN_CHARS} characters; left out "
                                 "or null: one is made and answered once")


class RoleIn(StrictModel):
    role: str = Field(max_length=16, description="viewer, operator, approver or admin")


class PasswordIn(StrictModel):
    password: str | None = Field(None, description=f"at least {accounts.PASSWORD_MIN_CHARS} characters; left out "
                                 "or null: one is made and answered once")


def _describe(session, user: UserAccount) -> dict:
    now = utcnow()
    live = (Credential.user_id == user.id) & Credential.revoked_at.is_(None)
    tokens = session.scalar(select(func.count()).select_from(Credential).where(live, Credential.kind == "token"))
    logins = session.scalar(select(func.count()).select_from(Credential).where(
        live, Credential.kind == "session", Credential.expires_at > now))
    state = "disabled" if user.disabled_at else ("token only" if user.password_hash is None else "active")
    return {"name": user.name, "role": user.role, "state": state, "password": user.password_hash is not None,
            "created_at": _iso(user.created_at), "disabled_at": _iso(user.disabled_at), "tokens": tokens or 0,
            "logins": logins or 0, "service_account": user.name == accounts.SERVICE_ACCOUNT}


def _iso(moment) -> str | None:
    return as_utc(moment).isoformat() if moment is not None else None


def _user(session, name: str) -> UserAccount:
    user = accounts.find_user(session, name)
    if user is None:
        raise ApiError(404, f"there is no account {name!r}", field="name", value=name)
    return user


def _refused(exc: accounts.AccountError, field: str, value=None) -> ApiError:
    return ApiError(422, str(exc), field=field, value=value)


def _not_yourself(actor, name: str, what: str) -> None:
    if actor.name == name:
        raise ApiError(409, f"you cannot {what} your own account from the console ({name}): another admin does it, "
                            "or `isorig user` on the service's machine; the console never locks out the admin using it")


def _log(session, actor, message: str, account: str, **values) -> None:
    store.add_event(session, None, "admin", f"{message} by {actor.name}", {"account": account, **values},
                    actor=actor.name)


@router.get("/api/accounts", summary="The lab's accounts: role, state, live logins and API tokens (role admin)",
            responses=ERROR_RESPONSES)
def list_accounts(session: SessionDep, actor: AdminDep) -> dict:
    return {"accounts": [_describe(session, u) for u in accounts.users(session)], "roles": list(accounts.ROLES),
            "password_min_chars": accounts.PASSWORD_MIN_CHARS, "name_rule": accounts.NAME_RULE, "you": actor.name}


@router.post("/api/accounts", status_code=201, responses=ERROR_RESPONSES,
             summary="Add an account; a password left out is made and answered once (role admin)")
def add_account(body: AccountIn, response: Response, session: SessionDep, actor: AdminDep) -> dict:
    made = body.password is None
    password = accounts.new_password() if made else body.password
    try:
        accounts.check_name(body.name)
    except accounts.AccountError as exc:
        raise _refused(exc, "name", body.name) from None
    try:
        accounts.check_role(body.role)
    except accounts.AccountError as exc:
        raise _refused(exc, "role", body.role) from None
    if accounts.find_user(session, body.name) is not None:
        raise ApiError(409, f"the account {body.name!r} exists already", field="name", value=body.name)
    try:
        user = accounts.add_user(session, body.name, body.role, password)
    except accounts.AccountError as exc:
        raise _refused(exc, "password") from None  # the password itself is never echoed
    _log(session, actor, f"account {user.name} added ({user.role})", user.name, role=user.role)
    session.commit()
    response.headers.update(NO_STORE)
    return {"account": _describe(session, user), "password": password if made else None}


@router.put("/api/accounts/{name}/role", summary="Give an account another role (role admin; not your own)",
            responses=ERROR_RESPONSES)
def set_role(name: AccountName, body: RoleIn, session: SessionDep, actor: AdminDep) -> dict:
    user = _user(session, name)
    try:
        accounts.check_role(body.role)
    except accounts.AccountError as exc:
        raise _refused(exc, "role", body.role) from None
    if user.role == body.role:
        return {"account": _describe(session, user)}
    _not_yourself(actor, name, "change the role of")
    before, user.role = user.role, body.role
    _log(session, actor, f"account {name} made {body.role} (was {before})", name, role=body.role, was=before)
    session.commit()
    return {"account": _describe(session, user)}


@router.post("/api/accounts/{name}/password", responses=ERROR_RESPONSES,
             summary="Set a new password (its logins end); left out, one is made and answered once (role admin)")
def reset_password(name: AccountName, body: PasswordIn, response: Response, session: SessionDep,
                   actor: AdminDep) -> dict:
    user = _user(session, name)
    made = body.password is None
    password = accounts.new_password() if made else body.password
    try:
        accounts.set_password(session, name, password)
    except accounts.AccountError as exc:
        raise _refused(exc, "password") from None
    _log(session, actor, f"new password set for {name}; its logins ended", name, made_here=made)
    session.commit()
    response.headers.update(NO_STORE)
    return {"account": _describe(session, user), "password": password if made else None,
            "logged_out": actor.name == name}


@router.post("/api/accounts/{name}/disable", responses=ERROR_RESPONSES,
             summary="Disable an account: its logins and tokens end now; its name stays in every record (role admin)")
def disable(name: AccountName, session: SessionDep, actor: AdminDep) -> dict:
    user = _user(session, name)
    _not_yourself(actor, name, "disable")
    was = user.disabled_at is not None
    accounts.disable_user(session, name)
    if not was:
        _log(session, actor, f"account {name} disabled; its logins and tokens ended", name)
    session.commit()
    return {"account": _describe(session, user)}


@router.post("/api/accounts/{name}/enable", summary="A disabled account may log in again (role admin)",
             responses=ERROR_RESPONSES)
def enable(name: AccountName, session: SessionDep, actor: AdminDep) -> dict:
    user = _user(session, name)
    if user.disabled_at is not None:
        accounts.enable_user(session, name)
        _log(session, actor, f"account {name} enabled", name)
        session.commit()
    return {"account": _describe(session, user)}


@router.post("/api/accounts/{name}/tokens", status_code=201, responses=ERROR_RESPONSES,
             summary="A new API token for the account, answered once (role admin)")
def new_token(name: AccountName, response: Response, session: SessionDep, actor: AdminDep) -> dict:
    user = _user(session, name)
    try:
        token = accounts.new_token(session, name)
    except accounts.AccountError as exc:
        raise ApiError(409, str(exc).replace(f"(`isorig user enable {name}` first)", "(enable it first)")) from None
    _log(session, actor, f"new API token for {name}", name)
    session.commit()
    response.headers.update(NO_STORE)
    return {"account": _describe(session, user), "token": token}


@router.delete("/api/accounts/{name}/tokens", summary="Every API token of the account ends (role admin)",
               responses=ERROR_RESPONSES)
def revoke_tokens(name: AccountName, session: SessionDep, actor: AdminDep) -> dict:
    user = _user(session, name)
    count = accounts.revoke_tokens(session, name)
    _log(session, actor, f"{count} API token(s) of {name} revoked", name, revoked=count)
    session.commit()
    return {"account": _describe(session, user), "revoked": count}
