"""The width and height of a string in a PDF core font, as matplotlib measures it, in fewer steps.

A report draws with the PDF's 14 core fonts (``pdf.use14corefonts``), measured from their AFM metrics. matplotlib's
``AFM.get_str_bbox_and_descent`` looks every character up one at a time; a 10-minute test's report measures about
73 000 characters (its per-cycle tables), which took 0.4 s of a 2.2 s report. ``fast_str_bbox_and_descent`` gives
the same answer from the distinct characters and the distinct pairs of neighbours (for the kerning): the widths are
whole font units, so the order of the sum does not change it.

``install()`` replaces matplotlib's method once per process, and only after checking, on strings that need the
fallback glyph, kerning and a line break, that both give the same answer; otherwise it leaves matplotlib as it is.
"""

from __future__ import annotations

from collections import Counter

_PROBES = ("", "\n", "AVATAR Wo.", "K_eff = 0.884 kN/mm\nEDC 1.23 kJ", "-12.50 mm  1.700  µ ± ° é €", "ﬁ\u2603x")


def _glyph(afm, c: str):
    """The glyph name matplotlib uses for ``c`` and its (width, bbox); 'question' for a glyph the font lacks."""
    from matplotlib._mathtext_data import uni2type1

    name = uni2type1.get(ord(c), f"uni{ord(c):04X}")
    try:
        wx, _, bbox = afm._metrics_by_name[name]
    except KeyError:
        name = "question"
        wx, _, bbox = afm._metrics_by_name[name]
    return name, wx, bbox


def fast_str_bbox_and_descent(afm, s: str) -> tuple:
    """(left, bottom, width, height, descent) of ``s`` in font units: matplotlib's AFM.get_str_bbox_and_descent."""
    if not len(s):
        return 0, 0, 0, 0, 0
    s = s.replace("\n", "")  # matplotlib skips line breaks; the kerning pair spans them
    glyphs = afm.__dict__.get("_isorig_glyphs")
    if glyphs is None:
        glyphs = afm.__dict__["_isorig_glyphs"] = {}
    total_width = 0.0
    miny, maxy, left = 1_000_000_000, 0, 0
    for c, count in Counter(s).items():
        g = glyphs.get(c)
        if g is None:
            g = glyphs[c] = _glyph(afm, c)
        _, wx, (lx, b, _w, h) = g
        total_width += wx * count
        left, miny, maxy = min(left, lx), min(miny, b), max(maxy, b + h)
    kern = afm._kern
    if kern:
        for (a, b), count in Counter(zip(s, s[1:], strict=False)).items():
            k = kern.get((glyphs[a][0], glyphs[b][0]), 0)
            if k:
                total_width += k * count
    return left, miny, total_width, maxy - miny, -miny


_ORIGINAL = None  # matplotlib's own, once replaced (None: not replaced)


def install() -> bool:
    """Use fast_str_bbox_and_descent for matplotlib's AFM fonts if it gives the same answers (True if in use)."""
    global _ORIGINAL
    if _ORIGINAL is not None:
        return True
    try:
        from matplotlib import _afm, cbook
        from matplotlib.backends._backend_pdf_ps import _cached_get_afm_from_fname

        original = _afm.AFM.get_str_bbox_and_descent
        core = cbook._get_data_path("fonts/pdfcorefonts")  # where the PDF backend reads the core fonts' metrics
        fonts = [_cached_get_afm_from_fname(str(core / f"{name}.afm")) for name in ("Helvetica", "Courier-Bold")]
        same = all(fast_str_bbox_and_descent(f, p) == original(f, p) for f in fonts for p in _PROBES)
    except Exception:  # another matplotlib: keep its own
        return False
    if not same:
        return False
    _ORIGINAL = original
    _afm.AFM.get_str_bbox_and_descent = fast_str_bbox_and_descent
    return True
