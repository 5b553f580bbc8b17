"""A lab's own rig: a rig file (JSON or TOML) over the defaults, and NAME=VALUE changes from the command line.

A rig file holds any subset of the ``RigParameters`` field names with SI values (the unit is in each name:
``piston_area_m2``, ``dead_zone_v``, ``position_latency_s`` ...), optionally ``name``, ``description`` and
``commissioning`` (where the values came from: written by ``isorig identify rig``, sim.commission, with the
date, the conditions and the fit's quality; kept as it is and shown with the rig):

    {"name": "Lab B rig", "piston_area_m2": 0.02, "half_volume_m3": 0.006, "position_latency_s": 0.002}

Unnamed fields keep the defaults of ``sim.rig.DEFAULT_RIG``. Everything is checked at once: unknown names
(with the nearest known one), values that are not numbers, non-finite or out of range, and combinations that
cannot be a rig (a dead zone as wide as the command range, a minimum supply above the maximum). One clear
``RigError`` names the file, the parameter, the value and what is allowed.
"""

from __future__ import annotations

import difflib
import json
import math
from dataclasses import dataclass, fields
from pathlib import Path

from .datafile import load_mapping
from .errors import FieldError
from .rig import DEFAULT_RIG, RigError, RigParameters

RIG_FIELDS = tuple(f.name for f in fields(RigParameters))
TEXT_FIELDS = ("name", "description")
METADATA_FIELDS = (*TEXT_FIELDS, "commissioning")
MAX_COMMISSIONING_CHARS = 200_000  # a commissioning section is a summary, not a record


@dataclass(frozen=True)
class RigDescription:
    """A rig as a lab describes it: its parameters, a name, and where they came from."""

    parameters: RigParameters
    name: str = "isorig default rig (sim.rig)"
    description: str = ""
    source: str = "sim.rig defaults"
    #: how the values were measured (``isorig identify rig``), None for a rig file written by hand
    commissioning: dict | None = None

    def changed(self) -> dict:
        """The parameters that differ from the defaults."""
        return {f: getattr(self.parameters, f) for f in RIG_FIELDS
                if getattr(self.parameters, f) != getattr(DEFAULT_RIG, f)}

    def to_dict(self) -> dict:
        return {"name": self.name, "description": self.description, "source": self.source,
                "changed": self.changed(), "commissioning": commissioning_summary(self.commissioning)}


def commissioning_summary(commissioning: dict | None) -> dict | None:
    """What a page or a report says of a rig's commissioning: when, on what, how well the fit explained it."""
    if not commissioning:
        return None
    c = commissioning
    keys = ("date", "rig", "supply_pa", "vertical_load_n", "specimen", "rig_time_s", "trusted")
    out = {k: c.get(k) for k in keys if k in c}
    fit = c.get("fit") if isinstance(c.get("fit"), dict) else {}
    out.update({k: fit.get(k) for k in ("flow_r2", "force_r2", "velocity_nrmse") if k in fit})
    return out


def suggestion(name: str, allowed) -> str:
    """' (did you mean X?)' for the nearest allowed name (or one it begins), else ''."""
    close = difflib.get_close_matches(name, allowed, n=1) or [a for a in allowed if a.startswith(name)][:1]
    return f" (did you mean {close[0]}?)" if close else ""


def _unknown(name: str, where: str) -> RigError:
    hint = suggestion(name, RIG_FIELDS)
    return RigError(name, None, "a RigParameters field name", f"{where}: {name!r} is not a rig parameter{hint}; "
                    "see `GET /api/rig` or docs/drivers.md for the names (SI units in each name)")


