"""Who is asking: the account behind a request, and the role a route needs (backend.accounts).

A request proves its account with ``Authorization: Bearer <API token>`` (scripts; ``isorig user token NAME``) or
with the login session cookie a browser got from ``POST /api/session``: HttpOnly (no script reads it),
SameSite=Strict (no other site's page sends it) and Secure behind HTTPS. ``ISORIG_OPERATOR_TOKEN``, where set,
is the token of the named service account ``automation`` (role operator), for a lab's automation.

A wrong or expired credential is 401 and a role too small 403, each saying what would do; neither ever names
where a secret lives on the server.
"""

from __future__ import annotations

import ipaddress
import logging
import secrets
import threading
import time
from collections import OrderedDict
from dataclasses import dataclass

from fastapi import Request
from fastapi.security import HTTPAuthorizationCredentials, HTTPBearer

from . import accounts
from .accounts import NOBODY, SERVICE_ACCOUNT, Actor
from .errors import ApiError

log = logging.getLogger(__name__)

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
        return _account(app, token, "token", "this API token is not valid (unknown, revoked, or its account "
                        "disabled)")
    cookie = request.cookies.get(SESSION_COOKIE)
    if cookie:
        return _account(app, cookie, "session", "your login has ended (expired, logged out, or the account "
                        "disabled)")
    return NOBODY


def _account(app, secret: str, kind: str, why: str) -> Actor:
    """The account a session secret or API token stands for now, else 401 saying ``why`` and how to log in."""
    with app.sessions() as session:
        actor = accounts.actor_for(session, secret, kind)
    if actor is None:
        raise _unauthorised(f"{why}: {HOW_TO_LOG_IN}")
    return actor


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


class ThrottleFull(Exception):
    """The throttle's table holds ``max_entries`` live entries: a guess that needs a new one waits ``wait_s``."""

    def __init__(self, wait_s: float):
        super().__init__(wait_s)
        self.wait_s = wait_s


@dataclass
class _Guesses:
    failures: int = 0  # guesses counted (a right password takes its own back)
    last: float = 0.0  # when the last guess was admitted or answered


def address_key(host: str) -> str:
    """The client address a throttle counts by: an IPv6 address's /64 (one machine's share), else the address."""
    try:
        ip = ipaddress.ip_address(host)
    except ValueError:
        return host[:64]
    if ip.version == 6 and ip.ipv4_mapped is None:
        return str(ipaddress.ip_network(f"{ip}/64", strict=False))
    return str(getattr(ip, "ipv4_mapped", None) or ip)


class LoginThrottle:
    """Progressive delays for password guesses (OWASP), per name from one address and per address.

    A guess is counted when it is admitted, before its password is checked (so a parallel burst gets no more than
    the free guesses checked); a right password takes its count back. After ``limit`` failures for a name from
    one address (``address_limit`` from one address over all names) each further guess waits ``first_delay_s``,
    doubled per failure, at most ``max_delay_s``, after the last one. Nothing is kept per name alone: guesses
    from one address never slow the account's owner at another. An entry is forgotten ``forget_s`` after its
    last guess, and only then; the table holds at most ``max_entries``, and a guess that would need a new entry
    in a full table is refused (``ThrottleFull``) rather than any count forgotten."""

    def __init__(self, limit: int = 5, address_limit: int = 20, first_delay_s: float = 1.0,
                 max_delay_s: float = 300.0, forget_s: float = 900.0, max_entries: int = 100_000,
                 clock=time.monotonic):
        self.limits = {"pair": limit, "address": address_limit}
        self.first_delay_s, self.max_delay_s = first_delay_s, max_delay_s
        self.forget_s = max(forget_s, max_delay_s)
        self.max_entries = max_entries
        self.clock = clock
        self._entries: OrderedDict[tuple, _Guesses] = OrderedDict()  # least recently touched first
        self._lock = threading.Lock()

    def delay_s(self, failures: int, limit: int) -> float:
        """The wait after the last guess before the next one, with ``failures`` counted."""
        if failures < limit:
            return 0.0
        return min(self.first_delay_s * 2.0 ** (failures - limit), self.max_delay_s)

    def _keys(self, name: str, address: str) -> list[tuple]:
        where = address_key(address)
        return [("pair", name, where), ("address", where)]

    def _touch(self, key: tuple, entry: _Guesses, now: float) -> None:
        entry.last = now
        self._entries[key] = entry
        self._entries.move_to_end(key)

    def _forget(self, now: float) -> None:
        """Drop the entries whose last guess is ``forget_s`` old (they are kept oldest first)."""
        while self._entries:
            key, entry = next(iter(self._entries.items()))
            if now - entry.last < self.forget_s:
                return
            del self._entries[key]

    def admit(self, name: str, address: str) -> float:
        """Count this guess now and return 0.0, or return the seconds to wait (then nothing is counted).
        ``ThrottleFull`` when it would need a new entry in a full table."""
        now = self.clock()
        with self._lock:
            self._forget(now)
            keys = self._keys(name, address)
            entries = [self._entries.get(key) for key in keys]
            wait = max((e.last + self.delay_s(e.failures, self.limits[key[0]]) - now
                        for key, e in zip(keys, entries, strict=True) if e is not None), default=0.0)
            if wait > 0:
                return wait
            new = sum(e is None for e in entries)
            if new and len(self._entries) + new > self.max_entries:
                oldest = next(iter(self._entries.values()))
                raise ThrottleFull(max(oldest.last + self.forget_s - now, 1.0))
            for key, entry in zip(keys, entries, strict=True):
                entry = entry or _Guesses()
                entry.failures += 1
                self._touch(key, entry, now)
                if entry.failures == self.limits[key[0]]:
                    log.warning("login throttle: %d guesses %s without a right password; each further wrong one "
                                "waits from %.0f s, doubling", entry.failures, _describe(key), self.first_delay_s)
            return 0.0

    def failed(self, name: str, address: str) -> None:
        """The admitted guess was wrong: its count stays, and the delay runs from now."""
        now = self.clock()
        with self._lock:
            for key in self._keys(name, address):
                entry = self._entries.get(key)
                if entry is not None:
                    self._touch(key, entry, now)

    def succeeded(self, name: str, address: str) -> None:
        """The admitted guess was right: the name's failures from this address are forgotten, and the address
        gets its guess back."""
        pair, where = self._keys(name, address)
        with self._lock:
            self._entries.pop(pair, None)
            entry = self._entries.get(where)
            if entry is not None:
                entry.failures = max(0, entry.failures - 1)

    def __len__(self) -> int:
        return len(self._entries)


def _describe(key: tuple) -> str:
    return f"at {key[1]!r} from {key[2]}" if key[0] == "pair" else f"from {key[1]}"
