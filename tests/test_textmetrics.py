"""backend.reports.textmetrics: the core fonts' string metrics in fewer steps, the same as matplotlib's."""

from __future__ import annotations

import random

import pytest

pytest.importorskip("matplotlib")

from matplotlib import _afm, cbook  # noqa: E402
from matplotlib.backends._backend_pdf_ps import _cached_get_afm_from_fname  # noqa: E402

from backend.reports import textmetrics  # noqa: E402

FONTS = ("Helvetica", "Helvetica-Bold", "Courier", "Times-Roman")


def _original():
    original = _afm.AFM.__dict__["get_str_bbox_and_descent"]
    return textmetrics._ORIGINAL if original is textmetrics.fast_str_bbox_and_descent else original


def test_the_same_answers_as_matplotlib_on_report_text_and_random_strings():
    original = _original()
    rng = random.Random(3)
    alphabet = "AVWTYLPFkeo.,:;-+ 0123456789mm kN/mm\n\u00b1\u00b0\u00b5\u00e9\u20ac\u2603\u2264xyz()[]"
    strings = ["", "\n", "\n\n", "AV", "A\nV", "To", "WAVE", "1.700", "K_eff (mean of 3 steady cycles)",
               "-12.50 mm \u00b1 0.01", "\u2603\u2603"]
    strings += ["".join(rng.choice(alphabet) for _ in range(rng.randint(1, 90))) for _ in range(400)]
    core = cbook._get_data_path("fonts/pdfcorefonts")
    for name in FONTS:
        font = _cached_get_afm_from_fname(str(core / f"{name}.afm"))
        for s in strings:
            assert textmetrics.fast_str_bbox_and_descent(font, s) == original(font, s), (name, s)


def test_installed_once_and_used_by_the_reports():
    from backend.reports.figures import plot_style

    plot_style()
    assert textmetrics.install() is True  # idempotent
    assert _afm.AFM.get_str_bbox_and_descent is textmetrics.fast_str_bbox_and_descent
