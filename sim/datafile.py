"""Reading a description file that is JSON or TOML (rig files, campaign files): one place for the
refusals (unreadable, not valid JSON or TOML), each a FieldError of the caller's kind."""

from __future__ import annotations

import json
import tomllib
from pathlib import Path

from .errors import FieldError


def load_mapping(path: str | Path, what: str, field: str, error: type[FieldError] = FieldError) -> dict:
    """The contents of ``path`` (``.toml`` by its suffix, JSON otherwise); ``what`` names the file in messages
    ("rig file"), ``field`` is the refusal's field, ``error`` its class."""
    path = Path(path)
    try:
        text = path.read_text()
    except (OSError, UnicodeDecodeError) as exc:
        reason = exc.strerror if isinstance(exc, OSError) else "not a text file"
        raise error(field, str(path), "a readable .json or .toml file",
                    f"cannot read the {what} {path}: {reason}") from None
    toml = path.suffix.lower() == ".toml"
    try:
        return tomllib.loads(text) if toml else json.loads(text)
    except (json.JSONDecodeError, tomllib.TOMLDecodeError) as exc:
        raise error(field, str(path), "valid JSON or TOML",
                    f"the {what} {path} is not valid {'TOML' if toml else 'JSON'}: {exc}") from None
