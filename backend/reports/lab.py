"""The lab that issues a report: its name, address and logo (the header band of page 1 and every footer).

``lab_header(name, address, logo_file)`` takes what it is given and the service's settings for the rest
(``lab_name``, ``lab_address``, ``lab_logo_file``: ``ISORIG_LAB_NAME`` ...). The logo is read here, once, with
Pillow (PNG, JPEG, ...) and made small (at most LOGO_MAX_PX on its long side: a 4000-pixel logo would cost the
PDF seconds and megabytes); a missing or unreadable file is one warning line (``LabHeader.warning``), never a
failed report.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

LOGO_MAX_PX = 400


@dataclass
class LabHeader:
    name: str = ""
    address: str = ""
    logo_file: str = ""
    logo: np.ndarray | None = None  # RGBA pixels, at most LOGO_MAX_PX on the long side
    warning: str | None = None  # why a logo file was given but is not shown
    units: str = "lab"  # the lab's units, what the PDF prints in: "lab" (mm, kN, kN/mm, bar) or "si" (backend.units)
    # the lab's tolerances against design values, by protocol name (backend.reports.design; absent: EN 15129's)
    tolerances: dict | None = None

    def to_json(self) -> dict:
        return {"name": self.name or None, "address": self.address or None, "logo_file": self.logo_file or None,
                "logo_shown": self.logo is not None, "logo_warning": self.warning, "units": self.units}

    @property
    def unit_system(self):
        """The report's units (backend.units.Units)."""
        from backend.units import Units

        return Units(self.units)

    @property
    def address_lines(self) -> list[str]:
        """The address as given, one line per line (newlines or ';' separate lines)."""
        lines = []
        for part in self.address.replace(";", "\n").splitlines():
            if part.strip():
                lines.append(part.strip())
        return lines


SETTINGS_ENV = {"name": "ISORIG_LAB_NAME", "address": "ISORIG_LAB_ADDRESS", "logo_file": "ISORIG_LAB_LOGO_FILE"}


def _settings_lab() -> dict:
    """The settings lab_name, lab_address, lab_logo_file as the environment gives them (the variables
    backend.settings.Settings reads, case-insensitive as there). Read here rather than through Settings(): that
    imports pydantic-settings and the rig drivers, 0.4 s on the critical path of a one-off ``isorig report``."""
    import os

    upper = {k.upper(): v for k, v in os.environ.items() if k.upper().startswith("ISORIG_LAB_")}
    return {key: upper.get(env, "") for key, env in SETTINGS_ENV.items()}


def lab_header(name: str | None = None, address: str | None = None, logo_file=None, settings=None,
               use_settings: bool = True, units: str | None = None) -> LabHeader:
    """The lab header: the values given, else those of ``settings`` (a backend.settings.Settings: the service's);
    without one, the environment's settings (``ISORIG_LAB_NAME``, ``ISORIG_LAB_ADDRESS``, ``ISORIG_LAB_LOGO_FILE``)
    unless ``use_settings`` is False. ``units``: the lab's units ("lab", the default, or "si")."""
    base: dict = {}
    if settings is not None:
        base = {"name": getattr(settings, "lab_name", ""), "address": getattr(settings, "lab_address", ""),
                "logo_file": str(getattr(settings, "lab_logo_file", "") or "")}
    elif use_settings and (name is None or address is None or logo_file is None):
        base = _settings_lab()
    lab = LabHeader(name=(name if name is not None else base.get("name")) or "",
                    address=(address if address is not None else base.get("address")) or "",
                    logo_file=str(logo_file if logo_file is not None else base.get("logo_file") or ""),
                    units="si" if units == "si" else "lab")
    if lab.logo_file:
        lab.logo, lab.warning = load_logo(lab.logo_file)
    return lab


def load_logo(path) -> tuple[np.ndarray | None, str | None]:
    """The logo's pixels (RGBA, at most LOGO_MAX_PX on the long side), or None and why not in one line."""
    try:
        from PIL import Image, UnidentifiedImageError
    except ImportError:
        return None, f"lab logo {path} not shown: Pillow is not installed"
    try:
        with Image.open(path) as img:
            img.thumbnail((LOGO_MAX_PX, LOGO_MAX_PX))
            pixels = np.asarray(img.convert("RGBA"))
    except FileNotFoundError:
        return None, f"lab logo {path} not shown: no such file"
    except IsADirectoryError:
        return None, f"lab logo {path} not shown: it is a folder"
    except PermissionError:
        return None, f"lab logo {path} not shown: permission denied"
    except UnidentifiedImageError:
        return None, f"lab logo {path} not shown: not an image Pillow can read (PNG, JPEG, ...)"
    except (OSError, ValueError, SyntaxError) as exc:  # truncated or corrupt image data
        return None, f"lab logo {path} not shown: unreadable ({type(exc).__name__}: {str(exc)[:120]})"
    if pixels.ndim != 3 or min(pixels.shape[:2]) < 1:
        return None, f"lab logo {path} not shown: empty image"
    return pixels, None
