"""Identification from records: what both identifications share (reading and checking measured records).

The identifications themselves live in ``sim.identify_steps`` (eq. 7 from step tests, section III of the
paper; Tables III-IV) and ``sim.identify_bouc_wen`` (eq. 4 from a force-displacement record).
"""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np

from .metrics import loadtxt_columns


class IdentificationError(ValueError):
    """A record cannot be identified: a missing column, a non-numeric cell, too few samples, bad time."""


def read_record_csv(path: str | Path, columns: tuple[str, ...], min_rows: int) -> dict[str, np.ndarray]:
    """The named columns of a CSV record as float arrays (other columns are ignored).

    Raises IdentificationError naming what is wrong: the file, a missing column (with those present),
    a non-numeric or empty cell (with its row and column), fewer than ``min_rows`` rows, or a ``time_s``
    column that is not strictly increasing.
    """
    path = Path(path)
    plain = _plain_columns(path, columns, min_rows)
    return plain if plain is not None else _careful_columns(path, columns, min_rows)


def _plain_columns(path: Path, columns: tuple[str, ...], min_rows: int) -> dict[str, np.ndarray] | None:
    """The columns by numpy's parser when the file is plain: the header names them, every cell used is a finite
    number, there are ``min_rows`` rows and time increases. None otherwise: _careful_columns then says what is
    wrong, with the row. (A 10-minute record: 0.7 s instead of 6.5 s; the same values, both round correctly.)"""
    try:
        with open(path, newline="") as fh:
            header = [h.strip() for h in next(csv.reader([fh.readline()]), [])]
        if not all(c in header for c in columns):
            return None
    except (OSError, UnicodeDecodeError, csv.Error):
        return None
    # no comment lines: the careful reader takes '#' as a bad cell
    data = loadtxt_columns(path, [header.index(c) for c in columns], comments=None, encoding=None)
    if data is None or data.shape[0] < min_rows or not np.isfinite(data).all():
        return None
    out = {name: np.ascontiguousarray(data[:, k]) for k, name in enumerate(columns)}
    if "time_s" in out and not np.all(np.diff(out["time_s"]) > 0.0):
        return None
    return out


def _careful_columns(path: Path, columns: tuple[str, ...], min_rows: int) -> dict[str, np.ndarray]:
    """read_record_csv cell by cell, naming the first thing that is wrong."""
    try:
        with open(path, newline="") as fh:
            rows = list(csv.reader(fh))
    except OSError as exc:
        raise IdentificationError(f"cannot read {path}: {exc.strerror}") from None
    except (UnicodeDecodeError, csv.Error) as exc:
        raise IdentificationError(f"{path} is not a readable CSV text file ({exc})") from None
    if not rows:
        raise IdentificationError(f"{path} is empty; expected a header with columns {', '.join(columns)}")
    header = [h.strip() for h in rows[0]]
    missing = [c for c in columns if c not in header]
    if missing:
        raise IdentificationError(
            f"{path} lacks column(s) {', '.join(missing)}; required: {', '.join(columns)}; "
            f"found: {', '.join(header) or '(none)'}")
    body = [r for r in rows[1:] if any(cell.strip() for cell in r)]
    if len(body) < min_rows:
        raise IdentificationError(f"{path} has {len(body)} data rows; at least {min_rows} are needed")
    out = {}
    for name in columns:
        j = header.index(name)
        values = np.empty(len(body))
        for i, row in enumerate(body):
            cell = row[j].strip() if j < len(row) else ""
            try:
                values[i] = float(cell)
            except ValueError:
                raise IdentificationError(
                    f"{path} row {i + 2}, column {name}: {cell!r} is not a number") from None
            if not np.isfinite(values[i]):
                raise IdentificationError(f"{path} row {i + 2}, column {name}: {cell!r} is not a finite number")
        out[name] = values
    if "time_s" in out:
        check_time(out["time_s"], str(path))
    return out


def check_time(time_s: np.ndarray, where: str = "record") -> None:
    """Raise IdentificationError unless time strictly increases."""
    steps = np.diff(time_s)
    bad = np.flatnonzero(steps <= 0.0)
    if bad.size:
        i = int(bad[0])
        raise IdentificationError(
            f"{where}: time_s must strictly increase, but row {i + 3} ({time_s[i + 1]:g} s) does not follow "
            f"row {i + 2} ({time_s[i]:g} s)")


def as_record(where: str, min_samples: int, **columns) -> list[np.ndarray]:
    """The columns (time_s first) as float arrays, checked: equal lengths, at least ``min_samples`` rows,
    all finite, time strictly increasing; IdentificationError says which rule failed."""
    arrays = [np.asarray(v, float) for v in columns.values()]
    names = list(columns)
    if len({a.size for a in arrays}) != 1:
        raise IdentificationError(f"{', '.join(names[:-1])} and {names[-1]} must have the same length")
    if arrays[0].size < min_samples:
        raise IdentificationError(f"a {where} needs at least {min_samples} samples, got {arrays[0].size}")
    if not all(np.all(np.isfinite(a)) for a in arrays):
        raise IdentificationError(f"the {where} contains non-finite values")
    check_time(arrays[0], where)
    return arrays