def rig_from_mapping(data: dict, base: RigParameters = DEFAULT_RIG, where: str = "rig") -> RigParameters:
    """``base`` with the values of ``data`` (field names of RigParameters), checked."""
    if not isinstance(data, dict):
        raise RigError("rig", data, "an object of parameter names and values", f"{where}: not an object of "
                       "parameter names and values")
    changes = {}
    for key, value in data.items():
        if key in METADATA_FIELDS:
            continue
        if key not in RIG_FIELDS:
            raise _unknown(key, where)
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise RigError(key, value, "a number", f"{where}: {key} = {value!r} is not a number")
        changes[key] = float(value)
    rig = base.with_changes(**changes)
    try:
        rig.check()
    except RigError as exc:
        raise RigError(exc.field, exc.value, exc.limit, f"{where}: {exc}") from None
    return rig


def load_rig_file(path: str | Path, base: RigParameters = DEFAULT_RIG) -> RigDescription:
    """A rig file (``.json`` or ``.toml``) over ``base``."""
    path = Path(path)
    data = load_mapping(path, "rig file", "rig_file", RigError)
    parameters = rig_from_mapping(data, base, where=f"rig file {path}")
    name = data.get("name", path.stem)
    description = data.get("description", "")
    if not isinstance(name, str) or not isinstance(description, str):
        raise RigError("name", name, "text", f"rig file {path}: name and description must be text")
    commissioning = data.get("commissioning")
    if commissioning is not None and (not isinstance(commissioning, dict)
                                      or len(json.dumps(commissioning, default=str)) > MAX_COMMISSIONING_CHARS):
        raise RigError("commissioning", None, "an object (what isorig identify rig wrote)",
                       f"rig file {path}: commissioning must be an object of at most {MAX_COMMISSIONING_CHARS} "
                       "characters, as `isorig identify rig` writes it")
    return RigDescription(parameters, name[:100], description[:400], str(path), commissioning)


def rig_file_data(rig: RigParameters, name: str, description: str = "", commissioning: dict | None = None,
                  always: tuple[str, ...] = ()) -> dict:
    """A rig file's contents: the parameters that differ from the defaults (and those named in ``always``),
    with its name, description and commissioning."""
    data = {"name": name, "description": description}
    for f in RIG_FIELDS:
        value = getattr(rig, f)
        if f in always or value != getattr(DEFAULT_RIG, f):
            data[f] = value
    if commissioning is not None:
        data["commissioning"] = commissioning
    return data


def write_rig_file(path: str | Path, data: dict) -> Path:
    """Write a rig file (JSON) atomically: a temporary file beside it, renamed into place once complete."""
    path = Path(path)
    if path.suffix.lower() != ".json":
        raise RigError("out", str(path), "a .json file", f"a rig file is written as JSON: {path} must end in .json")
    tmp = path.with_name(f".{path.name}.tmp")
    tmp.write_text(json.dumps(data, indent=2, default=float) + "\n")
    tmp.replace(path)
    return path


def parse_assignment(text: str, allowed: tuple[str, ...] = RIG_FIELDS,
                     what: str = "rig parameter") -> tuple[str, float]:
    """``NAME=VALUE`` -> (name, value), the name one of ``allowed``, the value a finite number."""
    name, sep, raw = text.partition("=")
    name = name.strip()
    if not sep or not name:
        raise FieldError(what, text, "NAME=VALUE", f"{text!r} is not NAME=VALUE")
    if name not in allowed:
        raise FieldError(name, raw, ", ".join(allowed), f"{name!r} is not a {what}{suggestion(name, allowed)}")
    try:
        value = float(raw)
    except ValueError:
        raise FieldError(name, raw, "a number", f"{name} = {raw!r} is not a number") from None
    if not math.isfinite(value):
        raise FieldError(name, raw, "a finite number", f"{name} = {raw!r} is not a finite number")
    return name, value


def with_assignments(rig: RigParameters, assignments: list[str], where: str) -> RigParameters:
    """``rig`` with each ``NAME=VALUE`` of ``assignments`` applied, checked."""
    changes = dict(parse_assignment(a) for a in assignments)
    return rig_from_mapping(changes, rig, where) if changes else rig
