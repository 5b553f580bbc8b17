"""Safety: each limit detector, and limit trips on a running test (controlled stop, event with values)."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import create_and_start, wait_for

from backend.safety import (
    FROZEN_PERIODS,
    FROZEN_SATURATED_PERIODS,
    LimitError,
    SafetyLimits,
    SafetyMonitor,
    check_block,
    make_limits,
)
from sim.measurement import FLAG_LOST, STATUS_ARMED, STATUS_SENSOR_FAULT, STATUS_WATCHDOG
from sim.rig import DEFAULT_RIG
from sim.samples import Samples

LIMITS = SafetyLimits(displacement_m=0.1, force_n=1e5, load_pressure_pa=2e7, tracking_error_m=0.005)


def rows(n=20):
    r = Samples(np.zeros((n, len(Samples.empty().fields))))
    r["time_s"] = np.arange(n) * 1e-3
    r["supply_pressure_pa"] = 100e5
    r["flags"] = STATUS_ARMED
    return r


@pytest.mark.parametrize(("field", "value", "detector"), [
    ("measured_displacement_m", 0.12, "displacement"), ("measured_displacement_m", -0.12, "displacement"),
    ("force_n", -2e5, "force"), ("load_pressure_pa", 2.5e7, "load_pressure"), ("target_m", 0.006, "tracking_error"),
    ("measured_displacement_m", np.nan, "non_finite"), ("voltage_v", np.inf, "non_finite"),
    ("supply_pressure_pa", np.nan, "non_finite"), ("supply_pressure_pa", 40e5, "supply_pressure"),
    ("flags", STATUS_ARMED | STATUS_SENSOR_FAULT, "rig_fault"), ("flags", STATUS_WATCHDOG, "rig_fault"),
])
def test_each_detector_trips_on_its_quantity(field, value, detector):
    r = rows()
    assert check_block(r, LIMITS, 100e5) is None
    r[field][7] = value
    trip = check_block(r, LIMITS, 100e5)
    assert trip is not None and trip.detector == detector and trip.index == 7
    assert abs(trip.time_s - 0.007) < 1e-12
    if detector not in ("non_finite", "rig_fault"):
        assert trip.values["limit"] > 0 and "limit" in trip.message or "lost" in trip.message
    if detector == "rig_fault":
        assert ("sensor fault" in trip.message) or ("watchdog" in trip.message)


def test_detectors_read_the_sensor_not_the_simulations_truth():
    r = rows()
    r["displacement_m"] = 0.5  # the true table (a simulation) beyond the stroke; the sensor reads 0
    assert check_block(r, LIMITS) is None


def test_first_offending_sample_wins_and_ramp_rows_skip_tracking():
    r = rows()
    r["measured_displacement_m"][12] = 0.2
    r["force_n"][5] = 3e5
    assert check_block(r, LIMITS).detector == "force"
    r = rows()
    r["target_m"] = np.nan  # open-loop ramp rows have no target
    r["measured_displacement_m"] = 0.05
    assert check_block(r, LIMITS) is None


def stuck_run(stuck_from, command_v, periods=600, n=30):
    """Blocks of n periods of a sine whose reading sticks at 1 mm from ``stuck_from`` on; the first trip."""
    monitor = SafetyMonitor(LIMITS, 100e5)
    for t0 in range(0, periods, n):
        r = rows(n)
        k = t0 + np.arange(n)
        r["time_s"] = k * 1e-3
        r["target_m"] = 0.004 * np.sin(2 * np.pi * k * 1e-3)
        r["measured_displacement_m"] = np.where(k < stuck_from, r["target_m"], 0.001)
        r["voltage_v"] = command_v
        trip = monitor.check(r)
        if trip is not None:
            return trip
    return None


def test_a_frozen_reading_trips_only_while_the_valve_is_open():
    tripped = stuck_run(150, command_v=3.0)
    assert tripped is not None and tripped.detector == "position_frozen"
    assert tripped.values["unchanged_periods"] >= FROZEN_PERIODS and "stuck" in tripped.message
    assert tripped.time_s == pytest.approx(0.25, abs=0.002)
    assert stuck_run(150, command_v=1.0) is None  # a nearly closed valve: a resting table reads the same
    assert stuck_run(150, command_v=np.where(np.arange(30) == 7, 0.0, 3.0)) is None  # the run must be unbroken
    # at rest nothing moves: the same reading is fine
    monitor = SafetyMonitor(LIMITS, 100e5)
    for _ in range(20):
        r = rows(30)
        r["measured_displacement_m"] = 0.001
        r["target_m"] = 0.001
        assert monitor.check(r) is None


def test_a_host_stall_is_not_a_stuck_sensor():
    """Issue 21: the host lost 40 periods (it held the last reading, flagged lost) with the valve at 9 V: the
    frozen-reading detector tripped on the host's own stall. Lost periods neither count nor break a run."""
    monitor = SafetyMonitor(LIMITS, 100e5)
    for t0 in range(0, 600, 30):
        r = rows(30)
        k = t0 + np.arange(30)
        r["time_s"] = k * 1e-3
        r["target_m"] = 0.004 * np.sin(2 * np.pi * k * 1e-3)
        lost = (k >= 200) & (k < 240)
        r["measured_displacement_m"] = np.where(lost, 0.004 * np.sin(2 * np.pi * 0.199), r["target_m"])
        r["flags"] = np.where(lost, FLAG_LOST, 0)
        r["voltage_v"] = 9.0
        assert monitor.check(r) is None, k[0]
    # the same readings not flagged lost: a stuck sensor
    monitor = SafetyMonitor(LIMITS, 100e5)
    trips = []
    for t0 in range(0, 600, 30):
        r = rows(30)
        k = t0 + np.arange(30)
        r["time_s"] = k * 1e-3
        r["target_m"] = 0.004 * np.sin(2 * np.pi * k * 1e-3)
        r["measured_displacement_m"] = np.where((k >= 200) & (k < 240), 0.004 * np.sin(2 * np.pi * 0.199),
                                                r["target_m"])
        r["voltage_v"] = 9.0
        trips.append(monitor.check(r))
    assert any(t is not None and t.detector == "position_frozen" for t in trips)
    # a stuck sensor across a lost stretch: the fresh readings before and after it still add up
    assert stuck_run(150, command_v=9.0) is not None


