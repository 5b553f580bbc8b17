"""One JSON shape for every error: ``{"detail": ..., "field": ..., "value": ..., "limit": ...}``.

Bad input is 422 and names the field, the value and the allowed range; a missing record 404; a request
the current state forbids 409; a missing or wrong token 401. Nothing the client sends may cause a 500.
"""

from __future__ import annotations

import logging
import math

from fastapi import FastAPI, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
from starlette.exceptions import HTTPException as StarletteHTTPException

from sim.errors import FieldError
from sim.isolator import IsolatorError
from sim.profiles import ProfileError

from .safety import LimitError
from .service import Conflict

log = logging.getLogger("isorig.api")

try:
    from sim.protocols import ProtocolError
except ImportError:  # pragma: no cover - sim/protocols.py not there yet
    class ProtocolError(ValueError):
        pass


class ApiError(Exception):
    def __init__(self, status: int, detail: str, field: str | None = None, value=None, limit: str | None = None,
                 headers: dict | None = None):
        super().__init__(detail)
        self.status = status
        self.detail = detail
        self.field = field
        self.value = value
        self.limit = limit
        self.headers = headers


def _jsonable(value):
    if value is None or isinstance(value, (bool, int, str)):
        return value if not isinstance(value, str) else value[:200]
    if isinstance(value, float):
        return value if math.isfinite(value) else str(value)
    if isinstance(value, (list, tuple)):
        return [_jsonable(v) for v in list(value)[:20]]
    if isinstance(value, dict):
        return {str(k)[:64]: _jsonable(v) for k, v in list(value.items())[:20]}
    return repr(value)[:200]


def error_response(status: int, detail: str, field=None, value=None, limit=None, errors=None, headers=None):
    body = {"detail": detail}
    if field is not None:
        body["field"] = field
        body["value"] = _jsonable(value)
    if limit is not None:
        body["limit"] = str(limit)
    if errors is not None:
        body["errors"] = errors
    return JSONResponse(body, status_code=status, headers=headers)


def _location(loc) -> str:
    parts = [str(p) for p in loc if p not in ("body", "query", "path")]
    out = ""
    for p in parts:
        out += f"[{p}]" if p.isdigit() else (f".{p}" if out else p)
    return out or "body"


# what each JSON type error asks for: a number is a JSON number, never a string or a boolean
_TYPE_ASKED = {"float_type": ("must be a number (a JSON integer or decimal, e.g. 100 or 2.5)", "a JSON number"),
               "float_parsing": ("must be a number (a JSON integer or decimal, e.g. 100 or 2.5)", "a JSON number"),
               "int_type": ("must be a whole number (a JSON integer, e.g. 3)", "a JSON integer"),
               "int_parsing": ("must be a whole number (a JSON integer, e.g. 3)", "a JSON integer"),
               "int_from_float": ("must be a whole number (a JSON integer, e.g. 3)", "a JSON integer"),
               "bool_type": ("must be true or false", "true or false"),
               "bool_parsing": ("must be true or false", "true or false")}


def _json_kind(value) -> str:
    if value is None:
        return "null"
    if isinstance(value, bool):
        return str(value).lower()
    if isinstance(value, str):
        return f"the string {_jsonable(value)!r}"
    if isinstance(value, (list, tuple)):
        return "a list"
    if isinstance(value, dict):
        return "an object"
    return repr(_jsonable(value))


def _wrong_type(kind: str, value) -> tuple[str, str] | None:
    """(message, what is allowed) for a value of the wrong JSON type, else None."""
    asked = _TYPE_ASKED.get(kind)
    if asked is None:
        return None
    return f"{asked[0]}, not {_json_kind(value)}", asked[1]


def install(app: FastAPI) -> None:
    @app.exception_handler(ApiError)
    async def _api_error(_request: Request, exc: ApiError):
        return error_response(exc.status, exc.detail, exc.field, exc.value, exc.limit, headers=exc.headers)

    @app.exception_handler(ProfileError)
    async def _profile_error(_request: Request, exc: ProfileError):
        field = exc.field if exc.field in ("supply_bar", "vertical_load_n") else f"profile.{exc.field}"
        return error_response(422, str(exc), field, exc.value, exc.limit)

    @app.exception_handler(FieldError)  # any other input refused with its field (e.g. a controller option)
    async def _field_error(_request: Request, exc: FieldError):
        return error_response(422, str(exc), exc.field, exc.value, exc.limit)

    @app.exception_handler(LimitError)
    async def _limit_error(_request: Request, exc: LimitError):
        return error_response(422, str(exc), exc.field, exc.value, exc.limit)

    @app.exception_handler(IsolatorError)
    async def _isolator_error(_request: Request, exc: IsolatorError):
        return error_response(422, str(exc), "isolator")

    @app.exception_handler(ProtocolError)
    async def _protocol_error(_request: Request, exc: ProtocolError):
        field = getattr(exc, "field", None) or "profile.protocol"
        field = field if field.startswith("profile") else f"profile.protocol.{field}"
        return error_response(422, str(exc), field, getattr(exc, "value", None), getattr(exc, "limit", None))

    @app.exception_handler(Conflict)
    async def _conflict(_request: Request, exc: Conflict):
        return error_response(409, str(exc))

    @app.exception_handler(RequestValidationError)
    async def _validation(_request: Request, exc: RequestValidationError):
        errors, said = [], []
        for e in exc.errors():
            field = _location(e.get("loc", ()))
            item = {"field": field, "message": e.get("msg", "invalid"), "value": _jsonable(e.get("input"))}
            ctx = e.get("ctx") or {}
            cause = ctx.get("error")
            if isinstance(cause, FieldError):  # a range checked in the schema (backend.schemas): its own words
                item["message"], item["limit"] = str(cause), str(cause.limit)
                said.append(str(cause) if field.endswith(cause.field) else f"{field}: {cause}")
                errors.append(item)
                continue
            wrong_type = _wrong_type(e.get("type", ""), e.get("input"))
            if wrong_type is not None:  # "100" or true where a number is asked (the models are strict)
                item["message"], item["limit"] = wrong_type
                said.append(f"{field}: {item['message']}")
                errors.append(item)
                continue
            if ctx:
                item["limit"] = ", ".join(f"{k} {_jsonable(v)}" for k, v in ctx.items() if k != "error")
            said.append(f"{field}: {item['message']} (got {item['value']!r})")
            errors.append(item)
        first = errors[0] if errors else {"field": "body", "message": "invalid request", "value": None}
        detail = "; ".join(said[:5]) or "invalid request"
        return error_response(422, detail, first["field"], first.get("value"), first.get("limit"), errors=errors)

    @app.exception_handler(StarletteHTTPException)
    async def _http(_request: Request, exc: StarletteHTTPException):
        detail = exc.detail if isinstance(exc.detail, str) else str(exc.detail)
        return error_response(exc.status_code, detail, headers=getattr(exc, "headers", None))

    @app.exception_handler(Exception)
    async def _unexpected(request: Request, exc: Exception):
        log.exception("unexpected error on %s %s", request.method, request.url.path)
        return error_response(500, f"internal error ({type(exc).__name__}); the service log has the details")
