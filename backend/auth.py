"""The operator token: bearer auth for every request that moves the rig or changes records.

Taken from ``ISORIG_OPERATOR_TOKEN``; otherwise generated at first start and saved owner-only (0600) in
the data directory (``<data_dir>/operator-token``), whose path the service prints.
"""

from __future__ import annotations

import os
import secrets
import stat

from fastapi import Request
from fastapi.security import HTTPAuthorizationCredentials, HTTPBearer

from .db import owner_only_dir
from .settings import Settings

bearer = HTTPBearer(auto_error=False, description="the operator token: Authorization: Bearer <token>")


def load_or_create_token(settings: Settings) -> tuple[str, str]:
    """(token, where it comes from)."""
    if settings.operator_token is not None and settings.operator_token.get_secret_value():
        return settings.operator_token.get_secret_value(), "the ISORIG_OPERATOR_TOKEN environment variable"
    path = settings.token_file
    owner_only_dir(path.parent)
    if path.exists():
        if stat.S_IMODE(path.stat().st_mode) & 0o077:
            os.chmod(path, 0o600)
        token = path.read_text().strip()
        if token:
            return token, str(path)
    token = secrets.token_urlsafe(32)
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
    with os.fdopen(fd, "w") as fh:
        fh.write(token + "\n")
    os.chmod(path, 0o600)
    return token, str(path)


def require_operator(request: Request, credentials: HTTPAuthorizationCredentials | None) -> str:
    """The actor name if the bearer token is right, else ApiError 401."""
    from .errors import ApiError

    source = request.app.state.token_source
    if credentials is None or credentials.scheme.lower() != "bearer":
        raise ApiError(401, "this action needs the operator token: send 'Authorization: Bearer <token>' "
                            f"(the token is in {source})", headers={"WWW-Authenticate": "Bearer"})
    if not secrets.compare_digest(credentials.credentials.encode(), request.app.state.token.encode()):
        raise ApiError(401, f"the operator token is wrong (the right one is in {source})",
                       headers={"WWW-Authenticate": "Bearer"})
    return "operator"