def test_a_wide_open_valve_finds_a_stuck_sensor_sooner():
    tripped = stuck_run(150, command_v=9.0)
    assert tripped is not None and tripped.detector == "position_frozen" and tripped.close_at_once
    assert tripped.values["unchanged_periods"] == FROZEN_SATURATED_PERIODS < FROZEN_PERIODS
    assert tripped.time_s == pytest.approx(0.150 + FROZEN_SATURATED_PERIODS * 1e-3, abs=0.002)
    assert "+-8 V" in tripped.message


def test_a_reading_beyond_the_stroke_is_a_sensor_fault_whatever_the_operators_limit():
    """An operator may let the displacement limit only indicate; a reading no table can give still closes
    the valve at once (the command came from it)."""
    indicate = {key: "indicate" for key in ("displacement_m", "velocity_m_per_s", "tracking_error_m")}
    lenient = SafetyLimits(displacement_m=0.1, force_n=1e5, load_pressure_pa=2e7, tracking_error_m=0.5,
                           velocity_m_per_s=100.0, actions=indicate)
    r = rows()
    r["measured_displacement_m"][9] = 1.0
    assert SafetyMonitor(lenient, 100e5).check(r) is None  # without the rig's stroke: only indications
    trip = SafetyMonitor(lenient, 100e5, sensor_range_m=DEFAULT_RIG.stroke_m).check(r)
    assert trip is not None and trip.detector == "sensor_range" and trip.index == 9
    assert trip.action == "valve_close" and trip.close_at_once
    assert "out of range" in trip.message and "1000 mm" in trip.message and "150 mm" in trip.message
    r["measured_displacement_m"][9] = -0.149  # inside the stroke: nothing but the operator's indication
    assert SafetyMonitor(lenient, 100e5, sensor_range_m=DEFAULT_RIG.stroke_m).check(r) is None


