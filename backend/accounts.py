"""Accounts: who may act, in which role, and how they prove it.

Roles, each including the ones before it: ``viewer`` (reads), ``operator`` (runs tests, moves the rig, changes
records that are not approved), ``approver`` (reviews and approves records), ``admin`` (accounts, lab settings).

A person proves who they are with a password (hashed with argon2id, argon2-cffi's defaults; only the test suite
makes cheaper hashes, ``TEST_CHEAP_HASHES_ENV`` below) and gets a login session, a cookie the browser sends back;
a script uses an API token (``isorig user token NAME``). Both are random secrets of 256 bits stored only as their
SHA-256, so a copy of the database logs nobody in. A disabled account's sessions and tokens stop working at once.
"""

from __future__ import annotations

import functools
import hashlib
import os
import re
import secrets
from dataclasses import dataclass
from datetime import UTC, datetime, timedelta
from pathlib import Path

from argon2 import PasswordHasher
from argon2.exceptions import InvalidHashError, VerificationError
from sqlalchemy import delete, select
from sqlalchemy.orm import Session

from .models import Credential, UserAccount, as_utc, utcnow

ROLES = ("viewer", "operator", "approver", "admin")
FIRST_PASSWORD_FILE = "first-admin-password.txt"  # in the data directory: the first admin's password, mode 0600
NAME_PATTERN = re.compile(r"^[A-Za-z0-9][A-Za-z0-9._@-]{0,63}$")
NAME_RULE = "1-64 characters: letters, digits and . _ @ -, starting with a letter or digit"
PASSWORD_MIN_CHARS = 10
SESSION_LIFETIME = timedelta(hours=12)  # a login lasts a working day
SESSION_PREFIX = "iss_"
TOKEN_PREFIX = "ist_"
SERVICE_ACCOUNT = "automation"  # the account ISORIG_OPERATOR_TOKEN acts as

# TEST ONLY: "1" makes argon2id hashes of one pass over 8 KiB (~0.1 ms instead of ~0.2 s of CPU), which the test
# suite sets (tests/conftest.py) because its services and accounts hash passwords hundreds of times. Unset or empty
# is production: argon2-cffi's defaults. Any other value is refused, so a typo never weakens a service silently. A
# cheap hasher never rehashes a stored hash at login, so a production hash is never made cheaper (_rehashes).
TEST_CHEAP_HASHES_ENV = "ISORIG_TEST_ONLY_CHEAP_PASSWORD_HASHES"


def password_hasher(environ=os.environ) -> PasswordHasher:
    """The password hasher ``environ`` asks for: argon2-cffi's defaults, or the test suite's cheap one (above)."""
    value = environ.get(TEST_CHEAP_HASHES_ENV, "")
    if value == "":
        return PasswordHasher()
    if value != "1":
        raise RuntimeError(f"{TEST_CHEAP_HASHES_ENV}={value!r}: it is for the test suite only and takes 1 or nothing; "
                           "a service runs without it")
    return PasswordHasher(time_cost=1, memory_cost=8, parallelism=1)


def _rehashes(hasher: PasswordHasher) -> bool:
    """Whether logins rehash a stored hash made with other parameters: only with hashes at least as costly as
    argon2-cffi's defaults (never down to the test suite's cheap ones)."""
    default = PasswordHasher()
    return hasher.time_cost >= default.time_cost and hasher.memory_cost >= default.memory_cost


_hasher = password_hasher()


class AccountError(ValueError):
    """A request about accounts that cannot be done; the message says why and what is allowed."""


@dataclass(frozen=True)
class Actor:
    """Who acts in a request: an account's name and role, or nobody (``role`` None)."""

    name: str
    role: str | None
    via: str = "session"  # session | token | service-token | none

    def has(self, role: str) -> bool:
        return self.role is not None and ROLES.index(self.role) >= ROLES.index(role)


NOBODY = Actor("", None, "none")


def check_name(name: str) -> str:
    if not NAME_PATTERN.match(name or ""):
        raise AccountError(f"the account name {name!r} is not allowed: {NAME_RULE}")
    return name


def check_role(role: str) -> str:
    if role not in ROLES:
        raise AccountError(f"the role {role!r} does not exist; roles: {', '.join(ROLES)}")
    return role


