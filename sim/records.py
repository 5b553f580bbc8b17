"""Sample records as CSV: the `isorig simulate` format, shared by the backend's data.csv."""

from __future__ import annotations

import io

import numpy as np

from .samples import RECORD_FIELDS


def samples_to_csv(samples, header: bool = True) -> str:
    """CSV text of the record fields (``RECORD_FIELDS``) of a ``Samples``; NaN (no such quantity for this
    controller) becomes an empty cell."""
    buf = io.StringIO()
    if header:
        buf.write(",".join(RECORD_FIELDS) + "\n")
    block = samples.select(RECORD_FIELDS)
    if block.size:
        np.savetxt(buf, block, fmt="%.9g", delimiter=",")
    text = buf.getvalue()
    return text.replace("nan", "")


def write_csv(path, samples) -> None:
    with open(path, "w", newline="") as fh:
        fh.write(samples_to_csv(samples))
