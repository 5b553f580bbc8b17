"""The service's doors: what every request passes before any route sees it (a pure ASGI middleware).

1. **Host allow-list** (DNS rebinding): the ``Host`` header must name this service (``Settings.host_allow_list``:
   localhost, 127.0.0.1, [::1], the address it binds, and ``--allowed-host`` / ``ISORIG_ALLOWED_HOSTS``); anything
   else is 400 (a websocket: refused before it opens). A page on ``evil.example`` whose name was re-pointed at
   127.0.0.1 therefore reads nothing.
2. **Body cap**: a request body larger than ``max_body_bytes`` is 413 before it is read: a ``Content-Length``
   over the cap is answered without calling the application, a chunked body is counted as it streams and
   answered 413 the moment it passes the cap.
3. **Cross-site requests**: a request that changes state (any method but GET, HEAD, OPTIONS) from a browser
   must come from the service's own origin: an ``Origin`` header, when present, must be this service's
   (``scheme://Host``; ``null`` is foreign), a ``Sec-Fetch-Site`` of ``cross-site``/``same-site`` is refused,
   both 403. A body must be JSON (``Content-Type: application/json``), and any other content type is 415: an
   HTML form or a ``text/plain`` fetch, the requests a foreign page can send without asking, never reach a
   route. A browser request (it has an ``Origin``) must in addition carry JSON or the ``X-Isorig-Client``
   header, which a foreign page cannot set without a CORS preflight, which this service never grants.
   Clients that are not browsers (curl, scripts) send no ``Origin``: a body-less POST from them (``curl -X
   POST .../abort``) stays possible; browsers always send ``Origin`` on such requests (Fetch standard).
   Websockets: an ``Origin`` (browsers always send one) must be the service's own, else the handshake is
   refused (403).

Every refusal is one JSON error (``backend.errors`` shape) saying what is wrong and what is allowed.
"""

from __future__ import annotations

import json
from urllib.parse import urlsplit

from starlette.types import ASGIApp, Message, Receive, Scope, Send

SAFE_METHODS = frozenset({"GET", "HEAD", "OPTIONS"})
CLIENT_HEADER = "x-isorig-client"


def _json_body(status: int, detail: str, **extra) -> tuple[dict, bytes]:
    body = json.dumps({"detail": detail, **extra}).encode()
    return {"type": "http.response.start", "status": status,
            "headers": [(b"content-type", b"application/json"), (b"content-length", str(len(body)).encode()),
                        (b"connection", b"close")]}, body


async def _refuse(send: Send, status: int, detail: str, **extra) -> None:
    start, body = _json_body(status, detail, **extra)
    await send(start)
    await send({"type": "http.response.body", "body": body})


def host_name(host_header: str) -> str:
    """'Example.org:8000' -> 'example.org'; '[::1]:8000' -> '::1'."""
    value = host_header.strip().lower()
    if value.startswith("["):
        return value[1:value.find("]")] if "]" in value else value
    return value.rsplit(":", 1)[0] if value.count(":") == 1 else value


def is_json(content_type: str) -> bool:
    kind = content_type.split(";", 1)[0].strip().lower()
    return kind == "application/json" or (kind.startswith("application/") and kind.endswith("+json"))


class BodyTooLarge(Exception):
    """Raised into the application when a streamed body passes the cap (the 413 has been sent)."""


