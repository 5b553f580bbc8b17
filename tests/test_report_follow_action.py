"""The report says when the follow detector was set to indicate (limits.actions.follow), whether it fired or not:
a reader of a report with no finding must still know a table that did not follow would not have stopped it."""

from __future__ import annotations

import pytest
from test_reports import PDFTOTEXT, pdf_text, protocol_run

from backend.reports import ReportBundle, render_report_pdf, report_json
from backend.reports.header import _condition_lines
from sim.rig import RigParameters
from sim.safety import make_limits

WORDS = "follow detector: indicate (a table that does not follow is an event, the test goes on)"


def limits(follow: str | None) -> dict:
    return make_limits(RigParameters(), {"actions": {"follow": follow}} if follow else None).to_dict()


@pytest.mark.parametrize(("stored", "said"), [
    ({"actions": {"follow": "indicate"}}, True),
    ({"follow": {"action": "indicate"}}, True),  # the action as SafetyLimits.to_dict also gives it
    ({"actions": {}, "follow": {"action": "controlled_stop"}}, False),
    ({"displacement_m": 0.1}, False),
])
def test_the_conditions_say_the_follow_detector_indicates(stored, said):
    lines = _condition_lines({"limits": stored}, None)
    assert any(value == WORDS for _key, value in lines) is said


@pytest.mark.skipif(PDFTOTEXT is None, reason="pdftotext (poppler-utils) is not installed")
def test_the_report_says_indicate_when_the_detector_did_not_fire(tmp_path):
    base = protocol_run()
    pages = {}
    for follow in ("indicate", None):
        bundle = ReportBundle({**base.record, "limits": limits(follow)}, base.samples, base.cycles, base.events)
        rep = report_json(bundle, identify=False)
        assert not rep["limit_indications"]  # the detector never fired: no "Limits indicated" line
        render_report_pdf(bundle, tmp_path / f"{follow}.pdf", report=rep, identify=False)
        pages[follow] = " ".join(pdf_text(tmp_path / f"{follow}.pdf")[0].split())
    assert WORDS in pages["indicate"]
    assert "follow detector" not in pages[None] and "Limits indicated" not in pages["indicate"]