def test_only_sensor_faults_close_the_valve_at_once():
    r = rows()
    r["force_n"][3] = 3e5
    assert not check_block(r, LIMITS).close_at_once  # a limit: the command was sound, it ramps to 0 V


def test_limits_bounded_by_the_rig():
    assert make_limits(DEFAULT_RIG, None).displacement_m == DEFAULT_RIG.stroke_m
    assert make_limits(DEFAULT_RIG, {"tracking_error_m": 0.002}).tracking_error_m == 0.002
    with pytest.raises(LimitError, match="hard limit"):
        make_limits(DEFAULT_RIG, {"displacement_m": 0.5})
    with pytest.raises(LimitError):
        make_limits(DEFAULT_RIG, {"force_n": 0})


@pytest.mark.parametrize(("limits", "detector"), [
    ({"tracking_error_m": 0.00003}, "tracking_error"),
    ({"displacement_m": 0.004}, "displacement"),
    ({"force_n": 2000.0}, "force"),
    ({"load_pressure_pa": 5e5}, "load_pressure"),
])
def test_limit_trip_stops_the_test(client, limits, detector):
    test_id = create_and_start(client, limits=limits, speed=10.0)
    rec = wait_for(client, test_id)
    assert rec["status"] == "aborted"
    trip = [e for e in rec["events"] if e["kind"] == "limit_trip"]
    assert len(trip) == 1
    values = trip[0]["values"]
    assert values["detector"] == detector
    key = values["limit_name"]
    assert abs(values[key]) > values["limit"] == limits[key]
    assert rec["reason"] == trip[0]["message"] and key not in rec["reason"]  # in words, not the API's names
    assert rec["reason"].startswith(f"{detector.replace('_', ' ')} limit tripped (valve close) at t = ")
    data = client.get(f"/api/tests/{test_id}/data.csv").text.splitlines()[1:]
    last = [r.split(",") for r in data[-100:]]
    voltage = np.array([float(r[4]) for r in last])
    assert voltage[-1] == 0.0  # the valve command ramped to zero ...
    assert np.all(np.abs(np.diff(voltage)) < 0.2)  # ... without a step
    assert all(r[1] == "" for r in last)  # open loop: no target during the ramp
    assert float(data[-1].split(",")[0]) < 1.45  # the test ended early


def test_lost_periods_do_not_fake_a_velocity():
    """Six lost periods hold an older reading; the next fresh one is 7 periods of motion later. Read across
    the held rows, 0.28 m/s would look like 0.39 m/s (the burst the emulator test tripped on)."""
    limits = SafetyLimits(displacement_m=0.1, force_n=1e5, load_pressure_pa=2e7, tracking_error_m=0.05,
                          velocity_m_per_s=0.35)
    r = rows(40)
    true_y = 0.28 * r["time_s"]
    r["target_m"] = true_y
    lost = np.zeros(40, dtype=bool)
    lost[20:26] = True
    r["measured_displacement_m"] = np.where(lost, true_y[19], true_y)
    r["flags"] = np.where(lost, STATUS_ARMED | FLAG_LOST, STATUS_ARMED)
    assert SafetyMonitor(limits, 100e5).check(r) is None
    assert check_block(r, limits, 100e5) is None
    r["measured_displacement_m"][32:] += 0.002  # a real jump of 2 mm in one period is still seen
    trip = SafetyMonitor(limits, 100e5).check(r)
    assert trip is not None and trip.detector == "velocity" and trip.index == 32
