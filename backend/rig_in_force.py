"""Which rig file the service runs on, and how a commissioned one is made the service's rig.

At start the rig in force is ``--rig-file`` (``ISORIG_RIG_FILE``) when given, else the rig file last applied
from a commissioning to this rig (``<data dir>/rig-in-force.<rig name>.json`` names it: kept across a restart;
per rig, as two rigs' services may share a data directory), else the defaults of ``sim.rig``. ``apply`` writes
a commissioned rig file into ``<data dir>/rig-files/`` and makes it the one in force (the caller switches
``app.state``). A ``--rig-file`` given at start always wins at the next start: an
applied file is then in force until the service stops, and the answer says so.
"""

from __future__ import annotations

import json
import logging
from datetime import UTC, datetime
from pathlib import Path

from sim.rig import RigError
from sim.rigfile import RigDescription, load_rig_file, write_rig_file

from .settings import DEFAULT_RIG_NAME, Settings

log = logging.getLogger("isorig.rig")

LEGACY_POINTER = "rig-in-force.json"  # written before rigs were named: the default rig's
FOLDER = "rig-files"


def pointer_path(settings: Settings) -> Path:
    """The file that names the rig file applied to this service's rig (the name has no '/': settings.rig_name)."""
    return settings.data_dir / f"rig-in-force.{settings.rig_name}.json"


def _pointer_to_read(settings: Settings) -> Path:
    """This rig's pointer; for the default rig without one, the pointer written before rigs were named."""
    pointer = pointer_path(settings)
    legacy = settings.data_dir / LEGACY_POINTER
    if not pointer.exists() and settings.rig_name == DEFAULT_RIG_NAME and legacy.exists():
        return legacy
    return pointer


def rig_in_force(settings: Settings) -> tuple[RigDescription, dict]:
    """(the rig description the service runs on, where it comes from: ``how`` = ``rig_file`` (--rig-file),
    ``applied`` (a commissioning applied earlier; when, by whom, which commissioning) or ``defaults``)."""
    if settings.rig_file is not None:
        return settings.rig_description(), {"how": "rig_file", "words": f"--rig-file {settings.rig_file}"}
    pointer = _pointer_to_read(settings)
    if pointer.exists():
        try:
            applied = json.loads(pointer.read_text())
            described = load_rig_file(applied["path"])
            return described, {"how": "applied", **applied,
                               "words": f"applied from commissioning {applied.get('commissioning_id')} by "
                                        f"{applied.get('by')} at {applied.get('at')}"}
        except (OSError, ValueError, KeyError, TypeError, RigError) as exc:
            words = (f"the rig file applied earlier ({pointer} names it) cannot be read ({exc}): the service runs "
                     "on the defaults of sim.rig; commission the rig again or give --rig-file")
            log.warning(words)
            return settings.rig_description(), {"how": "defaults", "warning": words, "words": "sim.rig defaults"}
    return settings.rig_description(), {"how": "defaults", "words": "sim.rig defaults"}


def apply(settings: Settings, data: dict, commissioning_id: int, by: str) -> tuple[RigDescription, dict]:
    """Write the commissioned rig file ``data`` into the data directory and make it the rig in force (read
    back through the one rig file reader, so what is in force is what a restart reads). Returns the rig
    description and where it comes from (as ``rig_in_force``)."""
    folder = settings.data_dir / FOLDER
    folder.mkdir(parents=True, exist_ok=True)
    path = write_rig_file(folder / f"commissioned-{commissioning_id}.json", data)
    described = load_rig_file(path)
    applied = {"path": str(path), "commissioning_id": commissioning_id, "by": by,
               "at": datetime.now(UTC).isoformat(timespec="seconds")}
    tmp = pointer_path(settings).with_name(f".{pointer_path(settings).name}.tmp")
    tmp.write_text(json.dumps(applied, indent=2) + "\n")
    tmp.replace(pointer_path(settings))
    origin = {"how": "applied", **applied, "words": f"applied from commissioning {commissioning_id} by {by} at "
                                                   f"{applied['at']}"}
    if settings.rig_file is not None:
        origin["note"] = (f"in force until the service stops: it was started with --rig-file {settings.rig_file}, "
                          "which is the rig at the next start (start it without --rig-file to keep this one)")
    return described, origin
