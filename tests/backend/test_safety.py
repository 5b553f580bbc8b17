"""Safety: each limit detector, and limit trips on a running test (controlled stop, event with values)."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import create_and_start, wait_for

from backend.safety import LimitError, SafetyLimits, check_block, command_ramp, make_limits
from sim.engine import C_FORCE, C_PL, C_TARGET, C_TIME, C_U, C_Y, COLUMNS
from sim.rig import DEFAULT_RIG

LIMITS = SafetyLimits(displacement_m=0.1, force_n=1e5, load_pressure_pa=2e7, tracking_error_m=0.005)


def rows(n=20):
    r = np.zeros((n, len(COLUMNS)))
    r[:, C_TIME] = np.arange(n) * 1e-3
    return r


@pytest.mark.parametrize(("column", "value", "detector"), [
    (C_Y, 0.12, "displacement"), (C_Y, -0.12, "displacement"), (C_FORCE, -2e5, "force"),
    (C_PL, 2.5e7, "load_pressure"), (C_TARGET, 0.006, "tracking_error"), (C_Y, np.nan, "non_finite"),
    (C_U, np.inf, "non_finite"),
])
def test_each_detector_trips_on_its_quantity(column, value, detector):
    r = rows()
    assert check_block(r, LIMITS) is None
    r[7, column] = value
    trip = check_block(r, LIMITS)
    assert trip is not None and trip.detector == detector and trip.index == 7
    assert abs(trip.time_s - 0.007) < 1e-12
    if detector != "non_finite":
        assert trip.values["limit"] > 0 and "limit" in trip.message


def test_first_offending_sample_wins_and_ramp_rows_skip_tracking():
    r = rows()
    r[12, C_Y] = 0.2
    r[5, C_FORCE] = 3e5
    assert check_block(r, LIMITS).detector == "force"
    r = rows()
    r[:, C_TARGET] = np.nan  # open-loop ramp rows have no target
    r[:, C_Y] = 0.05
    assert check_block(r, LIMITS) is None


def test_limits_bounded_by_the_rig():
    assert make_limits(DEFAULT_RIG, None).displacement_m == DEFAULT_RIG.stroke_m
    assert make_limits(DEFAULT_RIG, {"tracking_error_m": 0.002}).tracking_error_m == 0.002
    with pytest.raises(LimitError, match="hard limit"):
        make_limits(DEFAULT_RIG, {"displacement_m": 0.5})
    with pytest.raises(LimitError):
        make_limits(DEFAULT_RIG, {"force_n": 0})


def test_command_ramp_reaches_zero():
    ramp = command_ramp(4.0, 0.1, 1e-3)
    assert len(ramp) == 100 and ramp[-1] == 0.0 and np.all(np.diff(ramp) < 0)


@pytest.mark.parametrize(("limits", "detector"), [
    ({"tracking_error_m": 0.0002}, "tracking_error"),
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
    assert rec["reason"] == trip[0]["message"] and key in rec["reason"]
    data = client.get(f"/api/tests/{test_id}/data.csv").text.splitlines()[1:]
    last = [r.split(",") for r in data[-100:]]
    voltage = np.array([float(r[4]) for r in last])
    assert voltage[-1] == 0.0  # the valve command ramped to zero ...
    assert np.all(np.abs(np.diff(voltage)) < 0.2)  # ... without a step
    assert all(r[1] == "" for r in last)  # open loop: no target during the ramp
    assert float(data[-1].split(",")[0]) < 1.45  # the test ended early
