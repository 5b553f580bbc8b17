"""The lab's settings in the database (backend.lab): set by an admin, used by every report."""

from __future__ import annotations

import base64
import io

import pytest
from conftest import AUTH, make_settings, sine_test, wait_for
from fastapi.testclient import TestClient
from test_accounts import add, token_of

from backend.app import create_app


def png(width: int = 40, height: int = 20) -> bytes:
    from PIL import Image

    buf = io.BytesIO()
    Image.new("RGB", (width, height), (200, 30, 30)).save(buf, format="PNG")
    return buf.getvalue()


@pytest.fixture
def admin(client):
    add(client, "adam", "admin")
    add(client, "otto", "operator")
    return client, token_of(client, "adam")


def completed_test(client) -> int:
    r = client.post("/api/tests?start=true", json=sine_test(), headers=AUTH)
    return wait_for(client, r.json()["id"])["id"]


def test_an_admin_sets_the_lab_and_every_report_uses_it(admin):
    c, headers = admin
    test_id = completed_test(c)
    assert c.get("/api/lab").json()["name"] == ""
    r = c.put("/api/lab", json={"name": "Seismic Lab A", "address": "Via Roma 1; 00100 Roma", "units": "si"},
              headers=headers)
    assert r.status_code == 200, r.text
    lab = r.json()
    assert lab["name"] == "Seismic Lab A" and lab["units"] == "si" and lab["updated_by"] == "adam"
    assert lab["source"] == {"name": "database", "address": "database"}
    report = c.get(f"/api/tests/{test_id}/report.json").json()["lab"]
    assert report["name"] == "Seismic Lab A" and report["address"] == "Via Roma 1; 00100 Roma"
    assert report["logo_shown"] is False
    r = c.put("/api/lab/logo", json={"data_base64": base64.b64encode(png()).decode()}, headers=headers)
    assert r.status_code == 200 and r.json()["logo"] == "stored" and r.json()["logo_type"] == "image/png"
    assert c.get("/api/lab/logo").content == png()
    assert c.get(f"/api/tests/{test_id}/report.json").json()["lab"]["logo_shown"] is True
    pdf = c.get(f"/api/tests/{test_id}/report.pdf")
    assert pdf.status_code == 200 and pdf.content.startswith(b"%PDF")
    assert c.put("/api/lab/logo", json={"data_base64": None}, headers=headers).json()["logo"] is None
    assert c.get("/api/lab/logo").status_code == 404
    events = c.get("/api/events").json()
    assert any(e["message"] == "lab settings changed by adam" and e["actor"] == "adam" for e in events), events


@pytest.mark.parametrize(("data", "says"), [
    ("not base64 !!", "not valid base64"),
    (base64.b64encode(b"GIF89a....").decode(), "PNG or JPEG"),
    (base64.b64encode(b"\x89PNG\r\n\x1a\n" + b"garbage" * 10).decode(), "cannot be read"),
    (base64.b64encode(b"\x89PNG\r\n\x1a\n" + bytes(1024 * 1024)).decode(), "at most 1048576"),
])
def test_a_bad_logo_is_refused_saying_why(admin, data, says):
    c, headers = admin
    r = c.put("/api/lab/logo", json={"data_base64": data}, headers=headers)
    assert r.status_code == 422 and says in r.text, r.text
    assert c.get("/api/lab").json()["logo"] is None


def test_only_an_admin_changes_the_lab(admin):
    c, _ = admin
    for headers in ({}, token_of(c, "otto"), AUTH):
        r = c.put("/api/lab", json={"name": "mine"}, headers=headers)
        assert r.status_code in (401, 403), r.text
    r = c.put("/api/lab", json={"units": "imperial"}, headers=admin[1])
    assert r.status_code == 422 and "units" in r.text
    assert c.get("/api/lab").json()["name"] == ""


def test_without_database_settings_the_environment_s_stay_in_force(tmp_path):
    settings = make_settings(tmp_path, lab_name="Env Lab", lab_address="Street 2")
    with TestClient(create_app(settings)) as c:
        test_id = completed_test(c)
        assert c.get("/api/lab").json()["source"] == {"name": "environment", "address": "environment"}
        assert c.get(f"/api/tests/{test_id}/report.json").json()["lab"]["name"] == "Env Lab"
        add(c, "adam", "admin")
        c.put("/api/lab", json={"address": "New Street 3"}, headers=token_of(c, "adam"))
        lab = c.get(f"/api/tests/{test_id}/report.json").json()["lab"]
        assert lab["name"] == "Env Lab" and lab["address"] == "New Street 3"


def pdf_text(data: bytes, tmp_path) -> str:
    import shutil
    import subprocess

    if shutil.which("pdftotext") is None:
        pytest.skip("pdftotext (poppler-utils) is not installed")
    path = tmp_path / "report.pdf"
    path.write_bytes(data)
    return subprocess.run(["pdftotext", "-layout", str(path), "-"], capture_output=True, text=True, check=True,
                          timeout=60).stdout


def test_the_report_prints_every_figure_in_the_labs_units(admin, tmp_path):
    """The lab's units (PUT /api/lab units) are the report's: lab units by default (mm, kN, kN/mm, bar), SI once
    the lab chose it (m, N, N/m, MPa), in the header, the tables and the plots' axes; report.json stays SI and
    says which units the PDF printed in."""
    import re

    c, headers = admin
    test_id = completed_test(c)
    lab_text = " ".join(pdf_text(c.get(f"/api/tests/{test_id}/report.pdf").content, tmp_path).split())
    assert "k_d = 1.25 kN/mm" in lab_text and "k_w = 17 kN" in lab_text and "rho_BW = 0.141 1/mm" in lab_text
    assert "100.0 bar" in lab_text and "force [kN]" in lab_text and "displacement [mm]" in lab_text
    assert not re.search(r"\d (N/m|N|m|MPa)\b", lab_text), re.findall(r".{30}\d (?:N/m|N|m|MPa)\b", lab_text)
    assert c.get(f"/api/tests/{test_id}/report.json").json()["lab"]["units"] == "lab"
    assert c.put("/api/lab", json={"units": "si"}, headers=headers).status_code == 200
    si_pdf = pdf_text(c.get(f"/api/tests/{test_id}/report.pdf").content, tmp_path)
    si_text = " ".join(si_pdf.split())
    assert "k_d = 1250000 N/m" in si_text and "k_w = 17000 N" in si_text and "rho_BW = 141 1/m" in si_text
    assert "10.00 MPa" in si_text and "force [N]" in si_text and "displacement [m]" in si_text
    assert not re.search(r"\d (kN/mm|kN|mm|bar)\b", si_text), re.findall(r".{30}\d (?:kN/mm|kN|mm|bar)\b", si_text)
    units_line = next(line for line in si_pdf.splitlines() if line.split()[:3] == ["s", "m", "m"])
    assert units_line.split() == ["s", "m", "m", "N", "N", "N/m", "J", "%", "N", "N/m"]  # the per-cycle table
    report = c.get(f"/api/tests/{test_id}/report.json").json()
    assert report["lab"]["units"] == "si"
    assert report["isolator_nominal"]["kd_n_per_m"] == 1.25e6  # the JSON keeps SI, whatever the lab prints in