class ServiceDoors:
    """Pure ASGI middleware (never buffers a body): Host allow-list, body cap, cross-site refusals."""

    def __init__(self, app: ASGIApp, max_body_bytes: int, allowed_hosts: list[str]):
        self.app = app
        self.max_body_bytes = int(max_body_bytes)
        self.any_host = "*" in allowed_hosts
        self.allowed_hosts = frozenset(host_name(h) for h in allowed_hosts if h != "*")

    def host_allowed(self, host: str) -> bool:
        return self.any_host or host_name(host) in self.allowed_hosts

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] not in ("http", "websocket"):
            await self.app(scope, receive, send)
            return
        headers = {}
        for key, value in scope.get("headers") or ():
            headers.setdefault(key.decode("latin-1").lower(), value.decode("latin-1"))
        host = headers.get("host", "")
        if not self.host_allowed(host):
            detail = (f"Host {host[:100]!r} is not one this service answers to (allowed: "
                      f"{', '.join(sorted(self.allowed_hosts))}); add it with --allowed-host / "
                      "ISORIG_ALLOWED_HOSTS if the service is reached by that name")
            if scope["type"] == "websocket":
                await self._refuse_websocket(receive, send)
            else:
                await _refuse(send, 400, detail, field="Host", value=host[:100], limit="allowed_hosts")
            return
        origin = headers.get("origin")
        if scope["type"] == "websocket":
            if origin is not None and not self.same_origin(origin, host):
                await self._refuse_websocket(receive, send)
                return
            await self.app(scope, receive, send)
            return
        if scope["method"] not in SAFE_METHODS:
            refusal = self.cross_site(headers, origin, host)
            if refusal is not None:
                await _refuse(send, *refusal)
                return
        length = headers.get("content-length")
        if length is not None:
            try:
                n = int(length)
            except ValueError:
                await _refuse(send, 400, f"Content-Length {length[:40]!r} is not a number of bytes")
                return
            if n > self.max_body_bytes:
                await self._too_large(send, n)
                return
        await self._counted(scope, receive, send)

    @staticmethod
    def same_origin(origin: str, host: str) -> bool:
        """The Origin names this service as the browser reached it (scheme aside: a TLS proxy may sit before
        it)."""
        if origin == "null":
            return False
        parts = urlsplit(origin)
        return bool(parts.netloc) and parts.netloc.lower() == host.strip().lower()

    def cross_site(self, headers: dict, origin: str | None, host: str) -> tuple | None:
        """(status, detail) refusing a state-changing request a foreign page could have sent, else None."""
        if origin is not None and not self.same_origin(origin, host):
            return (403, f"cross-origin request refused: Origin {origin[:100]!r} is not this service "
                         f"({host[:100]}); the console changes state only from its own page")
        site = headers.get("sec-fetch-site")
        if site in ("cross-site", "same-site"):
            return (403, f"cross-site request refused (Sec-Fetch-Site: {site}); the console changes state only "
                         "from its own page")
        content_type = headers.get("content-type")
        has_body = headers.get("content-length", "0").strip() not in ("", "0") or "transfer-encoding" in headers
        if content_type is not None and not is_json(content_type):
            return (415, f"Content-Type {content_type[:100]!r} is refused for a request that changes state: send "
                         "JSON (Content-Type: application/json)")
        if content_type is None and has_body:
            return (415, "a request body needs Content-Type: application/json")
        if origin is not None and content_type is None and CLIENT_HEADER not in headers:
            return (403, "a browser request that changes state must send JSON (Content-Type: application/json) "
                         "or the X-Isorig-Client header, as the console does")
        return None

    async def _too_large(self, send: Send, n: int | None) -> None:
        got = f"{n} bytes" if n is not None else "more than that"
        await _refuse(send, 413, f"the request body is {got}; at most {self.max_body_bytes} bytes are accepted "
                                 "(max_body_bytes, ISORIG_MAX_BODY_BYTES)", field="body", value=n,
                      limit=f"<= {self.max_body_bytes} bytes")

    @staticmethod
    async def _refuse_websocket(receive: Receive, send: Send) -> None:
        message = await receive()  # websocket.connect
        if message["type"] == "websocket.connect":
            await send({"type": "websocket.close", "code": 1008})  # before accept: the server answers 403

    async def _counted(self, scope: Scope, receive: Receive, send: Send) -> None:
        """Call the application with a receive that counts the body and stops at the cap (chunked bodies)."""
        total = 0
        started = False
        refused = False

        async def counted_receive() -> Message:
            nonlocal total, refused
            message = await receive()
            if message["type"] == "http.request":
                total += len(message.get("body", b""))
                if total > self.max_body_bytes:
                    if not started and not refused:
                        refused = True
                        await self._too_large(send, None)
                    raise BodyTooLarge(total)
            return message

        async def guarded_send(message: Message) -> None:
            nonlocal started
            if refused:
                return  # the 413 went out: whatever the application answers to the broken body is dropped
            if message["type"] == "http.response.start":
                started = True
            await send(message)

        try:
            await self.app(scope, counted_receive, guarded_send)
        except BodyTooLarge:
            if not refused and not started:
                await self._too_large(send, None)
        except Exception:
            if not refused:
                raise
