"""Page layout shared by every page of the PDF: A4 size, the title and footer, number formatting, wrapping, and
blocks of monospace lines at a fixed pitch (tables, notes, event lists).
"""

from __future__ import annotations

from .data import num

A4_PORTRAIT_IN = (8.27, 11.69)


def report_title(record: dict) -> str:
    tid = record.get("id")
    label = record.get("label") or ""
    return f"Isolator test report - test {tid}" + (f" - {label}" if label else "") if tid is not None else \
        f"Isolator test report - {label or 'record'}"


def footer(fig, record, page: int, total: int, lab_name: str = "") -> None:
    """The line at the foot of every page: the lab, the report and "page N of M" (drawn once all pages exist)."""
    grey = "0.4"
    if lab_name:
        fig.text(0.06, 0.015, lab_name[:60], ha="left", fontsize=7, color=grey)
    fig.text(0.5, 0.015, report_title(record), ha="center", fontsize=7, color=grey)
    fig.text(0.94, 0.015, f"page {page} of {total}", ha="right", fontsize=7, color=grey)
    fig.add_artist(_rule(fig, 0.027))


def _rule(fig, y: float, x0: float = 0.06, x1: float = 0.94, color: str = "0.75", lw: float = 0.6):
    from matplotlib.lines import Line2D

    return Line2D([x0, x1], [y, y], transform=fig.transFigure, color=color, lw=lw)


def rule(fig, y: float, x0: float = 0.06, x1: float = 0.94, color: str = "0.75", lw: float = 0.6) -> None:
    """A horizontal line across the page at height ``y`` (figure fraction)."""
    fig.add_artist(_rule(fig, y, x0, x1, color, lw))


PAGE_TOP = 0.955  # baseline of a page's title
PAGE_BOTTOM = 0.045  # nothing below this but the footer


class Flow:
    """Text laid out from the top of a page down, onto a new page (with ``title`` continued) when one is full.

    Heights are in points (``pitch``), converted to figure fractions of the A4 page; ``room(pt)`` starts a new
    page unless that much is left, so a block that must stay together asks for its height first."""

    def __init__(self, plt, title: str, top: float = 0.91):
        self.plt = plt
        self.title = title
        self.figs: list = []
        self.top = top
        self.fig = None
        self.y = 0.0

    @staticmethod
    def frac(pt: float) -> float:
        return pt / 72.0 / A4_PORTRAIT_IN[1]

    def new_page(self, continued: bool = True, title: str | None = None):
        """A new page; its title is ``title`` (then the pages after it continue that), else the flow's title
        with "(continued)" if this is not its first page."""
        fig = self.plt.figure(figsize=A4_PORTRAIT_IN)
        self.figs.append(fig)
        self.fig = fig
        self.y = self.top
        if title is not None:
            self.title = title
        if title is not None or continued and len(self.figs) > 1:
            fig.text(0.06, PAGE_TOP, self.title + ("" if title is not None else " (continued)"), fontsize=12,
                     weight="bold")
            self.y = 0.925
        return fig

    def room(self, pt: float) -> None:
        if self.fig is None or self.y - self.frac(pt) < PAGE_BOTTOM:
            self.new_page()

    def left(self) -> float:
        """Points left on the current page."""
        return (self.y - PAGE_BOTTOM) * 72.0 * A4_PORTRAIT_IN[1]

    def skip(self, pt: float) -> None:
        self.y -= self.frac(pt)

    def text(self, x: float, text: str, pitch: float = 11.0, **kw) -> None:
        """One line at x, its baseline one pitch below the current height."""
        self.room(pitch)
        self.y -= self.frac(pitch)
        self.fig.text(x, self.y, text, **kw)

    def row(self, cells, pitch: float = 11.0, **kw) -> None:
        """One line of (x, text) or (x, text, extra keywords) cells on the same baseline."""
        self.room(pitch)
        self.y -= self.frac(pitch)
        for cell in cells:
            x, text = cell[0], cell[1]
            self.fig.text(x, self.y, text, **{**kw, **(cell[2] if len(cell) > 2 else {})})


def fmt_num(x, fmt="{:.4g}", scale=1.0, none="-"):
    v = num(x)
    return none if v is None else fmt.format(v * scale)


