"""The whole test as one zip a lab can archive or hand on: the record, report.json, the samples and the cycles as
CSV (SI units, the unit in every column name) and the PDF report, with a README that says what each file and
column is and the SHA-256 of each file.

``write_bundle_zip(out, bundle, report, pdf)`` writes it from what a report has made already (the CLI's
``isorig report ... --bundle FILE.zip``); ``bundle_zip_bytes(bundle)`` makes everything (the service's
``GET /api/tests/{id}/bundle.zip``).
"""

from __future__ import annotations

import hashlib
import io
import json
import zipfile

import numpy as np

from sim.samples import RECORD_FIELDS

from .data import clean_json

# the formats of data.csv (backend.api.tests.CSV_FORMATS): stored samples keep 7 significant digits
SAMPLE_FORMATS = ["%.9g"] + ["%.7g"] * (len(RECORD_FIELDS) - 1)
CYCLE_COLUMNS = ("cycle", "block", "phase", "in_headline", "t_start_s", "t_end_s", "d_max_m", "d_min_m", "f_max_n",
                 "f_min_n", "k_eff_n_per_m", "edc_j", "xi_eff", "qd_n", "kd_n_per_m", "f_peak_max_n", "f_peak_min_n",
                 "closure")
PROTOCOL_COLUMNS = ("level", "level_cycle", "judged")
SAMPLE_CHUNK_ROWS = 50_000


def samples_csv(samples, controller: str | None = None) -> bytes:
    """The samples' record fields as CSV, the columns, header and number formats of data.csv (the header labelled
    for the test's ``controller``: sim.records.column_labels; NaN: an empty cell)."""
    from sim.records import column_labels

    buf = io.StringIO()
    buf.write(",".join(column_labels(controller)) + "\n")
    n = len(samples)
    for i in range(0, n, SAMPLE_CHUNK_ROWS):
        block = samples[i:i + SAMPLE_CHUNK_ROWS].select(RECORD_FIELDS)
        part = io.StringIO()
        np.savetxt(part, block, fmt=SAMPLE_FORMATS, delimiter=",")
        buf.write(part.getvalue().replace("nan", ""))
    return buf.getvalue().encode()


def cycles_csv(cycles: list[dict], protocol=None) -> bytes:
    """One row per cycle: number, block, phase (taper_in, steady, taper_out, ramp_out), whether it is in the
    headline figures (steady only), time span and loop metrics in SI units; for a protocol its level, test cycle
    and whether the protocol judges it."""
    plan = {p["cycle"]: p for p in protocol.cycle_plan()} if protocol is not None else None
    columns = CYCLE_COLUMNS + (PROTOCOL_COLUMNS if plan is not None else ())
    lines = [",".join(columns)]
    for c in cycles:
        phase = c.get("phase")
        row = {**c, "phase": phase or "", "in_headline": int((phase or "steady") == "steady")}
        if plan is not None:
            p = plan.get(c.get("cycle"), {})
            row.update(level=p.get("level"), level_cycle=p.get("level_cycle"),
                       judged=int(bool(p.get("test"))) if p else None)
        lines.append(",".join(_cell(row.get(k)) for k in columns))
    return ("\n".join(lines) + "\n").encode()


def _cell(value) -> str:
    if value is None:
        return ""
    if isinstance(value, bool):
        return str(int(value))
    if isinstance(value, (int, np.integer)):
        return str(int(value))
    if isinstance(value, (float, np.floating)):
        return "" if not np.isfinite(value) else f"{float(value):.9g}"
    text = str(value)
    return f'"{text}"' if "," in text or '"' in text else text


