"""REST API: records, validation errors that name field, value and limit, state conflicts."""

from __future__ import annotations

import pytest
from conftest import AUTH, create_and_start, sine_test, wait_for

USER_ISOLATOR = {"name": "my_lrb", "rho_bw_per_m": 200.0, "sigma_bw": 0.5, "n": 1.0, "kd_n_per_m": 9e5,
                 "kw_n": 2e4, "description": "test"}


def test_health_and_rig(client):
    assert client.get("/api/health").json()["status"] == "ok"
    rig = client.get("/api/rig").json()
    assert rig["driver"] == "simulated"
    assert rig["envelope"]["stroke_m"] > 0
    assert rig["state"]["status"] == "idle"
    names = {p["name"] for p in rig["parameters"]}
    assert {"piston_area_m2", "stroke_m"} <= names
    assert rig["limits_default"]["displacement_m"] <= rig["limits_max"]["displacement_m"]
    # what the console needs to say when a start or a move can succeed, from the service, not copied into it
    assert rig["rig"]["start_tolerance_m"] == 0.002
    assert rig["manual_motion"] == {"min_speed_m_per_s": 0.001, "max_speed_m_per_s": 0.05,
                                    "default_speed_m_per_s": 0.005, "hold_s": 0.5, "max_duration_s": 600.0}
    assert (rig["envelope"]["min_speed"], rig["envelope"]["max_speed"]) == (0.1, 100.0)


def test_isolators_presets_and_user(client):
    names = {i["name"]: i["source"] for i in client.get("/api/isolators").json()}
    assert names["IUT_a"] == "preset" and names["IUT_b"] == "preset"
    r = client.post("/api/isolators", json=USER_ISOLATOR, headers=AUTH)
    assert r.status_code == 201, r.text
    assert client.get("/api/isolators/my_lrb").json()["kd_n_per_m"] == 9e5
    assert client.get("/api/isolators/my_lrb").json()["source"] == "user"
    assert client.post("/api/isolators", json=USER_ISOLATOR, headers=AUTH).status_code == 409
    assert client.post("/api/isolators", json={**USER_ISOLATOR, "name": "IUT_a"}, headers=AUTH).status_code == 409
    assert client.get("/api/isolators/nope").status_code == 404
    # a user isolator can be tested
    r = client.post("/api/tests", json=sine_test(isolator="my_lrb"), headers=AUTH)
    assert r.status_code == 201, r.text


def test_isolator_out_of_range_names_field(client):
    r = client.post("/api/isolators", json={**USER_ISOLATOR, "name": "bad", "kd_n_per_m": 5e9}, headers=AUTH)
    assert r.status_code == 422
    assert "kd_n_per_m" in r.json()["detail"] and "1e+09" in r.json()["detail"]


def test_create_test_record(client):
    r = client.post("/api/tests", json=sine_test(label="first"), headers=AUTH)
    assert r.status_code == 201
    rec = r.json()
    assert rec["status"] == "ready" and rec["id"] >= 1
    assert rec["cycles_total"] == 3 and abs(rec["duration_s"] - 1.5) < 1e-9
    assert rec["profile"]["amplitude_m"] == 0.01
    assert rec["scenario"]["isolator"]["name"] == "IUT_a"
    assert [e["kind"] for e in rec["events"]] == ["operator"]
    assert client.get(f"/api/tests/{rec['id']}").json()["label"] == "first"


def test_outside_envelope_names_field_value_limit(client):
    r = client.post("/api/tests", json=sine_test(profile={"amplitude_m": 0.2}), headers=AUTH)
    assert r.status_code == 422
    body = r.json()
    assert body["field"] == "profile.amplitude_m" and body["value"] == 0.2 and "0.15" in body["limit"]
    # force envelope: IUT_a at 10 bar cannot be pushed 0.1 m
    r = client.post("/api/tests", json=sine_test(supply_bar=10, profile={"amplitude_m": 0.1, "frequency_hz": 0.2}),
                    headers=AUTH)
    assert r.status_code == 422 and "A_p P_s" in r.json()["limit"]
    r = client.post("/api/tests", json=sine_test(supply_bar=500), headers=AUTH)
    assert r.status_code == 422 and r.json()["field"] == "supply_bar" and r.json()["value"] == 500