def wrap_text(text: str, width: int) -> list[str]:
    """Lines of at most ``width`` characters, breaking at spaces (a longer word is broken), never cut short."""
    import textwrap

    lines = []
    for paragraph in str(text).splitlines() or [""]:
        lines += textwrap.wrap(paragraph, width, break_on_hyphens=False) or [""]
    return lines


def draw_lines(fig, lines, x: float, y_top: float, fontsize: float, pitch_pt: float) -> None:
    """Monospace lines at a fixed pitch below (x, y_top) in figure fractions: line k (from 1) has its baseline k
    pitches below y_top. ``lines`` holds texts or (text, colour) pairs; an empty text leaves its line blank.

    One Text per line, anchored at its baseline: a multi-line Text would centre each line on the height of its own
    glyphs (matplotlib 3.11), moving lines by a fraction of a point from the fixed pitch.
    """
    from matplotlib.font_manager import FontProperties

    prop = FontProperties(family="monospace", size=fontsize)  # one for all: each Text keeps a copy
    step = pitch_pt / 72.0 / fig.get_figheight()
    for k, item in enumerate(lines, start=1):
        text, color = item if isinstance(item, tuple) else (item, "black")
        if text:
            fig.text(x, y_top - k * step, text, fontproperties=prop, color=color, va="baseline")


# Helvetica's advance widths (the PDF core font the text is set in; 1/1000 em, its AFM file), to wrap text to a
# width in points without asking matplotlib to measure every candidate line
_HELVETICA = dict(zip(
    " !\"#$%&'()*+,-./0123456789:;<=>?@ABCDEFGHIJKLMNOPQRSTUVWXYZ[\\]^_`abcdefghijklmnopqrstuvwxyz{|}~",
    (278, 278, 355, 556, 556, 889, 667, 191, 333, 333, 389, 584, 278, 333, 278, 278) + (556,) * 10
    + (278, 278, 584, 584, 584, 556, 1015, 667, 667, 722, 722, 667, 611, 778, 722, 278, 500, 667, 556, 833, 722, 778,
       667, 778, 722, 667, 611, 722, 667, 944, 667, 667, 611, 278, 278, 278, 469, 556, 333, 556, 556, 500, 556, 556,
       278, 556, 556, 222, 222, 500, 222, 833, 556, 556, 556, 556, 333, 500, 278, 556, 500, 722, 500, 500, 500, 334,
       260, 334, 584), strict=True))


def text_width_pt(text: str, size: float) -> float:
    """The width of ``text`` in Helvetica at ``size`` points (characters it lacks count as an 'M')."""
    return sum(_HELVETICA.get(ch, 833) for ch in text) * size / 1000.0


def wrap_pt(text: str, width_pt: float, size: float) -> list[str]:
    """``text`` broken at spaces into lines no wider than ``width_pt`` in Helvetica at ``size`` points (a word
    wider than that is cut into pieces), every word kept; newlines start new lines."""
    lines: list[str] = []
    for paragraph in str(text).splitlines() or [""]:
        line = ""
        for word in paragraph.split(" "):
            candidate = word if not line else line + " " + word
            if text_width_pt(candidate, size) <= width_pt or not line and not word:
                line = candidate
                continue
            if line:
                lines.append(line)
            while text_width_pt(word, size) > width_pt and len(word) > 1:  # a word wider than the line
                k = len(word)
                while k > 1 and text_width_pt(word[:k], size) > width_pt:
                    k -= 1
                lines.append(word[:k])
                word = word[k:]
            line = word
        lines.append(line)
    return lines


def wrap_items(items: list[str], width_pt: float, size: float, sep: str = ", ") -> list[str]:
    """Items joined by ``sep`` into lines no wider than ``width_pt``, breaking only between items (an item wider
    than a line is wrapped at its spaces): ``name = value unit`` stays on one line."""
    lines: list[str] = []
    line = ""
    for k, item in enumerate(items):
        piece = item + (sep.rstrip() if k < len(items) - 1 else "")
        candidate = piece if not line else line + " " + piece
        if text_width_pt(candidate, size) <= width_pt:
            line = candidate
            continue
        if line:
            lines.append(line)
        if text_width_pt(piece, size) > width_pt:
            *full, line = wrap_pt(piece, width_pt, size)
            lines += full
        else:
            line = piece
    if line or not lines:
        lines.append(line)
    return lines
