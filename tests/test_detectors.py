"""The engine's run with the service's detectors gives a test the verdict the service's worker gives it
(sim.detectors; backend.worker.run_here is the service's loop on the simulated rig), and the first cycle's
prediction finds the trip the issue 23 case meets."""

import numpy as np
import pytest

from backend.worker import run_here
from sim.detectors import CHECK_PERIODS, first_cycle_s, predict_first_trip
from sim.engine import Scenario, Simulation
from sim.rig import DEFAULT_RIG
from sim.safety import default_limits, make_limits


def paper_case(controller="mrac", frequency_hz=0.5, cycles=3):
    """Issue 23: the paper's section V scenario, IUT_b at 70 bar, 30 mm."""
    return Scenario.sine("IUT_b", 70.0, 0.03, frequency_hz, cycles, controller=controller)


def worker_verdict(scenario, limits):
    spec = {"isolator": scenario.isolator.to_dict(), "supply_pa": scenario.supply_pa,
            "vertical_load_n": scenario.effective_vertical_load_n, "profile": [b.to_dict() for b in scenario.profile],
            "controller": scenario.controller, "controller_options": {}, "rig_changes": {}}
    job = {"test_id": None, "rig": "simulated", "speed": 1e6, "scenario": spec, "limits": limits.to_dict(),
           "realtime": False}
    _run, sent, status, reason = run_here(job)
    return status, reason, sent.samples(), sent.of_kind("event")


CASES = {
    "mrac trips the pump-flow velocity limit": (paper_case(), None),
    "servo runs to the end": (paper_case("servo", cycles=2), None),
    "a controlled-stop displacement limit inside the sine (the guard)": (
        paper_case("servo", cycles=2), {"displacement_m": 0.02, "actions": {"displacement_m": "controlled_stop"}}),
    "a controlled-stop velocity limit, then the valve closes on another": (
        paper_case("servo", cycles=2), {"velocity_m_per_s": 0.05, "actions": {"velocity_m_per_s": "controlled_stop"}}),
    "an indicating force limit": (paper_case("servo", cycles=2), {"force_n": 2e4, "actions": {"force_n": "indicate"}}),
}


@pytest.mark.parametrize("name", list(CASES))
def test_the_engine_gives_the_workers_verdict(name):
    scenario, asked = CASES[name]
    limits = make_limits(DEFAULT_RIG, asked)
    status, reason, samples, events = worker_verdict(scenario, limits)
    result = Simulation(scenario).run(follow=True, limits=limits)
    assert (result.status, result.reason) == (status, reason)
    assert len(result.samples) == len(samples)
    assert np.array_equal(result.samples.array, samples.array, equal_nan=True)
    indicated = [e["message"] for e in events if e["kind"] == "limit_indicate"]
    assert [i.message for i in result.indications] == indicated
    if name.startswith("mrac"):
        assert status == "aborted" and reason.startswith("velocity limit tripped (valve close)")
    elif name.startswith("servo"):
        assert status == "completed" and reason is None
    elif "indicating" in name:
        assert status == "completed" and indicated
    else:
        assert status == "aborted"


def test_the_first_cycle_prediction_finds_the_velocity_trip():
    scenario = paper_case(cycles=30)
    limits = default_limits(DEFAULT_RIG)
    predicted = predict_first_trip(scenario, limits)
    assert first_cycle_s(scenario) == pytest.approx(4.0)  # the taper-in and one steady cycle at 0.5 Hz
    assert predicted is not None and predicted.trip.detector == "velocity"
    full = Simulation(scenario).run(follow=True, limits=limits)
    assert predicted.trip.message == full.reason  # the trip the whole test meets, word for word
    assert "expected to trip in its first cycle" in predicted.warning()
    assert abs(predicted.to_dict()["values"]["velocity_m_per_s"]) > limits.velocity_m_per_s
    assert predict_first_trip(paper_case("servo", cycles=30), limits) is None


def test_the_prediction_runs_the_first_cycle_only():
    """At most PREDICTION_MAX_S of test time, whatever the test's length."""
    slow = Scenario.sine("IUT_a", 100.0, 0.01, 0.02, 5, taper_cycles=1)
    assert first_cycle_s(slow) == pytest.approx(40.0)
    assert CHECK_PERIODS == 10


