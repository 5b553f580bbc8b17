"""Where numba keeps compiled code: a folder keyed by a fingerprint of every source file of sim/.

numba invalidates a cached function only when the file that defines it changes. The engine's loop
(sim.engine.run_periods) inlines the controllers and the rig from other files, so a change there would
silently run stale machine code. Keying the whole cache folder by the sources of the package makes any
change recompile everything once, and never mixes old and new code.
"""

from __future__ import annotations

import hashlib
import os
from pathlib import Path

PACKAGE_DIR = Path(__file__).resolve().parent
#: compiled code of sim/ inlines the foreign rigs' physics too (sim.foreign_plant): its sources count as well
FOREIGN_RIGS_DIR = PACKAGE_DIR.parent / "foreign_rigs"


def source_fingerprint(root: Path = PACKAGE_DIR) -> str:
    """SHA-1 of the relative paths and contents of every .py file below root (and, for sim/, of the foreign
    rigs' physics) (12 hex digits)."""
    digest = hashlib.sha1()
    roots = [root] + ([FOREIGN_RIGS_DIR] if root == PACKAGE_DIR and FOREIGN_RIGS_DIR.is_dir() else [])
    for base in roots:
        for path in sorted(base.rglob("*.py")):
            digest.update(str(path.relative_to(base.parent)).encode())
            digest.update(path.read_bytes())
    return digest.hexdigest()[:12]


def cache_dir(fingerprint: str) -> Path:
    base = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache")
    return base / "isorig" / f"numba-{fingerprint}"


def configure() -> None:
    """Point numba's cache at the fingerprinted folder, unless NUMBA_CACHE_DIR is set by the user."""
    if os.environ.get("NUMBA_CACHE_DIR"):
        return
    folder = str(cache_dir(source_fingerprint()))
    os.environ["NUMBA_CACHE_DIR"] = folder  # inherited by worker processes
    import sys

    config = sys.modules.get("numba.core.config")
    if config is not None:  # numba imported before sim: its config has read the environment already
        config.CACHE_DIR = folder
