"""Limits the operator sets, each with an action (indicate, controlled stop, valve close), and the velocity
limit: the detectors on blocks, and what a running test does when one fires."""

from __future__ import annotations

import shutil
import subprocess

import numpy as np
import pytest
from conftest import AUTH, create_and_start, sine_test, wait_for

from backend.safety import (
    INDICATIONS_RECORDED,
    VELOCITY_SPAN_PERIODS,
    LimitError,
    SafetyLimits,
    SafetyMonitor,
    check_block,
    make_limits,
    measured_velocity,
)
from sim.measurement import STATUS_ARMED
from sim.rig import DEFAULT_RIG
from sim.samples import Samples


def sine_rows(t0: int, n: int, amplitude_m=0.01, frequency_hz=2.0) -> Samples:
    r = Samples(np.zeros((n, len(Samples.empty().fields))))
    k = t0 + np.arange(n)
    r["time_s"] = k * 1e-3
    r["measured_displacement_m"] = amplitude_m * np.sin(2 * np.pi * frequency_hz * k * 1e-3)
    r["target_m"] = r["measured_displacement_m"]
    r["supply_pressure_pa"] = 100e5
    r["flags"] = STATUS_ARMED
    return r


def limits(**changes) -> SafetyLimits:
    return make_limits(DEFAULT_RIG, changes)


def test_velocity_is_the_measured_displacement_difference_across_blocks():
    y = 0.01 * np.sin(2 * np.pi * 2.0 * np.arange(2000) * 1e-3)
    whole = measured_velocity(y)
    pieces = np.concatenate([measured_velocity(y[:700]), measured_velocity(y[700:], y[:700])])
    assert np.all(np.isnan(whole[:VELOCITY_SPAN_PERIODS]))
    np.testing.assert_allclose(pieces[VELOCITY_SPAN_PERIODS:], whole[VELOCITY_SPAN_PERIODS:], rtol=0, atol=1e-12)
    peak = 2 * np.pi * 2.0 * 0.01  # 0.1257 m/s; the 5-period difference reads it within 0.1 %
    assert np.nanmax(np.abs(whole)) == pytest.approx(peak, rel=1e-3)


def test_velocity_limit_trips_at_the_first_sample_beyond_it():
    lim = limits(velocity_m_per_s=0.1)
    trip = check_block(sine_rows(0, 200), lim)
    assert trip is not None and trip.detector == "velocity" and trip.action == "valve_close"
    assert abs(trip.values["velocity_m_per_s"]) > 0.1 and trip.values["limit_name"] == "velocity_m_per_s"
    assert "velocity limit tripped (valve close)" in trip.message
    # in words and readable units, no API names: "|velocity| 100.3 mm/s beyond the limit of 100 mm/s"
    seen = abs(trip.values["velocity_m_per_s"]) * 1e3
    assert trip.message.endswith(f": |velocity| {seen:.4g} mm/s beyond the limit of 100 mm/s"), trip.message
    assert "velocity_m_per_s" not in trip.message
    assert check_block(sine_rows(0, 200), limits(velocity_m_per_s=0.13)) is None


def test_an_indicating_limit_never_trips_and_indicates_once_per_excursion():
    lim = limits(displacement_m=0.008, actions={"displacement_m": "indicate"})
    monitor = SafetyMonitor(lim, 100e5)
    indications = []
    for t0 in range(0, 2000, 10):  # 4 cycles at 2 Hz in blocks of 10 periods: 8 excursions beyond 8 mm
        assert monitor.check(sine_rows(t0, 10)) is None
        indications += monitor.take_indications()
    assert monitor.indication_counts == {"displacement_m": 8}
    assert len(indications) == 8 and all(i.action == "indicate" for i in indications)
    times = [i.time_s for i in indications]
    assert times == sorted(times) and np.all(np.diff(times) > 0.2)  # one per half cycle, not one per sample
    assert all(abs(i.values["displacement_m"]) > 0.008 for i in indications)
    assert "exceeded (indicated)" in indications[0].message


