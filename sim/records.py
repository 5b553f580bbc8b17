"""Sample records as CSV: the `isorig simulate` format, shared by the backend's data.csv.

The columns ``model_m, ar_hat, ay_hat, as_hat`` are named after the paper's MRAC (the reference model y_m and its
adapted a_r_hat, a_y_hat, a_s_hat, eqs. 8, 18-20); another controller reports its own quantities there (its
``ADAPTED``, sim.controllers). The header says which: a column whose controller puts another quantity in it
reads ``KEY: NAME (UNIT)`` (the servo's ``as_hat: learned frequency (Hz)``), the key first, so that a reader
finds the column by its key (``column_key``; sim.metrics.csv_header_names); the MRAC's, and the empty columns
of a controller that adapts nothing (PID), keep the bare keys.
"""

from __future__ import annotations

import io

import numpy as np

from .samples import RECORD_FIELDS

LABEL_SEPARATOR = ": "  # KEY: NAME (UNIT); no comma, so that the header stays one plain CSV row


def declared_quantities(controller: str | None) -> dict:
    """column -> sim.controllers.Adapted of what ``controller`` reports in the columns named after the MRAC's
    quantities (model_m, ar_hat, ay_hat, as_hat); the commissioning's excitation among them. Empty for the
    MRAC itself, for a controller that adapts nothing and for an unknown one."""
    if not controller or controller == "mrac":
        return {}
    from .controllers import ADAPTED, excitation, mrac

    declared = {**ADAPTED, "excitation": excitation.ADAPTED}.get(controller, ())
    paper = {a.column: (a.name, a.unit) for a in mrac.ADAPTED}
    return {a.column: a for a in declared if paper.get(a.column) != (a.name, a.unit)}


def column_labels(controller: str | None, fields=RECORD_FIELDS) -> list[str]:
    """The header cells of ``fields`` for a record of ``controller``: the key, or ``KEY: NAME (UNIT)`` where the
    controller reports another quantity than the key names (``declared_quantities``)."""
    declared = declared_quantities(controller)
    return [f"{f}{LABEL_SEPARATOR}{declared[f].name} ({declared[f].unit})" if f in declared else f for f in fields]


def column_key(label: str) -> str:
    """The column key of a header cell (``as_hat: learned frequency (Hz)`` -> ``as_hat``)."""
    return label.split(LABEL_SEPARATOR, 1)[0].strip()


def samples_to_csv(samples, header: bool = True, controller: str | None = None) -> str:
    """CSV text of the record fields (``RECORD_FIELDS``) of a ``Samples``, the header labelled for ``controller``
    (``column_labels``); NaN (no such quantity for this controller) becomes an empty cell."""
    buf = io.StringIO()
    if header:
        buf.write(",".join(column_labels(controller)) + "\n")
    block = samples.select(RECORD_FIELDS)
    if block.size:
        np.savetxt(buf, block, fmt="%.9g", delimiter=",")
    text = buf.getvalue()
    return text.replace("nan", "")


def write_csv(path, samples, controller: str | None = None) -> None:
    with open(path, "w", newline="") as fh:
        fh.write(samples_to_csv(samples, controller=controller))
