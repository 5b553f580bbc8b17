"""One tracking figure (issue 34 item 2, docs/metrics.md "The tracking figure"): every command prints the tracking
verdict's figure once, named and defined in the same words as the report and the test page; any other |y - r|
figure is named raw."""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pytest
from test_reports import PDFTOTEXT, pdf_text

from isorig.cli import main
from sim.tracking_figure import DEFINITION, HISTORY_DEFINITION, RAW_NAME

ROOT = Path(__file__).resolve().parents[1]
DEMO = ROOT / "docs" / "examples" / "structure_3_storey.json"


def percent(share: float) -> str:
    return f"{100 * share:.3g} %"


def test_simulate_prints_the_verdicts_figure_once_with_its_definition(tmp_path, capsys):
    assert main(["simulate", "--cycles", "4", "--out", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    verdict = json.loads((tmp_path / "summary.json").read_text())["tracking_verdict"]
    lines = [line for line in out.splitlines() if line.startswith("tracking error")]
    assert lines == [f"tracking error: {verdict['words']} [{DEFINITION}]"], out
    assert out.count(percent(verdict["rms_share"])) == 1, out
    # every other |y - r| figure is named for what it is; none is a share of the amplitude
    others = [line for line in out.splitlines() if line not in lines]
    assert all(line.startswith(RAW_NAME) for line in others if "y - r" in line or "RMS" in line), out
    assert not any("% of amplitude" in line for line in others), out


def test_the_definition_is_written_once_in_the_docs_and_word_for_word_on_the_page():
    docs = " ".join((ROOT / "docs" / "metrics.md").read_text().split())
    page = (ROOT / "frontend" / "static" / "js" / "verdict.js").read_text()
    for words in (DEFINITION, HISTORY_DEFINITION):
        assert words in docs and f'"{words}"' in page
    assert "tracking error (${trackingDefinition(t)})" in page


@pytest.mark.skipif(PDFTOTEXT is None, reason="pdftotext (poppler-utils) is not installed")
def test_the_report_shows_the_summarys_figure_with_the_same_words(tmp_path, capsys):
    run = tmp_path / "run"
    assert main(["simulate", "--cycles", "4", "--out", str(run)]) == 0
    printed = [line for line in capsys.readouterr().out.splitlines() if line.startswith("tracking error")]
    verdict = json.loads((run / "summary.json").read_text())["tracking_verdict"]
    assert main(["report", "--csv", str(run / "timeseries.csv"), "--out", str(tmp_path / "r.pdf"),
                 "--no-identify"]) == 0
    text = " ".join(" ".join(pdf_text(tmp_path / "r.pdf")).split())
    assert "Tracking error" in text and f"{verdict['words']} [{DEFINITION}]" in text, text[:3000]
    assert printed == [f"tracking error: {verdict['words']} [{DEFINITION}]"]  # the CLI's words, the report's
    assert text.count(percent(verdict["rms_share"])) == 1
    assert "Raw |y - r|" in text and "not the tracking error" in text and "Table followed" not in text


def test_hybrid_prints_j2_once_as_its_tracking_error(tmp_path, capsys):
    gm = tmp_path / "pulse.csv"
    t = np.arange(0.0, 4.0, 0.005)
    acc = 2.0 * np.sin(2 * np.pi * 1.2 * t) * np.exp(-((t - 2.0) / 0.8) ** 2)
    gm.write_text("time_s,acceleration_m_per_s2\n" + "".join(f"{a:.4f},{b:.6g}\n" for a, b in zip(t, acc,
                                                                                                  strict=True)))
    assert main(["hybrid", "--structure", str(DEMO), "--ground-motion", str(gm), "--isolator", "IUT_a",
                 "--out", str(tmp_path / "o")]) == 0
    out = capsys.readouterr().out
    j2 = json.loads((tmp_path / "o" / "summary.json").read_text())["criteria"]["j2_rms_percent"]
    lines = [line for line in out.splitlines() if line.startswith("tracking error")]
    assert len(lines) == 1 and lines[0].endswith(f"[{HISTORY_DEFINITION}]"), out
    assert f"J2 {j2:.3g} %" in lines[0]
    assert len(re.findall(r"\bJ2 \d", out)) == 1, out
