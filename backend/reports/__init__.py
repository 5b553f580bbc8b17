"""Test reports: a printable A4 PDF (matplotlib) and a JSON of all metrics, from a store bundle or a CSV.

``render_report_pdf(bundle, out)`` and ``report_json(bundle)`` take anything with the attributes of
``backend.store.TestBundle`` (``record``, ``samples``, ``cycles``, ``events``); ``bundle_from_csv`` builds one
from a CSV record (e.g. ``isorig simulate``'s timeseries.csv, with its summary.json when it sits beside it).
Numerics come from sim/ (metrics, protocols, identification); nothing is recomputed here that sim/ provides.
Layout and choices: docs/reports.md.

One job per module:

- ``data``: the bundle (``ReportBundle``, ``bundle_from_csv``) and what its record says (isolator, protocol,
  limit trips), values made fit for JSON (``clean_json``);
- ``identification``: the Bouc-Wen fit on the first minute of the record (``identification_task`` and
  ``run_identification`` can run in another process);
- ``content``: what the report says, for the PDF and the JSON (``report_json``, ``controller_state``,
  ``tracking``, ``acceptance``, ``earthquake_figures``: the J criteria and the reference of a history or hybrid
  test);
- ``layout``: page size, title and footer, number formatting, fixed-pitch monospace lines;
- ``figures``: the plotted pages (loops, time histories, detail) and ``plot_style``;
- ``header``: the header page(s) with the verdict and the identified Bouc-Wen parameters;
- ``tables``: the per-cycle table and the verdicts and events pages;
- ``earthquake``: the pages of a history or hybrid test (criteria and overlay; the structure and its reference);
- ``document``: the PDF (``render_report_pdf``, ``report_pdf_bytes``): which pages, in which order, "page N of M";
- ``lab``: the issuing lab's header (``lab_header``: name, address, logo; the settings ``lab_*``);
- ``export``: the whole test as one zip (``write_bundle_zip``, ``bundle_zip_bytes``): record, report.json, samples
  and cycles as CSV, the PDF.

Nothing here imports matplotlib until a PDF is drawn.
"""

from .content import acceptance, controller_state, earthquake_figures, headline, report_json, tracking
from .data import ESTIMATE_COLUMNS, UNREPORTED_COLUMNS, ReportBundle, bundle_from_csv, clean_json, event_text, run_of
from .document import render_report_pdf, report_pdf_bytes
from .export import bundle_zip_bytes, cycles_csv, samples_csv, write_bundle_zip
from .figures import DETAIL_WINDOW_S, LOOP_POINTS, MAX_LOOPS, PLOT_POINTS, plot_style
from .header import MAX_HEADER_LEVELS, MAX_HEADER_RULES
from .identification import (
    BOUC_WEN_FIELDS,
    IDENTIFY_FIT_POINTS,
    IDENTIFY_MAX_SAMPLES,
    identification_task,
    identified_bouc_wen,
    run_identification,
)
from .lab import LabHeader, lab_header
from .layout import A4_PORTRAIT_IN
from .tables import TABLE_HEAD, TABLE_NOTE, TABLE_ROWS, TABLE_UNITS

__all__ = [
    "A4_PORTRAIT_IN", "BOUC_WEN_FIELDS", "DETAIL_WINDOW_S", "ESTIMATE_COLUMNS", "IDENTIFY_FIT_POINTS",
    "IDENTIFY_MAX_SAMPLES", "LOOP_POINTS", "MAX_HEADER_LEVELS", "MAX_HEADER_RULES", "MAX_LOOPS", "PLOT_POINTS",
    "TABLE_HEAD", "TABLE_NOTE", "TABLE_ROWS", "TABLE_UNITS", "UNREPORTED_COLUMNS",
    "LabHeader", "ReportBundle", "acceptance", "bundle_from_csv", "bundle_zip_bytes", "clean_json",
    "controller_state", "cycles_csv", "earthquake_figures", "event_text", "headline", "identification_task",
    "identified_bouc_wen", "lab_header", "plot_style", "render_report_pdf", "report_json", "report_pdf_bytes",
    "run_identification", "run_of", "samples_csv", "tracking", "write_bundle_zip",
]
