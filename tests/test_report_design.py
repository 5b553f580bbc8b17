"""Issue 34, item 3: a protocol's headline figures per amplitude level (no mean over levels), acceptance against
the specimen's design values (K_eff, EDC, xi_eff within the lab's tolerances, EN 15129's type-test tolerances by
default) with a verdict per level, and the approver's note printed in the report."""

from __future__ import annotations

import copy
import shutil
import subprocess

import pytest
from test_reports import protocol_run

from backend.reports import LabHeader, render_report_pdf, report_json
from backend.reports.design import EN15129_TYPE_TEST, check_tolerances, tolerances_for
from sim.protocols import load_protocol

PDFTOTEXT = shutil.which("pdftotext")
needs_pdftotext = pytest.mark.skipif(PDFTOTEXT is None, reason="pdftotext (poppler-utils) is not installed")


def text_of(pdf) -> str:
    return subprocess.run([PDFTOTEXT, "-layout", str(pdf), "-"], check=True, capture_output=True, text=True,
                          timeout=60).stdout


@pytest.fixture(scope="module")
def run():
    return protocol_run("quick_check")


def scaled(bundle, level: int, factor: float, keys=("k_eff_n_per_m", "edc_j")):
    """The bundle with the metrics of one level's cycles scaled (a softer specimen at that amplitude)."""
    out = copy.copy(bundle)
    out.cycles = copy.deepcopy(bundle.cycles)
    plan = {p["cycle"]: p for p in load_protocol("quick_check").cycle_plan()}
    for c in out.cycles:
        if plan.get(c["cycle"], {}).get("level") == level:
            for k in keys:
                c[k] *= factor
    return out


def test_en15129_type_test_tolerances_are_the_shipped_default():
    t = tolerances_for(None, "en15129_type_test")
    assert (t["k_eff"], t["edc"], t["xi_eff"], t["mean"]) == (0.15, 0.15, 0.15, 0.10) and "EN 15129" in t["source"]
    lab = LabHeader(tolerances={"quick_check": {"k_eff": 0.2, "edc": 0.25, "xi_eff": 0.3, "mean": 0.12,
                                                "updated_by": "adam"}})
    assert tolerances_for(lab, "quick_check")["edc"] == 0.25 and "set by the lab" in tolerances_for(lab, "quick_check")[
        "source"]
    assert tolerances_for(lab, "en15129_type_test")["k_eff"] == EN15129_TYPE_TEST["k_eff"]  # per protocol
    with pytest.raises(ValueError, match="mean must be a fraction"):
        check_tolerances({"k_eff": 0.15, "edc": 0.15, "xi_eff": 0.15, "mean": 15})


def test_acceptance_judges_each_level_against_the_design_values(run):
    design = report_json(run, identify=False)["acceptance"]["design"]
    assert [lv["verdict"] for lv in design["levels"]] == ["PASSED", "PASSED"]  # the simulated plant is the model
    for lv in design["levels"]:
        assert set(lv["design"]) == {"k_eff_n_per_m", "edc_j", "xi_eff"}
        assert [m["name"] for m in lv["mean_checks"]] == ["K_eff", "EDC", "xi_eff"]
        assert len(lv["checks"]) == 3 * lv["test_cycles"]

    soft = report_json(scaled(run, 2, 0.8), identify=False)["acceptance"]
    levels = soft["design"]["levels"]
    assert [lv["verdict"] for lv in levels] == ["PASSED", "FAILED"] and soft["verdict"] == "FAILED"
    keff = next(m for m in levels[1]["mean_checks"] if m["name"] == "K_eff")
    assert keff["status"] == "fail" and keff["deviation_fraction"] == pytest.approx(-0.2, abs=0.02)
    xi = next(m for m in levels[1]["mean_checks"] if m["name"] == "xi_eff")
    assert xi["status"] == "pass"  # K_eff and EDC both 20 % low: the damping ratio is unchanged
    assert soft["summary"]["passed"] is True  # the protocol's own rules (cycle to cycle) still pass

    # 12 % low: each cycle within +-15 %, the level's mean not within +-10 %
    mean_only = report_json(scaled(run, 1, 0.88), identify=False)["acceptance"]["design"]["levels"][0]
    assert mean_only["verdict"] == "FAILED"
    assert all(c["status"] == "pass" for c in mean_only["checks"] if c["name"] == "K_eff")
    assert next(m for m in mean_only["mean_checks"] if m["name"] == "K_eff")["status"] == "fail"

    # the lab's tolerances for this protocol
    lab = LabHeader(tolerances={"quick_check": {"k_eff": 0.25, "edc": 0.25, "xi_eff": 0.25, "mean": 0.25}})
    eased = report_json(scaled(run, 2, 0.8), identify=False, lab=lab)["acceptance"]
    assert [lv["verdict"] for lv in eased["design"]["levels"]] == ["PASSED", "PASSED"] and eased["verdict"] == "PASSED"


def test_a_level_never_reached_is_not_passed(run):
    short = copy.copy(run)
    plan = {p["cycle"]: p for p in load_protocol("quick_check").cycle_plan()}
    short.cycles = [c for c in run.cycles if plan[c["cycle"]]["level"] == 1]
    short.record = {**run.record, "status": "stopped"}
    acc = report_json(short, identify=False)["acceptance"]
    assert [lv["verdict"] for lv in acc["design"]["levels"]] == ["PASSED", "NOT REACHED"]
    assert acc["verdict"] != "PASSED"


@needs_pdftotext
def test_the_pdf_gives_the_figures_and_the_verdict_per_level_and_the_approvers_note(run, tmp_path):
    bundle = scaled(run, 2, 0.8)
    bundle.record = {**run.record, "review": {"state": "approved", "by": "anna", "at": "2026-11-29T10:00:00+00:00",
                                              "note": "Softer than declared at 20 mm; see level 2.",
                                              "record_sha256": "ab" * 32}}
    render_report_pdf(bundle, tmp_path / "r.pdf", identify=False, lab=LabHeader(name="Lab A"))
    text = text_of(tmp_path / "r.pdf")
    page1 = text.split("\f")[0]
    assert "mean, all steady cycles" not in text  # no mean over levels of different amplitude
    assert "level 1: 10.00 mm 1 Hz" in page1 and "level 2: 20.00 mm 1 Hz" in page1
    design_rows = [line.split() for line in page1.splitlines() if line.strip().startswith("design value")]
    assert [row[-1] for row in design_rows] == ["PASSED", "FAILED"]
    assert "level 1 PASSED, level 2 FAILED" in page1
    assert "mean L1" in text and "mean L2" in text  # the table's means per level
    assert "Against the specimen's design values" in text and "EN 15129 type test" in text
    assert "Note of the approver (anna): Softer than declared at 20 mm; see level 2." in text