def test_indications_beyond_the_recorded_ones_are_only_counted():
    lim = limits(force_n=1.0, actions={"force_n": "indicate"})
    monitor = SafetyMonitor(lim, 100e5)
    recorded = []
    for t0 in range(0, 40 * 20, 20):
        r = sine_rows(t0, 20)
        r["force_n"] = np.where(np.arange(20) < 10, 5.0, 0.0)  # one excursion per block
        monitor.check(r)
        recorded += monitor.take_indications()
    assert monitor.indication_counts["force_n"] == 40
    assert len(recorded) == INDICATIONS_RECORDED and "counted" in recorded[-1].message


def test_actions_are_checked_and_kept_with_the_limits():
    lim = limits(force_n=5e4, actions={"force_n": "controlled_stop", "velocity_m_per_s": "indicate"})
    stored = lim.to_dict()
    assert stored["actions"] == {"displacement_m": "valve_close", "force_n": "controlled_stop",
                                 "velocity_m_per_s": "indicate", "load_pressure_pa": "valve_close",
                                 "tracking_error_m": "valve_close"}
    assert SafetyLimits.from_dict(stored) == lim
    old = {"displacement_m": 0.15, "force_n": 3e5, "load_pressure_pa": 2.1e7, "tracking_error_m": 0.05}
    assert SafetyLimits.from_dict(old).velocity_m_per_s is None  # a record made before velocity limits
    with pytest.raises(LimitError, match="not an action; allowed: indicate, controlled_stop, valve_close"):
        limits(actions={"force_n": "hold"})
    with pytest.raises(LimitError, match="speed is not a limit"):
        limits(actions={"speed": "indicate"})
    with pytest.raises(LimitError, match="hard limit"):
        limits(velocity_m_per_s=50.0)


def test_the_api_refuses_a_bad_action_with_the_allowed_ones(client):
    r = client.post("/api/tests", headers=AUTH, json=sine_test(limits={"actions": {"force_n": "stop"}}))
    assert r.status_code == 422 and "indicate" in r.text and "controlled_stop" in r.text
    r = client.post("/api/tests", headers=AUTH, json=sine_test(limits={"actions": {"stroke": "indicate"}}))
    assert r.status_code == 422 and r.json()["field"] == "limits.actions.stroke"
    assert client.get("/api/tests").json() == []  # nothing left behind


def test_an_indicating_limit_lets_the_test_run_to_its_end(client):
    test_id = create_and_start(client, limits={"displacement_m": 0.008, "actions": {"displacement_m": "indicate"}})
    rec = wait_for(client, test_id)
    assert rec["status"] == "completed" and rec["limits"]["actions"]["displacement_m"] == "indicate"
    shown = [e for e in rec["events"] if e["kind"] == "limit_indicate"]
    # 3 cycles of 10 mm with a taper in and out: the steady cycle's two peaks at least go beyond 8 mm
    assert len(shown) >= 2 and all(abs(e["values"]["displacement_m"]) > 0.008 for e in shown)
    assert rec["summary"]["limit_indications"]["displacement_m"] == len(shown)
    assert not [e for e in rec["events"] if e["kind"] == "limit_trip"]
    # the report names the limit, its action and how often it was exceeded
    report = client.get(f"/api/tests/{test_id}/report.json").json()
    assert report["limit_indications"] == {"displacement_m": len(shown)} and report["limit_trips"] == []
    assert any("exceeded (indicated)" in e["text"] and "displacement y" in e["text"] for e in report["events"])
    pdftotext = shutil.which("pdftotext")
    if pdftotext is not None:
        pdf = client.get(f"/api/tests/{test_id}/report.pdf").content
        text = subprocess.run([pdftotext, "-", "-"], input=pdf, capture_output=True, check=True, timeout=60).stdout
        page1 = " ".join(text.decode().split("\f")[0].split())
        assert "|y| <= 8 mm (indicate)" in page1 and f"displacement_m: {len(shown)} times (the test went on)" in page1