def check_password(password: str) -> str:
    if len(password) < PASSWORD_MIN_CHARS:
        raise AccountError(f"a password needs at least {PASSWORD_MIN_CHARS} characters")
    if len(password) > 1024:
        raise AccountError("a password may have at most 1024 characters")
    return password


def hash_password(password: str) -> str:
    return _hasher.hash(check_password(password))


def new_password() -> str:
    """A random password a person can type (about 120 bits)."""
    return secrets.token_urlsafe(15)


def find_user(session: Session, name: str) -> UserAccount | None:
    return session.scalars(select(UserAccount).where(UserAccount.name == name)).first()


def get_user(session: Session, name: str) -> UserAccount:
    user = find_user(session, name)
    if user is None:
        raise AccountError(f"there is no account {name!r} (`isorig user list` shows them)")
    return user


def add_user(session: Session, name: str, role: str, password: str | None) -> UserAccount:
    """A new account; ``password`` None makes an account that logs in by API token only."""
    check_name(name)
    check_role(role)
    if find_user(session, name) is not None:
        raise AccountError(f"the account {name!r} exists already")
    user = UserAccount(name=name, role=role, password_hash=hash_password(password) if password is not None else None)
    session.add(user)
    session.flush()
    return user


def set_password(session: Session, name: str, password: str) -> None:
    user = get_user(session, name)
    user.password_hash = hash_password(password)
    _revoke(session, user, "session")


def disable_user(session: Session, name: str) -> UserAccount:
    """The account can no longer log in; its sessions and tokens end now. Its name stays in every record."""
    user = get_user(session, name)
    if user.disabled_at is None:
        user.disabled_at = utcnow()
    _revoke(session, user, None)
    return user


def enable_user(session: Session, name: str) -> UserAccount:
    user = get_user(session, name)
    user.disabled_at = None
    return user


def users(session: Session) -> list[UserAccount]:
    return list(session.scalars(select(UserAccount).order_by(UserAccount.name)))


def ensure_service_account(session: Session) -> UserAccount:
    """The named account ISORIG_OPERATOR_TOKEN acts as (role operator, no password)."""
    user = find_user(session, SERVICE_ACCOUNT)
    if user is None:
        user = UserAccount(name=SERVICE_ACCOUNT, role="operator", password_hash=None)
        session.add(user)
        session.flush()
    return user


def first_admin(session: Session) -> tuple[str, str] | None:
    """On the first start (no account with a password yet): create ``admin`` with a random password and return
    (name, password), for ``write_first_password``; else None."""
    people = session.scalars(select(UserAccount).where(UserAccount.password_hash.is_not(None))).first()
    if people is not None:
        return None
    password = new_password()
    existing = find_user(session, "admin")
    if existing is None:
        add_user(session, "admin", "admin", password)
    else:
        existing.role, existing.password_hash, existing.disabled_at = "admin", hash_password(password), None
    return "admin", password


def _sha256(secret: str) -> str:
    return hashlib.sha256(secret.encode()).hexdigest()


def _revoke(session: Session, user: UserAccount, kind: str | None) -> None:
    query = select(Credential).where(Credential.user_id == user.id, Credential.revoked_at.is_(None))
    if kind is not None:
        query = query.where(Credential.kind == kind)
    for cred in session.scalars(query):
        cred.revoked_at = utcnow()


def _issue(session: Session, user: UserAccount, kind: str) -> str:
    secret = (SESSION_PREFIX if kind == "session" else TOKEN_PREFIX) + secrets.token_urlsafe(32)
    expires = utcnow() + SESSION_LIFETIME if kind == "session" else None
    session.add(Credential(secret_sha256=_sha256(secret), kind=kind, user_id=user.id, expires_at=expires))
    session.flush()
    return secret


def new_token(session: Session, name: str) -> str:
    """A new API token for the account (shown once; only its hash is kept). Earlier tokens stay valid."""
    user = get_user(session, name)
    if user.disabled_at is not None:
        raise AccountError(f"the account {name!r} is disabled (`isorig user enable {name}` first)")
    return _issue(session, user, "token")


