"""A table that cannot follow because the actuator has no more force to give is told as that, not as the
controller's loop or a rig file to commission again (sim.force_limit; issue 32 item 5)."""

import math

import numpy as np
import pytest

from sim.engine import Scenario, Simulation
from sim.force_limit import TRIP_SHARE, ActuatorLimits, at_force_limit, diagnosis
from sim.isolator import load_isolator


def rows(p_load_pa, supply_pa, voltage_v):
    return {"load_pressure_pa": np.asarray(p_load_pa, dtype=float),
            "supply_pressure_pa": np.asarray(supply_pa, dtype=float), "voltage_v": np.asarray(voltage_v, dtype=float)}


def test_each_way_has_its_own_limit_and_the_command_its_own():
    single = ActuatorLimits(command_limit_v=10.0, area_ratio_b=0.5)
    ps = 1e7
    got = at_force_limit(rows([0.95 * ps, 0.85 * ps, -0.46 * ps, -0.44 * ps, 0.0, 0.0, math.nan],
                              [ps] * 7, [0.0, 0.0, 0.0, 0.0, 9.95, -9.95, 0.0]), single)
    # pushing at 95 % of P_s, not at 85 %; pulling beyond 90 % of (A_B / A_A) P_s = 45 %, not at 44 %; the
    # command at its limit either way; a reading that is not a number is not a limit
    assert got.tolist() == [1, 0, -1, 0, 1, -1, 0]
    double = ActuatorLimits(command_limit_v=10.0)
    assert at_force_limit(rows([-0.46 * ps, -0.95 * ps], [ps, ps], [0.0, 0.0]), double).tolist() == [0, -1]


def test_the_diagnosis_needs_a_share_of_the_window_and_names_the_way_and_the_remedy():
    limits = ActuatorLimits(command_limit_v=10.0, area_ratio_b=0.5, max_supply_pa=2.1e7)
    window = np.zeros(1000, dtype=np.int8)
    window[: int(TRIP_SHARE * 1000) - 1] = -1
    assert diagnosis(window, 1e7, limits) is None  # just under the share: not the cause
    window[: int(TRIP_SHARE * 1000) + 100] = -1
    share, text = diagnosis(window, 1e7, limits)
    assert share == pytest.approx(TRIP_SHARE + 0.1)
    assert "pulling towards -y with its rod side" in text and "at 100 bar" in text
    assert "up to 210 bar" in text and "smaller amplitude" in text
    # at the rig's highest supply already: no higher one is offered
    assert "higher supply" not in diagnosis(window, 2.1e7, limits)[1]


def test_a_test_beyond_the_actuators_force_is_stopped_as_that_not_as_a_rig_to_commission():
    """Our own rig at 20 bar: IUT_a at 20 mm needs more than A_p P_s. Before sim.force_limit the stop said
    "the rig is not what the controller was told: commission it"."""
    scenario = Scenario.sine(load_isolator("IUT_a"), 20.0, 0.02, 0.5, 6)
    result = Simulation(scenario, validate=False).run(follow=True)
    trip = result.trip
    assert trip is not None, "the table cannot follow at 20 bar: the follow monitor must stop the test"
    assert trip.values["cause"] == "force_limit", trip.message
    assert trip.values["force_limit_share"] >= TRIP_SHARE
    assert "force limit" in trip.message and "higher supply pressure" in trip.message
    assert "commission it" not in trip.message
    p_load = np.asarray(result.samples["load_pressure_pa"])
    supply = np.asarray(result.samples["supply_pressure_pa"])
    assert np.max(np.abs(p_load) / supply) > 0.9  # the record shows the limit the message names


def test_a_stop_with_force_to_spare_keeps_its_own_cause():
    """A rig softer than told (tests/test_follow.py's SOFT: a 22 Hz column where 55 Hz was declared) is stopped
    with the advice to commission it: the actuator was not at its limit, so nothing is put down to it."""
    scenario = Scenario.sine(load_isolator("IUT_a"), 100.0, 0.02, 0.5, 10,
                             plant_changes={"mass_kg": 3000.0, "bulk_modulus_pa": 4.5e8})
    result = Simulation(scenario, validate=False).run(follow=True)
    trip = result.trip
    assert trip is not None, "a column this much softer than told must be stopped"
    assert trip.values["cause"] is None and trip.values["force_limit_share"] is None
    assert "force limit" not in trip.message and "commission" in trip.message