def test_other_validation_errors(client):
    cases = [
        (sine_test(isolator="unknown_iso"), "isolator"),
        (sine_test(controller="lqr"), "controller"),
        (sine_test(speed=0), "speed"),
        (sine_test(speed=1000), "speed"),
        (sine_test(profile={"taper_cycles": 5}), "profile.taper_cycles"),
        (sine_test(profile={"kind": "square"}), "profile"),
        (sine_test(limits={"displacement_m": 1.0}), "limits.displacement_m"),
        (sine_test(limits={"force_n": -1}), "limits.force_n"),
        ({**sine_test(), "extra": 1}, "extra"),
        ({k: v for k, v in sine_test().items() if k != "supply_bar"}, "supply_bar"),
    ]
    for body, field in cases:
        r = client.post("/api/tests", json=body, headers=AUTH)
        assert r.status_code == 422, (body, r.text)
        out = r.json()
        assert isinstance(out["detail"], str) and out["detail"]
        assert out["field"].startswith(field), (field, out)
    r = client.post("/api/tests", content=b'{"supply_bar": NaN}', headers={**AUTH, "content-type": "application/json"})
    assert r.status_code == 422


def test_list_filters_and_404(client):
    ids = [client.post("/api/tests", json=sine_test(isolator=iso), headers=AUTH).json()["id"]
           for iso in ("IUT_a", "IUT_b", "IUT_a")]
    assert [t["id"] for t in client.get("/api/tests").json()] == ids[::-1]
    assert {t["id"] for t in client.get("/api/tests", params={"isolator": "IUT_b"}).json()} == {ids[1]}
    assert len(client.get("/api/tests", params={"status": "ready"}).json()) == 3
    assert client.get("/api/tests", params={"status": "completed"}).json() == []
    assert client.get("/api/tests", params={"status": "bogus"}).status_code == 422
    assert len(client.get("/api/tests", params={"since": "2000-01-01T00:00:00Z"}).json()) == 3
    assert client.get("/api/tests", params={"until": "2000-01-01T00:00:00Z"}).json() == []
    assert client.get("/api/tests/999").status_code == 404
    assert client.get("/api/tests/999/cycles").status_code == 404
    assert client.get("/api/tests/999/data.csv").status_code == 404
    assert client.get("/api/tests/0").status_code == 422


def test_state_conflicts_and_delete(client):
    test_id = client.post("/api/tests", json=sine_test(), headers=AUTH).json()["id"]
    assert client.post(f"/api/tests/{test_id}/stop", headers=AUTH).status_code == 409
    assert client.post(f"/api/tests/{test_id}/abort", headers=AUTH).status_code == 409
    r = client.delete(f"/api/tests/{test_id}", headers=AUTH)
    assert r.status_code == 204
    assert client.get(f"/api/tests/{test_id}").status_code == 404
    # the audit log keeps the deletion
    events = client.get("/api/events", params={"test_id": test_id}).json()
    assert any("deleted" in e["message"] for e in events)


def test_reports_route_answers(client):
    test_id = client.post("/api/tests", json=sine_test(), headers=AUTH).json()["id"]
    try:
        import backend.reports  # noqa: F401
    except ImportError:
        r = client.get(f"/api/tests/{test_id}/report.json")
        assert r.status_code == 503 and "reports" in r.json()["detail"]
        return
    r = client.get(f"/api/tests/{test_id}/report.json")
    assert r.status_code == 200, r.text
    assert r.headers["content-type"].startswith("application/json")
    assert client.get("/api/tests/999/report.json").status_code == 404