def test_a_study_is_judged_as_the_service_would_and_runs_on():
    """isorig compare's runs (sim.engine.run_judged): the service's status and reason, the figures of the whole
    run; not judged with detectors=False."""
    from sim.engine import run_judged

    scenario = paper_case()
    acted = Simulation(scenario).run(follow=True, limits=default_limits(DEFAULT_RIG))
    judged = run_judged(scenario)
    assert (judged.status, judged.reason) == (acted.status, acted.reason) and judged.ran_past_trip
    assert len(judged.samples) == scenario.n_periods > len(acted.samples)
    assert judged.summary()["ran_past_trip"] is True
    free = run_judged(scenario, detectors=False)
    assert free.status == "completed" and free.trip is None
    assert np.array_equal(free.samples.array, judged.samples.array, equal_nan=True)


def _drawn_rigs():
    """A small campaign: rigs drawn from docs/examples/unknown_rigs.toml's ranges, run uncommissioned at 2 mm
    1 Hz and 20 mm 0.5 Hz (oscillation and tracking stops, rigs that follow), and the lab spread's pid (a
    tracking stop at the end of its first steady cycle)."""
    from pathlib import Path

    from sim.campaign import load_campaign

    campaign = load_campaign(Path(__file__).resolve().parents[1] / "docs" / "examples" / "unknown_rigs.toml")
    campaign.runs = 6
    out = {}
    for run, (plant, seed) in enumerate(campaign.draws()):
        for amplitude_m, frequency_hz in ((0.002, 1.0), (0.02, 0.5)):
            out[f"drawn rig {run}, {amplitude_m * 1e3:g} mm"] = (
                Scenario.sine("IUT_a", 100.0, amplitude_m, frequency_hz, 10, plant_changes=plant, noise_seed=seed),
                None)
    out["pid on a heavier rig"] = (Scenario.sine("IUT_a", 100.0, 0.02, 1.0, 10, controller="pid",
                                                 plant_changes={"mass_kg": 1400.0, "dead_zone_v": 0.9}), None)
    return out


SOFT_RIG = {"mass_kg": 3000.0, "bulk_modulus_pa": 4.5e8}
COMPARED = {**CASES, **_drawn_rigs(),
            "a soft rig: servo": (Scenario.sine("IUT_a", 100.0, 0.02, 0.5, 10, plant_changes=SOFT_RIG), None),
            "a soft rig: mrac": (Scenario.sine("IUT_a", 100.0, 0.02, 0.5, 10, controller="mrac",
                                               plant_changes=SOFT_RIG), None)}


def _trip(trip):
    return None if trip is None else (trip.detector, trip.index, trip.time_s, trip.message, repr(trip.values),
                                      trip.action)


@pytest.mark.parametrize("name", list(COMPARED))
def test_the_compiled_detectors_give_the_reference_trips(name):
    """The follow detector compiled and each detector fed once per run (sim.follow._judge_blocks,
    RunDetectors.first_trip_period) against the per-block numpy path fed as before (``reference_detectors``):
    the same trip (detector, row, time, message, values, action), indications and rows, acted on and judged
    only (isorig compare)."""
    scenario, asked = COMPARED[name]
    limits = make_limits(scenario.rig, asked)
    for act in (True, False):
        fast = Simulation(scenario, validate=False).run(follow=True, limits=limits, act=act)
        slow = Simulation(scenario, validate=False).run(follow=True, limits=limits, act=act, reference_detectors=True)
        assert _trip(fast.trip) == _trip(slow.trip), (name, act)
        assert (fast.status, fast.reason) == (slow.status, slow.reason)
        assert [_trip(i) for i in fast.indications] == [_trip(i) for i in slow.indications]
        assert np.array_equal(fast.samples.array, slow.samples.array, equal_nan=True)
    kind = None if fast.trip is None else fast.trip.values.get("kind", fast.trip.detector)
    expected = {"mrac trips the pump-flow velocity limit": "velocity", "a soft rig: servo": "oscillation",
                "a soft rig: mrac": "tracking", "pid on a heavier rig": "tracking",
                "a controlled-stop displacement limit inside the sine (the guard)": "displacement"}
    if name in expected:  # every kind of trip is compared
        assert kind == expected[name]
