"""The data a report is made of: a bundle (record, samples, cycles, events) and what its record says.

A bundle is anything with the attributes of ``backend.store.TestBundle``; ``bundle_from_csv`` builds a
``ReportBundle`` from a CSV record (e.g. ``isorig simulate``'s timeseries.csv, with its summary.json when it sits
beside it). ``isolator_of``, ``protocol_of`` and ``limit_trips`` read the test's conditions and events from a
record; ``num`` and ``clean_json`` turn values into what a report shows (no NaN: None).
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path

import numpy as np

from sim.samples import RECORD_FIELDS, SAMPLE_FIELDS, Samples

UNREPORTED_COLUMNS = ("model_m", "load_pressure_pa")  # in the samples, but neither the PDF nor the JSON shows them
ESTIMATE_COLUMNS = ("ar_hat", "ay_hat", "as_hat")  # adaptive estimates: the report shows their final values


@dataclass
class ReportBundle:
    """The same shape as backend.store.TestBundle, for records that do not come from the store."""

    record: dict
    samples: np.ndarray
    cycles: list[dict] = field(default_factory=list)
    events: list[dict] = field(default_factory=list)


def bundle_from_csv(path, summary_path=None, isolator=None, supply_bar: float | None = None,
                    protocol=None, meta: dict | None = None, all_columns: bool = True) -> ReportBundle:
    """A bundle from a CSV record (columns time_s, displacement_m, force_n required; target_m, voltage_v,
    model_m, ar_hat, ay_hat, as_hat, load_pressure_pa used when present).

    ``summary_path`` (default: summary.json beside the CSV, if any) supplies the scenario that
    ``isorig simulate`` ran: isolator, supply pressure, profile and controller; cycles are then split by the
    command's phase. ``isolator`` (name, dict or Isolator), ``supply_bar`` and ``protocol`` (name, path or
    Protocol) override it. ``all_columns=False`` reads only what a report shows: model_m and load_pressure_pa
    stay NaN, and the adaptive estimates (whose final values the report shows) are read from the last rows
    only, NaN before them (0.9 s less for 10 minutes; their other cells are then not checked). Raises
    sim.metrics.RecordError (a ValueError) for a malformed CSV.
    """
    from sim.isolator import Isolator, isolator_from_dict, load_isolator
    from sim.metrics import cycle_metrics, profile_cycle_starts_s, read_csv_columns
    from sim.protocols import Protocol, load_protocol

    path = Path(path)
    optional = [c for c in RECORD_FIELDS if c not in ("time_s", "displacement_m", "force_n")
                and (all_columns or c not in UNREPORTED_COLUMNS + ESTIMATE_COLUMNS)]
    cols = read_csv_columns(path, optional=optional)
    n = cols["time_s"].size
    if not all_columns:
        final = _final_estimates(path, n)
        if final is None:  # not settled by the last rows: read their whole columns (and check every cell)
            cols.update(read_csv_columns(path, required=(), optional=ESTIMATE_COLUMNS, min_rows=0))
        else:
            cols.update(final)
    # column by column into a column-major array: contiguous copies, and no NaN fill of 67 MB to overwrite
    array = np.empty((len(SAMPLE_FIELDS), n)).T
    for j, name in enumerate(SAMPLE_FIELDS):
        array[:, j] = cols[name] if name in cols else np.nan
    samples = Samples(array)

    summary = None
    summary_file = Path(summary_path) if summary_path else path.with_name("summary.json")
    if summary_file.exists():
        try:
            summary = json.loads(summary_file.read_text())
        except (OSError, json.JSONDecodeError) as exc:
            if summary_path:
                raise ValueError(f"cannot read the summary {summary_file}: {exc}") from None
    scenario = (summary or {}).get("scenario") or {}

    iso = None
    if isinstance(isolator, Isolator):
        iso = isolator
    elif isinstance(isolator, dict):
        iso = isolator_from_dict(isolator)
    elif isolator:
        iso = load_isolator(isolator)
    elif isinstance(scenario.get("isolator"), dict):
        iso = isolator_from_dict(scenario["isolator"])
    proto = protocol if isinstance(protocol, Protocol) or protocol is None else load_protocol(protocol)

    blocks = None
    if proto is not None:
        blocks = proto.blocks
    elif scenario.get("profile"):
        from sim.profiles import SineProfile

        blocks = [SineProfile(b["amplitude_m"], b["frequency_hz"], int(b["cycles"]), int(b["taper_cycles"]),
                              b.get("offset_m", 0.0)) for b in scenario["profile"]]
    t, d, f = cols["time_s"], cols["displacement_m"], cols["force_n"]
    if blocks:
        starts, end = profile_cycle_starts_s(blocks)
        cycles = cycle_metrics(t, d, f, starts, end)
    else:
        cycles = cycle_metrics(t, d, f)
    for c in cycles:
        j1 = min(c["i_end"] + 1, n)
        c["displacement_m"] = d[c["i_start"]:j1]
        c["force_n"] = f[c["i_start"]:j1]

    if proto is not None:
        profile = {"kind": "protocol", "protocol": proto.to_dict()}
    elif blocks:
        profile = blocks[0].to_dict() if len(blocks) == 1 else {"kind": "blocks",
                                                                "blocks": [b.to_dict() for b in blocks]}
    else:
        profile = None
    stat = path.stat()
    record = {
        "id": None,
        "label": path.name,
        "source": str(path),
        "status": "recorded",
        "created_at": datetime.fromtimestamp(stat.st_mtime, UTC).isoformat(),
        "isolator": iso.name if iso else None,
        "supply_bar": supply_bar if supply_bar is not None else scenario.get("supply_bar"),
        "controller": scenario.get("controller"),
        "profile": profile,
        "duration_s": float(t[-1] - t[0]) if n else 0.0,
        "samples_stored": n,
        "scenario": {**scenario, **({"isolator": iso.to_dict()} if iso else {})},
        "summary": {k: v for k, v in (summary or {}).items() if k not in ("scenario", "cycles")},
        **(meta or {}),
    }
    return ReportBundle(record=record, samples=samples, cycles=cycles, events=[])


def _final_estimates(path: Path, n_rows: int, tail_bytes: int = 1 << 16) -> dict[str, np.ndarray] | None:
    """The adaptive estimates over the last rows of a CSV record (about 500), NaN before: the report shows only
    their last finite values. Columns absent, or empty in the first data row, are left out, as
    sim.metrics.read_csv_columns leaves them out. None when the last rows do not settle it (a cell that is not
    a number, a short or blank row, no finite value): the caller then reads the whole columns."""
    from sim.metrics import csv_header_names

    with open(path, "rb") as fh:
        header = fh.readline().decode("utf-8", "replace")
        start = fh.tell()  # the first data row: a tail that reaches it holds every row
        first = fh.readline().decode("utf-8", "replace").rstrip("\r\n").split(",")
        size = fh.seek(0, 2)
        fh.seek(max(start, size - tail_bytes))
        at_start = fh.tell() == start
        tail = fh.read().decode("utf-8", "replace").split("\n")
    names = csv_header_names(header)
    wanted = {c: names.index(c) for c in ESTIMATE_COLUMNS
              if c in names and names.index(c) < len(first) and first[names.index(c)].strip()}
    lines = [line.rstrip("\r") for line in (tail if at_start else tail[1:])]  # the first one may be cut
    if lines and not lines[-1]:
        lines.pop()  # the file's last newline
    if not lines or any(not line.strip() for line in lines) or len(lines) > n_rows or \
            (at_start and len(lines) != n_rows):
        return None
    out = {}
    for name, j in wanted.items():
        values = np.full(n_rows, np.nan)
        for k, line in enumerate(lines, start=n_rows - len(lines)):
            cells = line.split(",")
            cell = cells[j].strip() if j < len(cells) else None
            if cell is None or "_" in cell:
                return None
            try:
                values[k] = float(cell) if cell else np.nan
            except ValueError:
                return None
        if not np.isfinite(values).any():
            return None
        out[name] = values
    return out


def num(x):
    return x if isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x) else None


def protocol_of(record: dict):
    """The protocol a test ran, or None for a plain sine (or if it cannot be rebuilt; then a note)."""
    profile = record.get("profile")
    if not isinstance(profile, dict) or profile.get("kind") != "protocol":
        return None, None
    try:
        from sim.protocols import profile_from_spec

        _blocks, protocol = profile_from_spec(profile)
        return protocol, None
    except (ImportError, ValueError) as exc:
        return None, f"the test's protocol cannot be rebuilt: {exc}"


def isolator_of(record: dict):
    from sim.isolator import PRESETS, isolator_from_dict

    scenario = record.get("scenario") or {}
    if isinstance(scenario.get("isolator"), dict):
        try:
            return isolator_from_dict(scenario["isolator"])
        except ValueError:
            pass
    name = record.get("isolator")
    return PRESETS.get(name) if isinstance(name, str) else None


def limit_trips(events: list[dict]) -> list[dict]:
    return [e for e in events if e.get("kind") == "limit_trip"]


def clean_json(value):
    """A value ready for strict JSON: NaN and infinities become None, numpy values Python ones."""
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, np.generic):
        return clean_json(value.item())
    if isinstance(value, np.ndarray):
        return [clean_json(v) for v in value.tolist()]
    if isinstance(value, dict):
        return {k: clean_json(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [clean_json(v) for v in value]
    return value