def test_protocol_profiles(client):
    pytest.importorskip("sim.protocols")
    body = {**sine_test(), "profile": {"kind": "protocol", "name": "quick_check"}}
    r = client.post("/api/tests", json=body, headers=AUTH)
    assert r.status_code == 201, r.text
    rec = r.json()
    assert len(rec["scenario"]["profile"]) >= 1 and rec["profile"] == {"kind": "protocol", "name": "quick_check",
                                                                        "protocol": None,
                                                                        "design_displacement_m": None,
                                                                        "frequency_hz": None}
    assert rec["cycles_total"] == sum(b["cycles"] for b in rec["scenario"]["profile"])
    # scaled to another design displacement: every level in proportion (the one parser, sim.protocols)
    scaled = {**body, "profile": {"kind": "protocol", "name": "quick_check", "design_displacement_m": 0.01}}
    r = client.post("/api/tests", json=scaled, headers=AUTH)
    assert r.status_code == 201, r.text
    amplitudes = [b["amplitude_m"] for b in r.json()["scenario"]["profile"]]
    assert amplitudes == pytest.approx([0.5 * b["amplitude_m"] for b in rec["scenario"]["profile"]])
    # at the specimen's design frequency: every level, and the test's length with it
    slower = {**body, "profile": {"kind": "protocol", "name": "quick_check", "frequency_hz": 0.25}}
    r = client.post("/api/tests", json=slower, headers=AUTH)
    assert r.status_code == 201, r.text
    assert {b["frequency_hz"] for b in r.json()["scenario"]["profile"]} == {0.25}
    assert r.json()["duration_s"] > rec["duration_s"] and r.json()["profile"]["frequency_hz"] == 0.25
    r = client.post("/api/tests", json={**body, "profile": {**slower["profile"], "frequency_hz": -1}}, headers=AUTH)
    assert r.status_code == 422 and r.json()["field"] == "profile.frequency_hz", r.text
    for profile, field in (({"kind": "protocol", "name": "/etc/passwd"}, "profile.name"),
                           ({"kind": "protocol"}, "profile"),
                           ({"kind": "protocol", "protocol": {"name": "x"}}, "profile")):
        r = client.post("/api/tests", json={**sine_test(), "profile": profile}, headers=AUTH)
        assert r.status_code == 422, r.text
        assert r.json()["field"].startswith(field)


def test_envelope_check_explains_without_creating(client):
    before = len(client.get("/api/tests").json())
    ok = client.post("/api/tests/check", json=sine_test(isolator="IUT_b", supply_bar=70,
                                                       profile={"amplitude_m": 0.03, "frequency_hz": 0.5}))
    assert ok.status_code == 200
    body = ok.json()
    assert body["ok"] is True
    assert 0.03 < body["max_amplitude_m"] <= 0.15
    assert body["max_frequency_hz"] > 0.5
    assert body["max_force_n"] > 5e4
    # pump flow refused: 200 with the field, the limit, and the highest frequency that fits
    refused = client.post("/api/tests/check", json=sine_test(isolator="IUT_b", supply_bar=150,
                                                             profile={"amplitude_m": 0.1, "frequency_hz": 1.0}))
    assert refused.status_code == 200
    r = refused.json()
    assert r["ok"] is False and r["field"] == "frequency_hz" and "l/min" in r["detail"] and r["limit"]
    assert 0 < r["max_frequency_hz"] < 1.0
    assert r["max_amplitude_m"] < 0.1
    # beyond the cylinder's force at any frequency: no highest frequency (null), and the refusal says so
    r = client.post("/api/tests/check", json=sine_test(profile={"amplitude_m": 0.1, "frequency_hz": 1.0})).json()
    assert r["ok"] is False and r["max_frequency_hz"] is None and 0 < r["max_amplitude_m"] < 0.1
    assert "no frequency fits amplitude_m = 0.1 m" in r["detail"], r["detail"]
    # an unknown isolator or a bad protocol name is a refusal too, never a 500
    assert client.post("/api/tests/check", json=sine_test(isolator="nope")).json()["ok"] is False
    proto = client.post("/api/tests/check", json=sine_test(profile={"kind": "protocol", "name": "/etc/passwd"}))
    assert proto.status_code in (200, 422) and proto.json().get("ok") is not True
    assert len(client.get("/api/tests").json()) == before  # nothing was created


