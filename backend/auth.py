"""Who is asking: the account behind a request, and the role a route needs (backend.accounts).

A request proves its account with ``Authorization: Bearer <API token>`` (scripts; ``isorig user token NAME``) or
with the login session cookie a browser got from ``POST /api/session``: HttpOnly (no script reads it),
SameSite=Strict (no other site's page sends it) and Secure behind HTTPS. ``ISORIG_OPERATOR_TOKEN``, where set,
is the token of the named service account ``automation`` (role operator), for a lab's automation.

A wrong or expired credential is 401 and a role too small 403, each saying what would do; neither ever names
where a secret lives on the server.
"""

from __future__ import annotations

import secrets
import threading
import time
from collections import deque

from fastapi import Request
from fastapi.security import HTTPAuthorizationCredentials, HTTPBearer

from . import accounts
from .accounts import NOBODY, SERVICE_ACCOUNT, Actor
from .errors import ApiError

SESSION_COOKIE = "isorig_session"
bearer = HTTPBearer(auto_error=False, description="an API token: Authorization: Bearer <token> (`isorig user "
                    "token NAME` on the service's machine); a browser logs in instead (POST /api/session)")

HOW_TO_LOG_IN = ("log in (the console's Log in button, or POST /api/session with name and password) or send an "
                 "API token: 'Authorization: Bearer <token>' (`isorig user token NAME` on the service's machine)")


def _unauthorised(detail: str) -> ApiError:
    return ApiError(401, detail, headers={"WWW-Authenticate": "Bearer"})


def actor_of(request: Request, credentials: HTTPAuthorizationCredentials | None) -> Actor:
    """The account behind the request (NOBODY without a credential); 401 for a credential that is not valid."""
    cached = getattr(request.state, "actor", None)
    if cached is not None:
        return cached
    actor = _resolve(request, credentials)
    request.state.actor = actor
    return actor


def _resolve(request: Request, credentials: HTTPAuthorizationCredentials | None) -> Actor:
    app = request.app.state
    if credentials is not None:
        if credentials.scheme.lower() != "bearer":
            raise _unauthorised(f"only Bearer tokens are taken: {HOW_TO_LOG_IN}")
        token = credentials.credentials
        service = app.service_token
        if service and secrets.compare_digest(token.encode(), service.encode()):
            return Actor(SERVICE_ACCOUNT, "operator", "service-token")
        with app.sessions() as session:
            actor = accounts.actor_for(session, token, "token")
        if actor is None:
            raise _unauthorised(f"this API token is not valid (unknown, revoked, or its account disabled): "
                                f"{HOW_TO_LOG_IN}")
        return actor
    cookie = request.cookies.get(SESSION_COOKIE)
    if cookie:
        with app.sessions() as session:
            actor = accounts.actor_for(session, cookie, "session")
        if actor is None:
            raise _unauthorised(f"your login has ended (expired, logged out, or the account disabled): "
                                f"{HOW_TO_LOG_IN}")
        return actor
    return NOBODY


def require(request: Request, credentials: HTTPAuthorizationCredentials | None, role: str) -> Actor:
    """The acting account if it holds ``role`` (or a larger one); else 401 (nobody) or 403 (too small a role)."""
    actor = actor_of(request, credentials)
    if actor.role is None:
        raise _unauthorised(f"this action needs an account with the role {role} or above: {HOW_TO_LOG_IN}")
    if not actor.has(role):
        raise ApiError(403, f"this action needs the role {role} or above; {actor.name} is {_article(actor.role)} "
                            f"{actor.role} (an admin changes roles: `isorig user role NAME ROLE`)")
    return actor


def _article(role: str) -> str:
    return "an" if role[0] in "aeiou" else "a"


class LoginThrottle:
    """At most ``limit`` failed logins per account name, and ``address_limit`` per client address (a console
    several people share), in ``window_s``: beyond, 429 with the seconds to wait. Guessing a random password
    over the network then takes centuries, not hours."""

    def __init__(self, limit: int = 5, address_limit: int = 20, window_s: float = 300.0):
        self.limits = {"n": limit, "a": address_limit}
        self.window_s = window_s
        self._failures: dict[str, deque] = {}
        self._lock = threading.Lock()

    def _recent(self, key: str, now: float) -> deque:
        q = self._failures.setdefault(key, deque())
        while q and now - q[0] > self.window_s:
            q.popleft()
        return q

    def wait_s(self, name: str, address: str) -> float:
        """Seconds before another try is taken (0: now)."""
        now = time.monotonic()
        with self._lock:
            waits = [self.window_s - (now - q[0]) for key in (f"n:{name}", f"a:{address}")
                     if len(q := self._recent(key, now)) >= self.limits[key[0]]]
        return max(waits, default=0.0)

    def failed(self, name: str, address: str) -> None:
        now = time.monotonic()
        with self._lock:
            for key in (f"n:{name}", f"a:{address}"):
                self._recent(key, now).append(now)
            if len(self._failures) > 10_000:  # a flood of names: forget the oldest, keep memory bounded
                for key in list(self._failures)[:5_000]:
                    del self._failures[key]

    def succeeded(self, name: str) -> None:
        with self._lock:
            self._failures.pop(f"n:{name}", None)
