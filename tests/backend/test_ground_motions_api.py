"""/api/ground-motions: the shipped synthetic ground motions as data, and a PEER .AT2 file read by the service's
one reader (sim.history.parse_at2) for the console, whose answer goes back unchanged in a test."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import AUTH

from sim.ground_motion import GROUND_MOTIONS, synthetic_ground_motion
from sim.history import read_at2

G = 9.80665
DT_S = 0.01
VALUES_G = 0.15 * np.sin(2 * np.pi * 1.0 * np.arange(300) * DT_S) * np.sin(np.pi * np.arange(300) / 300) ** 2
HEADER = ("PEER NGA STRONG MOTION DATABASE RECORD", "SYNTHETIC BURST, 1/1/2000, ISORIG, 000",
          "ACCELERATION TIME HISTORY IN UNITS OF G")


def at2_text(values=VALUES_G, npts=None) -> str:
    rows = [values[i:i + 5] for i in range(0, len(values), 5)]
    body = "\n".join("".join(f"{v:15.7E}" for v in row) for row in rows)
    return "\n".join(HEADER) + f"\nNPTS=  {len(values) if npts is None else npts}, DT=   .0100 SEC\n{body}\n"


def test_the_shipped_ground_motions_are_listed_with_their_seed_and_measured_peaks(client):
    r = client.get("/api/ground-motions")
    assert r.status_code == 200
    listed = {g["name"]: g for g in r.json()}
    assert set(listed) == set(GROUND_MOTIONS)
    for name, params in GROUND_MOTIONS.items():
        g = listed[name]
        assert g["seed"] == params.seed and g["duration_s"] == params.duration_s
        _t, acc, info = synthetic_ground_motion(name)
        assert g["measured"]["pga_g"] == pytest.approx(info["pga_g"])
        assert g["measured"]["pga_g"] == pytest.approx(np.max(np.abs(acc)) / G, rel=1e-9)
        assert g["samples"] == acc.size and "Kanai-Tajimi" in g["method"]


def test_an_at2_file_is_read_as_the_cli_reads_it_and_runs_as_sent_back(client, tmp_path):
    text = at2_text()
    r = client.post("/api/ground-motions/read-at2", json={"filename": "burst.AT2", "text": text})
    assert r.status_code == 200, r.text
    got = r.json()
    assert got["units"] == "g" and got["units_how"] == "the header"
    assert got["header"] == list(HEADER)
    assert got["rows"] == 300 and got["dt_s"] == pytest.approx(DT_S) and got["duration_s"] == pytest.approx(2.99)
    np.testing.assert_allclose(got["acceleration"], VALUES_G, rtol=1e-6, atol=1e-12)
    assert got["peak"] == pytest.approx(np.max(np.abs(VALUES_G)), rel=1e-6)
    (tmp_path / "burst.AT2").write_text(text)  # the CLI's reader: the same samples
    t_cli, a_cli = read_at2(tmp_path / "burst.AT2")
    np.testing.assert_allclose(np.array(got["acceleration"]) * G, a_cli, rtol=1e-12)
    np.testing.assert_allclose(got["time_s"], t_cli, rtol=1e-12)
    body = {"isolator": "IUT_a", "supply_bar": 100, "speed": 10.0,
            "profile": {"kind": "history", "ground_motion": {"time_s": got["time_s"],
                                                              "acceleration_m_per_s2": got["acceleration"],
                                                              "units": got["units"]}}}
    check = client.post("/api/tests/check", json=body).json()
    assert check["ok"] is True, check
    assert check["profile"]["kind"] == "history" and check["peak_displacement_m"] > 0


@pytest.mark.parametrize(("text", "words"), [
    ("hello\nworld\n", "no line with NPTS and DT"),
    (at2_text(npts=400), "a truncated record"),
    (at2_text(VALUES_G * 100), "beyond any recorded ground motion"),  # a peak of 14 g: the wrong unit
    (at2_text().replace("1.", "x.", 1), "is not a number"),
])
def test_a_file_that_is_not_a_record_is_refused_naming_what_is_wrong(client, text, words):
    r = client.post("/api/ground-motions/read-at2", json={"filename": "bad.AT2", "text": text})
    assert r.status_code == 422, r.text
    detail = r.json()["detail"]
    assert "bad.AT2" in detail and words in detail, detail
    assert "Traceback" not in r.text


def test_the_read_creates_nothing_and_needs_no_token(client):
    before = client.get("/api/tests").json()
    r = client.post("/api/ground-motions/read-at2", json={"filename": "burst.AT2", "text": at2_text()})
    assert r.status_code == 200
    assert client.get("/api/tests").json() == before
    bad = client.post("/api/ground-motions/read-at2", json={"filename": "x.AT2", "text": "a", "extra": 1},
                      headers=AUTH)
    assert bad.status_code == 422 and "extra" in bad.text