def test_the_vertical_load_is_a_condition_of_the_test(client):
    from conftest import AUTH, sine_test

    r = client.post("/api/tests", json=sine_test(vertical_load_n=4e5), headers=AUTH)
    assert r.status_code == 201 and r.json()["vertical_load_n"] == 4e5
    assert r.json()["scenario"]["vertical_load_n"] == 4e5
    r = client.post("/api/tests", json=sine_test(), headers=AUTH)
    assert r.json()["vertical_load_n"] == 1.25e5  # the paper's, the rig's default
    for bad in (-5.0, 9e5):
        r = client.post("/api/tests", json=sine_test(vertical_load_n=bad), headers=AUTH)
        body = r.json()
        assert r.status_code == 422 and body["field"] == "vertical_load_n" and "850000" in body["limit"], body
    assert client.post("/api/tests/check", json=sine_test(vertical_load_n=9e5)).json()["ok"] is False
    rig = client.get("/api/rig").json()["envelope"]
    assert rig["max_vertical_load_n"] == 850e3 and rig["vertical_load_n_default"] == 1.25e5
    # a user isolator's design load is the default of its tests
    iso = {"name": "LRB_design", "rho_bw_per_m": 150.0, "sigma_bw": 0.5, "n": 1.0, "kd_n_per_m": 7e5,
           "kw_n": 4e4, "design_vertical_load_n": 3.5e5}
    assert client.post("/api/isolators", json=iso, headers=AUTH).status_code == 201
    r = client.post("/api/tests", json=sine_test(isolator="LRB_design"), headers=AUTH)
    assert r.status_code == 201 and r.json()["vertical_load_n"] == 3.5e5
    bad_iso = {**iso, "name": "LRB_kN", "design_vertical_load_n": -1}
    r = client.post("/api/isolators", json=bad_iso, headers=AUTH)
    assert r.status_code == 422 and "design_vertical_load_n" in r.json()["detail"]


def test_controller_options_travel_with_the_test_and_are_checked(client):
    from conftest import AUTH, sine_test

    r = client.post("/api/tests", json=sine_test(controller="mrac", controller_options={"gamma": 5e4}), headers=AUTH)
    assert r.status_code == 201 and r.json()["scenario"]["controller_options"] == {"gamma": 5e4}
    r = client.post("/api/tests", json=sine_test(controller="mrac", controller_options={"gamma": -1}), headers=AUTH)
    body = r.json()
    assert r.status_code == 422 and body["field"] == "controller_options.gamma" and "range" in body["detail"]
    r = client.post("/api/tests", json=sine_test(controller="pid", controller_options={"gama": 1}), headers=AUTH)
    assert r.status_code == 422 and "unknown pid option" in r.json()["detail"]
    check = client.post("/api/tests/check", json=sine_test(controller="mrac", controller_options={"x_clip": 2}))
    assert check.json()["ok"] is False and check.json()["field"] == "controller_options.x_clip"
    # a servo loop that cannot keep its margin on the rig in force is refused before anything moves (loop_design)
    unstable = {"kp_per_s": 200.0, "min_kp_share": 1.0}
    r = client.post("/api/tests", json=sine_test(controller="servo", controller_options=unstable), headers=AUTH)
    body = r.json()
    assert r.status_code == 422 and body["field"] == "controller_options.kp_per_s", body
    assert "cannot be made stable enough" in body["detail"] and "Lower kp_per_s" in body["detail"]
    check = client.post("/api/tests/check", json=sine_test(controller="servo", controller_options=unstable)).json()
    assert check["ok"] is False and check["field"] == "controller_options.kp_per_s"
    controllers = {c["name"]: c for c in client.get("/api/rig").json()["controllers"]}
    assert controllers["servo"]["default"] and controllers["mrac"]["adapted"][3]["unit"] == "m"


def test_who_and_what_travel_with_the_test(client):
    from conftest import AUTH, sine_test

    r = client.post("/api/tests", json=sine_test(specimen_id="LRB-2026-017", operator_name="M. Rossi",
                                                 notes="bearing 3 of 4, as delivered"), headers=AUTH)
    rec = r.json()
    assert r.status_code == 201 and rec["specimen_id"] == "LRB-2026-017"
    assert rec["operator_name"] == "M. Rossi (through automation)"  # the service account keeps the name given
    assert client.get(f"/api/tests/{rec['id']}").json()["notes"] == "bearing 3 of 4, as delivered"
    r = client.post("/api/tests", json=sine_test(specimen_id="x" * 65), headers=AUTH)
    assert r.status_code == 422


def test_the_api_schema_of_a_test_declares_every_field_of_the_record(client):
    """One test record: store.test_record builds it for the API, the export and the report; TestOut (the
    OpenAPI schema) must name each of its fields, so neither can grow without the other."""
    from backend.schemas import TestOut

    test_id = create_and_start(client)
    record = wait_for(client, test_id)
    assert set(record) == set(TestOut.model_fields)
    documented = client.get("/openapi.json").json()["components"]["schemas"]["TestOut"]["properties"]
    assert set(documented) == set(record)
