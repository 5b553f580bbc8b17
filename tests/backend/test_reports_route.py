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
    assert report["approval"]["tested_by"] == "A. Rossi"
    assert pdf[:5] == b"%PDF-"