def _readme(record: dict, report: dict, files: dict[str, bytes]) -> bytes:
    tid = record.get("id")
    ctrl = report.get("controller") or {}
    adapted = {a["column"]: f"{a['name']} [{a['unit']}]: {a['meaning']}" for a in ctrl.get("adapted") or []}
    lines = [f"isorig test bundle: {'test record ' + str(tid) if tid is not None else record.get('label', 'record')}",
             f"status: {record.get('status')}" + (f" ({record['reason']})" if record.get("reason") else ""),
             f"made: {report.get('generated_at')}", "",
             "files (SHA-256):"]
    descriptions = {
        "record.json": "the test record as GET /api/tests/{id} returns it (conditions, scenario, limits, summary, "
                       "events)",
        "report.json": "every number of the report: headline figures (steady cycles), cycles, acceptance with each "
                       "check, identification, events in words",
        "samples.csv": "every sample, one row per control period, SI units (the columns of data.csv)",
        "cycles.csv": "one row per cycle: phase, in_headline (1: steady, in the headline figures), loop metrics "
                      "(SI units)",
        "report.pdf": "the printable report",
    }
    for name, data in files.items():
        lines.append(f"  {hashlib.sha256(data).hexdigest()}  {name}  ({len(data)} bytes): {descriptions[name]}")
    lines += ["", "samples.csv columns: time_s [s], target_m [m] (empty: open loop), model_m [m], displacement_m [m], "
              "voltage_v [V], force_n [N], load_pressure_pa [Pa], ar_hat, ay_hat, as_hat (the controller's adapted "
              "parameters, below), measured_displacement_m [m] (what the controller read), flags (status bits, "
              "docs/architecture.md)"]
    for column in ("ar_hat", "ay_hat", "as_hat"):
        lines.append(f"  {column}: {adapted.get(column, 'not used by this controller (empty)')}")
    lines += ["cycles.csv columns: " + ", ".join(CYCLE_COLUMNS) + " (metrics: docs/metrics.md; a protocol adds "
              "level, level_cycle, judged)", ""]
    return "\n".join(lines).encode()


def write_bundle_zip(out, bundle, report: dict, pdf: bytes, protocol=None) -> list[str]:
    """Write the zip (a path or a binary file) from a report already made; returns the names in it."""
    record = bundle.record
    tid = record.get("id")
    folder = f"test-{tid}" if tid is not None else "record"
    files = {
        "record.json": json.dumps(clean_json(record), indent=1, allow_nan=False).encode(),
        "report.json": json.dumps(report, indent=1, allow_nan=False).encode(),
        "samples.csv": samples_csv(bundle.samples, record.get("controller")),
        "cycles.csv": cycles_csv(report.get("cycles") or [], protocol),
        "report.pdf": pdf,
    }
    files = {"README.txt": _readme(record, report, files), **files}
    with zipfile.ZipFile(out, "w", compression=zipfile.ZIP_DEFLATED, compresslevel=6) as zf:
        for name, data in files.items():
            # the PDF is compressed already; the samples (70 MB for 10 minutes) at level 1: 0.6 s instead of 3.9 s
            # at level 6, for a zip 13 % larger
            zf.writestr(f"{folder}/{name}", data, compress_type=zipfile.ZIP_STORED if name.endswith(".pdf")
                        else zipfile.ZIP_DEFLATED, compresslevel=1 if name == "samples.csv" else 6)
    return [f"{folder}/{name}" for name in files]


def bundle_zip_bytes(bundle, lab=None, identify: bool = True, pdf: bytes | None = None) -> bytes:
    """The zip of a test, everything made here (report.json, the PDF, the CSVs); ``pdf``: the report kept at an
    approval, zipped as it is instead of one made now."""
    import logging

    from .content import report_json
    from .data import protocol_of
    from .document import render_report_pdf
    from .lab import lab_header

    if lab is None:
        lab = lab_header()
    if lab.warning:
        logging.getLogger("isorig.reports").warning(lab.warning)
    report = report_json(bundle, identify=identify, lab=lab)
    if pdf is None:
        buf = io.BytesIO()
        render_report_pdf(bundle, buf, report=report, lab=lab)
        pdf = buf.getvalue()
    out = io.BytesIO()
    write_bundle_zip(out, bundle, report, pdf, protocol_of(bundle.record)[0])
    return out.getvalue()