def test_a_controlled_stop_brakes_the_target_to_rest_under_control(client):
    """Issue 21: a controlled stop no longer tapers the running sine out (that went on to the sine's peak). The
    target brakes to rest from where it is, continuous in position and speed, and holds there, closed loop."""
    test_id = create_and_start(client, limits={"force_n": 2000.0, "actions": {"force_n": "controlled_stop"}},
                               profile={"cycles": 6})
    rec = wait_for(client, test_id)
    assert rec["status"] == "aborted" and "controlled stop" in rec["reason"]
    trip = [e for e in rec["events"] if e["kind"] == "limit_trip"]
    assert trip[0]["values"]["action"] == "controlled_stop"
    rows = csv_rows(client, test_id)
    t = np.array([float(r[0]) for r in rows])
    after = [r for r, ti in zip(rows, t, strict=True) if ti > trip[0]["time_s"]]
    target = np.array([float(r[1]) for r in after])  # closed loop to the end: every row has a target
    y = np.array([float(r[3]) for r in after])
    assert all(r[1] != "" for r in after)
    # the target comes to rest: its last 0.4 s do not move, and the table rests there within 0.05 mm
    assert np.ptp(target[-400:]) == 0.0 and np.max(np.abs(y[-100:] - target[-1])) < 5e-5
    # no step: the target moves no more in one period than the sine's top speed (2 pi f A T) allows
    assert np.max(np.abs(np.diff(target))) < 1.1 * 2 * np.pi * 2.0 * 0.01 * 1e-3
    # it did not go on to the sine's peak: the rest point is nearer than 10 mm
    assert abs(target[-1]) < 0.0095
    assert t[-1] < trip[0]["time_s"] + 0.7  # a braking stop of < 0.2 s, held 0.5 s


def test_a_controlled_stop_never_passes_its_displacement_limit(client):
    """Issue 21: a 15 mm controlled-stop limit on a 30 mm sine went on to 26 mm. The displacement guard now brakes
    the target so that it comes to rest within the limit less the recent tracking error."""
    test_id = create_and_start(client, isolator="IUT_b", supply_bar=70.0,
                               limits={"displacement_m": 0.015, "actions": {"displacement_m": "controlled_stop"}},
                               profile={"amplitude_m": 0.03, "frequency_hz": 0.5, "cycles": 3})
    rec = wait_for(client, test_id)
    assert rec["status"] == "aborted" and "controlled stop" in rec["reason"] and "15 mm" in rec["reason"]
    trip = [e for e in rec["events"] if e["kind"] == "limit_trip"][0]
    assert trip["values"]["detector"] == "displacement" and trip["values"]["guard"]
    rows = csv_rows(client, test_id)
    y = np.abs(np.array([float(r[3]) for r in rows]))
    assert y.max() <= 0.015 and y.max() > 0.0145  # within the limit, and it did reach near it
    assert abs(float(rows[-1][3])) > 0.0145  # at rest there, not back to zero


def csv_rows(client, test_id: int) -> list[list[str]]:
    return [r.split(",") for r in client.get(f"/api/tests/{test_id}/data.csv").text.splitlines()[1:]]


def test_a_valve_close_trip_overrules_a_controlled_stop(client):
    # a reference run: the force where |y| first passes 2 mm
    reference_id = create_and_start(client, profile={"cycles": 6, "taper_cycles": 0})
    reference = csv_rows(client, wait_for(client, reference_id)["id"])
    y = np.array([float(r[3]) for r in reference])
    f = np.abs(np.array([float(r[5]) for r in reference]))
    force_limit = f[np.flatnonzero(np.abs(y) > 0.002)[0]]
    # without a taper-in the target starts at its top speed: the velocity limit asks for a controlled stop at
    # once, and the braking stop goes on outwards beyond 2 mm: the force limit (valve close) fires during it
    # and closes the valve
    test_id = create_and_start(client, limits={"velocity_m_per_s": 0.06, "force_n": force_limit,
                                               "actions": {"velocity_m_per_s": "controlled_stop"}},
                               profile={"cycles": 6, "taper_cycles": 0})
    rec = wait_for(client, test_id)
    trips = [e for e in rec["events"] if e["kind"] == "limit_trip"]
    assert rec["status"] == "aborted" and trips[0]["values"]["detector"] == "velocity"
    assert len(trips) == 2 and trips[1]["values"]["detector"] == "force" and trips[1]["values"]["escalation"]
    assert "the valve closes" in trips[1]["message"]
    rows = csv_rows(client, test_id)
    assert rows[-1][1] == "" and float(rows[-1][4]) == 0.0  # ended open loop, the valve command at 0 V