def revoke_tokens(session: Session, name: str) -> int:
    user = get_user(session, name)
    before = session.scalars(select(Credential).where(Credential.user_id == user.id, Credential.kind == "token",
                                                      Credential.revoked_at.is_(None))).all()
    _revoke(session, user, "token")
    return len(before)


def log_in(session: Session, name: str, password: str) -> tuple[UserAccount, str] | None:
    """(account, session secret) for the right password of an enabled account, else None. The hash is checked
    even for an unknown name, so the answer's time does not tell which names exist."""
    user = find_user(session, name) if NAME_PATTERN.match(name or "") else None
    stored = user.password_hash if user is not None and user.password_hash else _dummy_hash()
    try:
        _hasher.verify(stored, password)
    except (VerificationError, InvalidHashError):
        return None
    if user is None or user.password_hash is None or user.disabled_at is not None:
        return None
    if _rehashes(_hasher) and _hasher.check_needs_rehash(user.password_hash):
        user.password_hash = _hasher.hash(password)
    purge_ended_sessions(session)
    return user, _issue(session, user, "session")


def purge_ended_sessions(session: Session) -> int:
    """Delete the login sessions that can never be used again (expired, or ended by logout or by disabling the
    account, ``SESSION_LIFETIME`` ago): without it every login left a row behind for ever. API tokens are kept
    (a revoked one is listed as such). Returns how many were deleted."""
    now = utcnow()
    ended = delete(Credential).where(Credential.kind == "session",
                                     (Credential.expires_at <= now) | (Credential.revoked_at <= now - SESSION_LIFETIME))
    return session.execute(ended).rowcount or 0


def log_out(session: Session, secret: str) -> None:
    cred = session.scalars(select(Credential).where(Credential.secret_sha256 == _sha256(secret))).first()
    if cred is not None and cred.revoked_at is None:
        cred.revoked_at = utcnow()


def actor_for(session: Session, secret: str, kind: str) -> Actor | None:
    """The account a session secret or API token belongs to, if it is valid now (not revoked, not expired, the
    account enabled); else None."""
    cred = session.scalars(select(Credential).where(Credential.secret_sha256 == _sha256(secret),
                                                    Credential.kind == kind)).first()
    if cred is None or cred.revoked_at is not None:
        return None
    if cred.expires_at is not None and as_utc(cred.expires_at) <= datetime.now(UTC):
        return None
    user = cred.user
    if user.disabled_at is not None:
        return None
    return Actor(user.name, user.role, kind)


@functools.cache
def _dummy_hash() -> str:
    """A hash no password matches, verified for an unknown name (made on first need, not at every import)."""
    return _hasher.hash(secrets.token_urlsafe(16))


def acting_name(account: str, given: str, field: str) -> str:
    """The name a record keeps for who did something (``operator_name``, who archived ...): the logged-in
    account's. A person's account cannot write another name (AccountError naming the field); the service account
    ``automation`` acts for a lab's scripts, so the name they give is kept beside it: "bob (through automation)"."""
    given = (given or "").strip()
    if account == SERVICE_ACCOUNT:
        return f"{given} (through {SERVICE_ACCOUNT})" if given and given != SERVICE_ACCOUNT else SERVICE_ACCOUNT
    if given and given != account:
        raise AccountError(f"{field} is who is logged in ({account}); leave it out or give {account!r}, not "
                           f"{given!r}: every record names the account that acted")
    return account


def write_first_password(path: Path, password: str) -> Path:
    """The first admin's password (one line, as ``isorig user --password-file`` reads) written to ``path``, owner
    only (0600) from its first byte: a new file beside it, renamed over any old one, so no other account on the
    machine ever reads it and no log or terminal ever holds it. A missing directory is made 0700. Its path."""
    from .db import owner_only_dir

    path = Path(path)
    owner_only_dir(path.parent)
    spare = path.with_name(f".{path.name}.{secrets.token_hex(4)}.new")
    fd = os.open(spare, os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_NOFOLLOW", 0), 0o600)
    try:
        os.fchmod(fd, 0o600)  # the umask never widens it; fchmod only narrows what open made
        with os.fdopen(fd, "w", encoding="utf-8") as out:
            out.write(password + "\n")
            out.flush()
            os.fsync(out.fileno())
        os.replace(spare, path)
    except BaseException:
        spare.unlink(missing_ok=True)
        raise
    return path
