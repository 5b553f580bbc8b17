"""``/api/ground-motions``: the synthetic ground motions the service ships, and a PEER ``.AT2`` file read for the
console (sim.history.parse_at2: one reader for the CLI and the console)."""

from __future__ import annotations

import functools
from dataclasses import asdict

from fastapi import APIRouter, Request
from pydantic import Field

from sim.ground_motion import GROUND_MOTIONS, synthetic_ground_motion
from sim.history import parse_at2

from ..schemas import ERROR_RESPONSES, StrictModel

router = APIRouter(tags=["ground motions"])

# the console's file limit (12 MB): a 200 000-sample record (the most a test takes inline) is about 3 MB of .AT2
# text; the request carrying it must stay under Settings.max_body_bytes (16 MiB)
MAX_AT2_CHARS = 12_000_000
MEASURED = ("pga_g", "pgv_m_per_s", "pgd_m", "significant_duration_s", "arias_intensity_m_per_s")


@functools.cache
def describe_ground_motion(name: str) -> dict:
    """A shipped ground motion: its parameters (seed included), the method, and what it measures."""
    time_s, _acc, info = synthetic_ground_motion(name)
    out = asdict(GROUND_MOTIONS[name])
    out["method"] = info["method"]
    out["samples"] = int(len(time_s))
    out["step_s"] = float(time_s[1] - time_s[0])
    out["measured"] = {key: float(info[key]) for key in MEASURED}
    return out


@router.get("/api/ground-motions", summary="The synthetic ground motions shipped with the service "
            "(docs/earthquake.md, section 5): parameters, seed, measured peaks")
def list_ground_motions() -> list[dict]:
    return [describe_ground_motion(name) for name in GROUND_MOTIONS]


class At2FileIn(StrictModel):
    """A PEER NGA ``.AT2`` file's text, as the browser read it."""

    filename: str = Field(max_length=255, description="the file's name, for the messages")
    text: str = Field(max_length=MAX_AT2_CHARS, description="the file's text (header, NPTS/DT line, values in g), "
                      f"at most {MAX_AT2_CHARS} characters")
    check_units: bool = Field(True, strict=True, description="false: accept a peak outside 0.005-3 g")


def read_at2(text: str, filename: str, check_units: bool) -> dict:
    """The answer of POST /api/ground-motions/read-at2 (a plain function: it runs in a check worker process)."""
    record = parse_at2(text, filename, check_units)
    values = record.values
    return {"filename": filename, "format": "PEER NGA .AT2", "header": list(record.header),
            "units": record.units, "units_how": record.units_how, "rows": int(len(values)), "dt_s": record.dt_s,
            "duration_s": float(record.time_s[-1]), "peak": float(abs(values).max()),
            "time_s": record.time_s.tolist(), "acceleration": values.tolist()}


@router.post("/api/ground-motions/read-at2", summary="Read a PEER NGA .AT2 file: its samples in the file's unit",
             responses={**ERROR_RESPONSES, 503: {"description": "busy: too many files being read at once "
                                                 "(Retry-After)"}})
def read_at2_file(body: At2FileIn, request: Request) -> dict:
    """The record as the console sends it back in a test (``time_s``, ``acceleration`` in ``units``), with what
    was read: the header lines, the step, the duration and the peak. A file that is not an ``.AT2`` record is a
    422 naming the line. Read in a check worker process (backend.checks: a few at a time, 503 beyond)."""
    return request.app.state.checks.run("read an .AT2 file", read_at2, body.text, body.filename, body.check_units)
