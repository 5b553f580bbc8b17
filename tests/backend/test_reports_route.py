"""GET /api/tests/{id}/bundle.zip: the whole test as one zip (record, report, samples, cycles, PDF)."""

from __future__ import annotations

import csv
import io
import json
import zipfile

import pytest
from conftest import create_and_start, make_settings, wait_for
from fastapi.testclient import TestClient

from backend.app import create_app


def test_the_bundle_of_a_test_that_ran(tmp_path):
    settings = make_settings(tmp_path, lab_name="Prove Lab", lab_address="Via Roma 1; Milano",
                             lab_logo_file=tmp_path / "no-logo.png")
    with TestClient(create_app(settings)) as client:
        test_id = create_and_start(client, specimen_id="LRB-9", operator_name="A. Rossi")
        record = wait_for(client, test_id)
        assert record["status"] == "completed"
        r = client.get(f"/api/tests/{test_id}/bundle.zip")
        assert r.status_code == 200, r.text
        assert r.headers["content-type"] == "application/zip"
        assert f'filename="test-{test_id}-bundle.zip"' in r.headers["content-disposition"]
        data_csv = client.get(f"/api/tests/{test_id}/data.csv").text
        # the report routes take the lab from the service's settings too, not only from the environment
        assert client.get(f"/api/tests/{test_id}/report.json").json()["lab"]["name"] == "Prove Lab"
        assert client.get("/api/tests/999/bundle.zip").status_code == 404
    folder = f"test-{test_id}/"
    with zipfile.ZipFile(io.BytesIO(r.content)) as zf:
        assert sorted(zf.namelist()) == sorted(folder + n for n in ("README.txt", "record.json", "report.json",
                                                                    "samples.csv", "cycles.csv", "report.pdf"))
        stored = json.loads(zf.read(folder + "record.json"))
        report = json.loads(zf.read(folder + "report.json"))
        samples = zf.read(folder + "samples.csv").decode()
        cycles = list(csv.DictReader(io.StringIO(zf.read(folder + "cycles.csv").decode())))
        pdf = zf.read(folder + "report.pdf")
    assert stored["id"] == test_id and stored["specimen_id"] == "LRB-9" and stored["events"]
    assert samples == data_csv  # the samples exactly as data.csv gives them (SI units, same columns)
    assert [c["phase"] for c in cycles] == ["taper_in", "steady", "taper_out"]
    assert [c["in_headline"] for c in cycles] == ["0", "1", "0"]
    # the headline figures are the steady cycle's, as the service's summary says
    steady = float(cycles[1]["k_eff_n_per_m"])
    assert report["headline"]["means"]["k_eff_n_per_m"] == pytest.approx(steady, rel=1e-8)
    assert record["summary"]["loop_metrics_mean"]["k_eff_n_per_m"] == report["headline"]["means"]["k_eff_n_per_m"]
    assert report["lab"]["name"] == "Prove Lab" and report["lab"]["logo_shown"] is False
    assert "no such file" in report["lab"]["logo_warning"]  # the report is made all the same
    assert report["approval"]["tested_by"] == "A. Rossi (through automation)"
    assert pdf[:5] == b"%PDF-"


def test_a_protocol_tests_acceptance_without_the_report(client):
    """GET .../acceptance: the report's verdicts of a protocol test, per rule and cycle, and each level's means;
    the summary keeps the verdict word; a sine test has none (422, said)."""
    from conftest import AUTH, sine_test

    from backend.reports.content import acceptance, headline
    from backend.store import load_test_bundle

    body = {**sine_test(speed=20.0), "profile": {"kind": "protocol", "name": "quick_check"}}
    test_id = client.post("/api/tests?start=true", json=body, headers=AUTH).json()["id"]
    record = wait_for(client, test_id)
    assert record["status"] == "completed"
    r = client.get(f"/api/tests/{test_id}/acceptance")
    assert r.status_code == 200, r.text
    got = r.json()
    with client.app.state.sessions() as session:  # the report's own computation on the whole bundle
        bundle = load_test_bundle(session, test_id)
    from backend.reports.data import protocol_of, run_of

    full = acceptance(bundle, run_of(bundle))
    assert got["verdict"] == full["verdict"] == "PASSED"
    assert [v["value"] for v in got["verdicts"]] == pytest.approx([v["value"] for v in full["verdicts"]])
    assert len(got["verdicts"]) == got["summary"]["verdicts"] == 8
    levels = headline(bundle, protocol_of(bundle.record)[0])["levels"]
    assert [lv["amplitude_m"] for lv in got["levels"]] == [0.01, 0.02]
    assert got["levels"][1]["means"]["k_eff_n_per_m"] == pytest.approx(levels[1]["means"]["k_eff_n_per_m"])
    assert record["summary"]["acceptance"] == {"verdict": "PASSED", "verdicts": 8, "failed": 0}
    sine = create_and_start(client, speed=20.0)
    assert "acceptance" not in wait_for(client, sine)["summary"]
    r = client.get(f"/api/tests/{sine}/acceptance")
    assert r.status_code == 422 and "did not run a protocol" in r.json()["detail"]
