"""POST /api/tests/check warns when the chosen controller is expected to trip a limit in its first cycle (issue
23: mrac on IUT_b, 70 bar, 30 mm at 0.5 Hz lurches to -51 mm and trips the pump-flow velocity limit)."""

import time

from conftest import sine_test

PAPER_CASE = {"isolator": "IUT_b", "supply_bar": 70, "speed": 1.0,
              "profile": {"amplitude_m": 0.03, "frequency_hz": 0.5, "cycles": 10, "taper_cycles": 1}}


def check(client, **overrides):
    t0 = time.perf_counter()
    r = client.post("/api/tests/check", json=sine_test(**{**PAPER_CASE, **overrides}))
    assert r.status_code == 200, r.text
    return r.json(), time.perf_counter() - t0


def test_mrac_on_the_papers_case_is_warned_of_its_velocity_trip(client):
    answer, _s = check(client, controller="mrac")
    assert answer["ok"] is True  # within the envelope: a warning, not a refusal
    trip = answer["predicted_trip"]
    assert trip["detector"] == "velocity" and trip["action"] == "valve_close" and 1.0 < trip["time_s"] < 2.0
    assert abs(trip["values"]["velocity_m_per_s"]) > trip["values"]["limit"]
    assert len(answer["warnings"]) == 1
    warning = answer["warnings"][0]
    assert "expected to trip in its first cycle" in warning and "mrac" in warning
    assert "velocity limit tripped (valve close)" in warning
    # the very trip the service's worker meets on that test: what the record would say
    from backend.safety import default_limits
    from backend.worker import run_here
    from sim.isolator import load_isolator
    from sim.profiles import SineProfile
    from sim.rig import DEFAULT_RIG

    iso = load_isolator("IUT_b")
    spec = {"isolator": iso.to_dict(), "supply_pa": 70e5, "vertical_load_n": None, "controller": "mrac",
            "profile": [SineProfile(0.03, 0.5, 10, 1).to_dict()], "controller_options": {}, "rig_changes": {}}
    job = {"test_id": None, "rig": "simulated", "speed": 1e6, "scenario": spec, "realtime": False,
           "limits": default_limits(DEFAULT_RIG).to_dict()}
    _run, _sent, status, reason = run_here(job)
    assert status == "aborted" and reason == trip["message"]


def test_the_default_servo_on_the_same_test_has_no_warning(client):
    answer, _s = check(client, controller="servo")
    assert answer["ok"] is True and answer["warnings"] == [] and answer["predicted_trip"] is None
    assert answer["prediction"].endswith("no limit trips")


def test_the_warning_follows_the_limits_asked(client):
    """A velocity limit that only indicates does not stop the test: no trip to warn of."""
    answer, _s = check(client, controller="mrac", limits={"actions": {"velocity_m_per_s": "indicate"}})
    assert all("velocity limit" not in w for w in answer["warnings"])


def test_a_refused_test_is_not_simulated(client):
    answer, _s = check(client, controller="mrac", supply_bar=500)
    assert answer["ok"] is False and answer["warnings"] == [] and answer["prediction"] is None
