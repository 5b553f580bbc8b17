"""Sample records as CSV: the `isorig simulate` format, shared by the backend's data.csv."""

from __future__ import annotations

import io

import numpy as np

from .engine import CSV_COLUMNS


def samples_to_csv(samples: np.ndarray, header: bool = True) -> str:
    """CSV text of the CSV columns; NaN (no such quantity for this controller) becomes an empty cell."""
    buf = io.StringIO()
    if header:
        buf.write(",".join(CSV_COLUMNS) + "\n")
    block = samples[:, : len(CSV_COLUMNS)]
    if block.size:
        np.savetxt(buf, block, fmt="%.9g", delimiter=",")
    text = buf.getvalue()
    return text.replace("nan", "")


def write_csv(path, samples: np.ndarray) -> None:
    with open(path, "w", newline="") as fh:
        fh.write(samples_to_csv(samples))
