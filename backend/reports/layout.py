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


def footer(fig, record, page: int):
    fig.text(0.5, 0.015, f"{report_title(record)}  |  page {page}  |  isorig", ha="center", fontsize=7, color="0.4")


def fmt_num(x, fmt="{:.4g}", scale=1.0, none="-"):
    v = num(x)
    return none if v is None else fmt.format(v * scale)


def wrap_text(text: str, width: int) -> list[str]:
    import textwrap

    return textwrap.wrap(text, width) or [""]


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
