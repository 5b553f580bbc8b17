"""The PDF document: which pages, in which order, written with matplotlib's PdfPages.

``render_report_pdf`` assembles the pages of header.py, figures.py and tables.py. When the Bouc-Wen fit is made
elsewhere meanwhile (``identification=`` a callable), the header page that shows it is drawn last and moved
first: the PDF's page tree is reordered after matplotlib has written the file (``_pages_moved_first``).
"""

from __future__ import annotations

import io
import re

from .content import report_json
from .data import ReportBundle, isolator_of, protocol_of
from .figures import DETAIL_WINDOW_S, page_loops, page_time, page_time_detail, plot_style
from .header import header_pages, identification_block, page_header
from .layout import report_title
from .tables import pages_table, pages_verdicts_events


def render_report_pdf(bundle, out, meta: dict | None = None, report: dict | None = None,
                      identify: bool = True, identification=None) -> None:
    """Write the A4 report of a test to ``out`` (a path or a binary file object).

    Pages: header (lab, rig, operator, date, isolator, supply, protocol, controller with its final adapted
    parameters, overall verdict, identified Bouc-Wen parameters), loops and per-cycle K_eff/EDC, time histories
    (displacement and target, voltage, tracking error), the per-cycle table, verdicts, events and limit trips.
    ``meta`` (lab, rig, operator) fills in what the record does not hold; ``report`` (from report_json) saves
    computing the metrics twice; ``identify=False`` skips the Bouc-Wen fit. ``identification``, a function
    returning identified_bouc_wen's answer, lets the fit finish elsewhere meanwhile: the header page that shows
    it is then drawn last and put first (it replaces ``report["identification"]``).
    """
    import logging

    if meta:
        bundle = ReportBundle(record={**bundle.record, **{k: v for k, v in meta.items() if v}},
                              samples=bundle.samples, cycles=bundle.cycles, events=bundle.events)
    if report is None and identification is None:
        report = report_json(bundle, identify=identify)
    elif report is None:
        report = report_json(bundle, identify=False)
    plt = plot_style()
    # the core-font AFM files say "medium" where matplotlib asks for "normal": harmless, silence it
    font_log = logging.getLogger("matplotlib.font_manager")
    level = font_log.level
    font_log.setLevel(logging.ERROR)
    target = out if hasattr(out, "write") else open(out, "wb")
    try:
        if identification is None:
            _write_pages(target, plt, bundle, report)
        else:  # drawn into memory with the header last, then the header pages moved first
            buf = io.BytesIO()
            moved = _write_pages(buf, plt, bundle, report, identification)
            data = _pages_moved_first(buf.getvalue(), moved)
            if data is None:  # a page tree this code does not know: draw again in order (the fit is there now)
                buf = io.BytesIO()
                _write_pages(buf, plt, bundle, report)
                data = buf.getvalue()
            target.write(data)
    finally:
        font_log.setLevel(level)
        if target is not out:
            target.close()


def _write_pages(target, plt, bundle, report: dict, identification=None) -> int:
    """Every page, in order; with ``identification`` (a callable) the header page(s) are drawn last, when the fit
    is there, and their number is returned (0 otherwise) for _pages_moved_first."""
    from matplotlib.backends.backend_pdf import PdfPages

    record = bundle.record
    iso = isolator_of(record)
    protocol, _note = protocol_of(record)
    acc, trk, ctrl = report["acceptance"], report["tracking"], report["controller"]
    with PdfPages(target, metadata={"Title": report_title(record), "Creator": "isorig"}) as pdf:
        if identification is None:
            header = page_header(plt, bundle, ctrl, iso, protocol, acc, report["identification"], trk, 1)
            _save(plt, pdf, header)
        else:  # all but the Bouc-Wen table now; the table when the fit is there
            header, y = header_pages(plt, bundle, ctrl, iso, protocol, acc, trk, 1)
        figs = [page_loops(plt, bundle, protocol, len(header) + 1)]
        figs.append(page_time(plt, bundle, len(header) + len(figs) + 1))
        s = bundle.samples
        if len(s) > 1 and s["time_s"][-1] - s["time_s"][0] > 6 * DETAIL_WINDOW_S:
            figs.append(page_time_detail(plt, bundle, len(header) + len(figs) + 1))
        figs += pages_table(plt, bundle, acc, len(header) + len(figs) + 1, protocol)
        figs += pages_verdicts_events(plt, bundle, acc, len(header) + len(figs) + 1)
        _save(plt, pdf, figs)
        if identification is None:
            return 0
        report["identification"] = identification()
        identification_block(header[-1], y, report["identification"], record, len(header))
        _save(plt, pdf, header)
        return len(header)


def _save(plt, pdf, figs) -> None:
    for fig in figs:
        pdf.savefig(fig)
        plt.close(fig)


# The page tree's root as matplotlib writes it: << /Type /Pages /Kids [ 12 0 R 40 0 R ... ] /Count 15 >>
_PAGE_TREE = re.compile(rb"/Type\s*/Pages\s*/Kids\s*\[([^\]]*)\]\s*/Count\s+(\d+)")
_REFERENCE = re.compile(rb"\d+\s+\d+\s+R")


def _pages_moved_first(pdf: bytes, n: int) -> bytes | None:
    """The PDF with its last ``n`` pages moved first, or None if its page tree is not the one flat list of pages
    matplotlib writes (then nothing is changed).

    The order of the pages is the order of the /Kids array of the page tree's root. Its references are permuted in
    place, each separator kept where it was: the file keeps its length, so the cross-reference table (byte
    offsets of the objects) stays right. PdfPages has no public way to order pages other than as saved.
    """
    trees = list(_PAGE_TREE.finditer(pdf))
    if len(trees) != 1:
        return None
    tree = trees[0]
    kids = tree.group(1)
    refs = _REFERENCE.findall(kids)
    if len(refs) != int(tree.group(2)) or not 0 <= n <= len(refs):
        return None
    if n == 0:
        return pdf
    gaps = _REFERENCE.split(kids)  # the whitespace around the references: len(refs) + 1 pieces
    if any(gap.strip() for gap in gaps):
        return None
    order = refs[-n:] + refs[:-n]
    moved = gaps[0] + b"".join(ref + gap for ref, gap in zip(order, gaps[1:], strict=True))
    return pdf[:tree.start(1)] + moved + pdf[tree.end(1):]


def report_pdf_bytes(bundle, meta: dict | None = None, identify: bool = True) -> bytes:
    """The PDF as bytes (for an HTTP response)."""
    buf = io.BytesIO()
    render_report_pdf(bundle, buf, meta, identify=identify)
    return buf.getvalue()
