"""The PDF document: which pages, in which order, written with matplotlib's PdfPages.

``render_report_pdf`` assembles the pages of header.py, figures.py and tables.py. When the Bouc-Wen fit is made
elsewhere meanwhile (``identification=`` a callable), the header page that shows it is drawn last and moved
first: the PDF's page tree is reordered after matplotlib has written the file (``_pages_moved_first``).
"""

from __future__ import annotations

import io
import re

from ..units import LAB
from .content import earthquake_figures, report_json
from .data import ReportBundle, isolator_of, protocol_of
from .earthquake import pages_earthquake
from .figures import DETAIL_WINDOW_S, page_loops, page_time, page_time_detail, plot_style
from .header import header_pages, identification_block, page_header
from .lab import lab_header
from .layout import footer, report_title
from .tables import pages_table, pages_verdicts_events


def render_report_pdf(bundle, out, meta: dict | None = None, report: dict | None = None,
                      identify: bool = True, identification=None, lab=None) -> None:
    """Write the A4 report of a test to ``out`` (a path or a binary file object).

    Pages: header (the lab, the status banner of a test that did not run to its end, specimen, operator, dates,
    duration and cycles run, conditions, headline figures from the steady cycles, the acceptance verdict, tracking,
    limit trips, notes, rig and sensors, controller with every option and its adapted parameters, identified
    Bouc-Wen parameters), loops and per-cycle K_eff/EDC (scaled to the steady cycles, tapers marked), time
    histories (displacement and target, voltage, tracking error), the per-cycle table, the protocol with every
    check, the events and the approval block; "page N of M" on every page. A history or hybrid test (no cycles)
    has, instead of the loops and the table, its J criteria with the command against the measurement and, for a
    hybrid test, the structure beside its full-numerical reference (earthquake.py).
    ``meta`` (rig, operator; lab_name, lab_address, lab_logo_file) fills in what the record does not hold;
    ``lab`` (lab.LabHeader) is the lab already resolved (default: from ``meta`` and the settings); ``report``
    (from report_json) saves computing the metrics twice; ``identify=False`` skips the Bouc-Wen fit.
    ``identification``, a function returning identified_bouc_wen's answer, lets the fit finish elsewhere
    meanwhile: the header page that shows it is then drawn last and put first (it replaces
    ``report["identification"]``).
    """
    import logging

    meta = meta or {}
    if lab is None:
        lab = lab_header(meta.get("lab_name") or meta.get("lab"), meta.get("lab_address"), meta.get("lab_logo_file"))
        if lab.warning:
            logging.getLogger("isorig.reports").warning(lab.warning)
    extra = {k: v for k, v in meta.items() if v and not k.startswith("lab")}
    if extra:
        bundle = ReportBundle(record={**bundle.record, **extra}, samples=bundle.samples, cycles=bundle.cycles,
                              events=bundle.events)
    if report is None:
        report = report_json(bundle, identify=identify and identification is None, lab=lab)
    plt = plot_style()
    # the core-font AFM files say "medium" where matplotlib asks for "normal": harmless, silence it
    font_log = logging.getLogger("matplotlib.font_manager")
    level = font_log.level
    font_log.setLevel(logging.ERROR)
    target = out if hasattr(out, "write") else open(out, "wb")
    try:
        if identification is None:
            _write_pages(target, plt, bundle, report, lab)
        else:  # drawn into memory with the header last, then the header pages moved first
            buf = io.BytesIO()
            moved = _write_pages(buf, plt, bundle, report, lab, identification)
            data = _pages_moved_first(buf.getvalue(), moved)
            if data is None:  # a page tree this code does not know: draw again in order (the fit is there now)
                buf = io.BytesIO()
                _write_pages(buf, plt, bundle, report, lab)
                data = buf.getvalue()
            target.write(data)
    finally:
        font_log.setLevel(level)
        if target is not out:
            target.close()


def _write_pages(target, plt, bundle, report: dict, lab, identification=None) -> int:
    """Every page, numbered "page N of M"; with ``identification`` (a callable) the header page(s) are saved last,
    when the fit is there, and their number is returned (0 otherwise) for _pages_moved_first."""
    from matplotlib.backends.backend_pdf import PdfPages

    record = bundle.record
    iso = isolator_of(record)
    protocol, _note = protocol_of(record)
    u = lab.unit_system if lab is not None else LAB  # every figure in the lab's units
    if identification is None:
        flow = None
        header = page_header(plt, bundle, report, iso, protocol, lab)
    else:  # all but the Bouc-Wen table now (with room for it); the table when the fit is there
        flow = header_pages(plt, bundle, report, iso, protocol, lab)
        header = flow.figs
    figures = earthquake_figures(bundle) if report.get("earthquake") else None
    if figures is not None:  # a history or hybrid test: no cycles; the criteria, the overlay, the reference
        figs = pages_earthquake(plt, bundle, figures, u) + [page_time(plt, bundle, u)]
    else:
        figs = [page_loops(plt, bundle, protocol, report, u), page_time(plt, bundle, u)]
    s = bundle.samples
    if len(s) > 1 and s["time_s"][-1] - s["time_s"][0] > 6 * DETAIL_WINDOW_S:
        figs.append(page_time_detail(plt, bundle, u))
    if figures is None or bundle.cycles:
        figs += pages_table(plt, bundle, report["acceptance"], protocol, report["headline"], u)
    figs += pages_verdicts_events(plt, bundle, report, protocol, u)
    total = len(header) + len(figs)
    for page, fig in enumerate(header + figs, start=1):
        footer(fig, record, page, total, lab.name if lab is not None else "")
    with PdfPages(target, metadata={"Title": report_title(record), "Creator": "isorig",
                                    "Author": (lab.name if lab is not None else "") or "isorig"}) as pdf:
        if flow is None:
            _save(plt, pdf, header + figs)
            return 0
        _save(plt, pdf, figs)
        report["identification"] = identification()
        identification_block(flow, report["identification"], u)
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


def report_pdf_bytes(bundle, meta: dict | None = None, identify: bool = True, report: dict | None = None,
                     lab=None) -> bytes:
    """The PDF as bytes (for an HTTP response)."""
    buf = io.BytesIO()
    render_report_pdf(bundle, buf, meta, report=report, identify=identify, lab=lab)
    return buf.getvalue()
