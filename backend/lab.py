"""The lab's settings in the database: name, address and logo for every report, the console's default units.

An admin sets them in the console (``PUT /api/lab``, ``PUT /api/lab/logo``). What the database holds wins; a
field it does not hold falls back to the service's settings (``ISORIG_LAB_NAME``, ``ISORIG_LAB_ADDRESS``,
``ISORIG_LAB_LOGO_FILE``), so a lab that configured them that way keeps its reports as they were.
"""

from __future__ import annotations

import base64
import binascii
import io

from sqlalchemy.orm import Session

from .models import LabSettings, utcnow

UNITS = ("lab", "si")
LOGO_MAX_BYTES = 1024 * 1024
LOGO_TYPES = {b"\x89PNG\r\n\x1a\n": "image/png", b"\xff\xd8\xff": "image/jpeg"}


class LabError(ValueError):
    """A lab setting that cannot be taken; the message says what is allowed."""

    def __init__(self, field: str, detail: str):
        super().__init__(detail)
        self.field = field


def row(session: Session) -> LabSettings | None:
    return session.get(LabSettings, 1)


def _row_for_update(session: Session) -> LabSettings:
    lab = row(session)
    if lab is None:
        lab = LabSettings(id=1, name="", address="", units="lab")
        session.add(lab)
    return lab


def describe(session: Session, settings) -> dict:
    """The lab as reports and the console use it, and where each value comes from."""
    lab = row(session)
    name = lab.name if lab is not None and lab.name else settings.lab_name
    address = lab.address if lab is not None and lab.address else settings.lab_address
    stored_logo = lab is not None and lab.logo is not None
    return {"name": name or "", "address": address or "", "units": lab.units if lab is not None else "lab",
            "logo": "stored" if stored_logo else ("file" if settings.lab_logo_file else None),
            "logo_type": lab.logo_type if stored_logo else None,
            "updated_at": lab.updated_at.isoformat() if lab is not None and lab.updated_at else None,
            "updated_by": lab.updated_by if lab is not None else None,
            "source": {"name": "database" if lab is not None and lab.name else ("environment" if name else None),
                       "address": "database" if lab is not None and lab.address else
                       ("environment" if address else None)}}


def update(session: Session, by: str, name: str | None, address: str | None, units: str | None) -> None:
    if units is not None and units not in UNITS:
        raise LabError("units", f"units must be one of {', '.join(UNITS)} (lab: mm, kN, kN/mm; si: m, N, N/m)")
    lab = _row_for_update(session)
    if name is not None:
        lab.name = name.strip()
    if address is not None:
        lab.address = address.strip()
    if units is not None:
        lab.units = units
    lab.updated_at, lab.updated_by = utcnow(), by


def set_logo(session: Session, by: str, data_base64: str | None) -> None:
    """Store a PNG or JPEG (at most LOGO_MAX_BYTES, checked by its first bytes and by Pillow), or remove it."""
    lab = _row_for_update(session)
    if data_base64 is None:
        lab.logo = lab.logo_type = None
    else:
        try:
            data = base64.b64decode(data_base64, validate=True)
        except (binascii.Error, ValueError):
            raise LabError("data_base64", "the logo is not valid base64") from None
        if len(data) > LOGO_MAX_BYTES:
            raise LabError("data_base64", f"the logo has {len(data)} bytes; at most {LOGO_MAX_BYTES} are taken")
        kind = next((t for magic, t in LOGO_TYPES.items() if data.startswith(magic)), None)
        if kind is None:
            raise LabError("data_base64", "the logo must be a PNG or JPEG image")
        from .reports.lab import load_logo

        pixels, why = load_logo(io.BytesIO(data))
        if pixels is None:
            raise LabError("data_base64", f"the logo cannot be read: {why.split(' not shown: ', 1)[-1]}")
        lab.logo, lab.logo_type = data, kind
    lab.updated_at, lab.updated_by = utcnow(), by


def header(session: Session, settings=None):
    """The report's lab header (backend.reports.lab.LabHeader) from the database, else the settings (None: the
    environment's, ``ISORIG_LAB_NAME`` ...), with the lab's units: reports print in them."""
    from .reports.lab import LabHeader, lab_header, load_logo

    lab = row(session)
    if lab is None:
        return lab_header(settings=settings)
    base = lab_header(name=lab.name or None, address=lab.address or None,
                      logo_file="" if lab.logo is not None else None, settings=settings, units=lab.units)
    if lab.logo is not None:
        pixels, why = load_logo(io.BytesIO(lab.logo))
        base = LabHeader(name=base.name, address=base.address, logo_file="(stored in the service)", logo=pixels,
                         warning=why and "the stored lab logo is not shown: unreadable", units=base.units)
    return base
