"""A single-rod actuator pulls with its rod side's area only: the envelope checks of a sine (sim.profiles) and of a
time history (sim.history) judge the pulling force against A_B P_s, the pushing one against A_p P_s. Before, both
took A_p P_s both ways, and a test the rig could not pull was started and stalled (docs/commissioning.md, "What
stops the commissioned rigs' tests": 6 single-rod rigs at 20 mm)."""

import numpy as np
import pytest

from sim.history import history_envelope_problem, prepare_history
from sim.isolator import load_isolator
from sim.profiles import SineProfile, envelope_problem, force_estimate_n, max_amplitude_m, max_frequency_hz
from sim.rig import BAR_PA, DEFAULT_RIG

IUT_A = load_isolator("IUT_a")
SUPPLY_PA = 100 * BAR_PA
#: the default rig with a rod side of half the cap side's area
SINGLE = DEFAULT_RIG.with_changes(piston_area_b_m2=0.5 * DEFAULT_RIG.piston_area_m2)


def test_each_way_has_its_force():
    assert SINGLE.max_force_n(SUPPLY_PA) == pytest.approx(DEFAULT_RIG.piston_area_m2 * SUPPLY_PA)
    assert SINGLE.max_pull_force_n(SUPPLY_PA) == pytest.approx(0.5 * DEFAULT_RIG.piston_area_m2 * SUPPLY_PA)
    assert DEFAULT_RIG.max_pull_force_n(SUPPLY_PA) == DEFAULT_RIG.max_force_n(SUPPLY_PA)  # double-rod


def test_a_sine_the_rod_side_cannot_pull_is_refused_with_what_fits():
    block = SineProfile(0.04, 0.5, 3, 1)
    needed = force_estimate_n(block, SINGLE, IUT_A)
    assert SINGLE.max_pull_force_n(SUPPLY_PA) < needed < SINGLE.max_force_n(SUPPLY_PA)  # the case: only pulling fails
    assert envelope_problem(block, DEFAULT_RIG, IUT_A, SUPPLY_PA) is None  # the double-rod rig runs it
    err = envelope_problem(block, SINGLE, IUT_A, SUPPLY_PA)
    assert err is not None and err.field == "amplitude_m" and err.limit.startswith("A_B P_s")
    assert "pull at most A_B P_s = 66.7 kN with its rod side" in str(err), str(err)
    largest = max_amplitude_m(0.5, SINGLE, IUT_A, SUPPLY_PA)
    assert f"amplitude_m must be <= {largest:.3g} m" in str(err)
    assert force_estimate_n(SineProfile(largest, 0.5, 3, 1), SINGLE, IUT_A) <= SINGLE.max_pull_force_n(SUPPLY_PA)


def test_a_history_is_judged_by_the_way_it_pulls_or_pushes():
    t = np.arange(0.0, 6.0 + 1e-9, 0.002)
    symmetric = prepare_history(t, 0.04 * np.sin(2 * np.pi * 0.5 * t), 1e-3)
    assert history_envelope_problem(symmetric, DEFAULT_RIG, IUT_A, SUPPLY_PA) is None
    err = history_envelope_problem(symmetric, SINGLE, IUT_A, SUPPLY_PA)
    assert err is not None and err.limit.startswith("A_B P_s") and "must pull" in str(err) and "rod side" in str(err)
    assert symmetric.r_m[err.sample] < 0.0  # it pulls where the table is on the -y side
    # the same motion on the +y side only (a pushing history): within A_p P_s, so the single-rod rig runs it
    pushing = prepare_history(t, 0.02 + 0.02 * np.sin(2 * np.pi * 0.5 * t - np.pi / 2), 1e-3)
    assert np.all(pushing.r_m >= -1e-6)
    assert history_envelope_problem(pushing, SINGLE, IUT_A, SUPPLY_PA) is None


def test_the_valve_passes_less_towards_the_rod_side():
    """The valve law's drop towards -y is (A_B / A_A) P_s - |P_L| on a single-rod actuator (sim.rig.supply_share):
    a sine near the double-rod rig's valve limit is beyond the single-rod rig's, and a history's first sample
    beyond it moves towards -y."""
    f_double = max_frequency_hz(0.01, DEFAULT_RIG, IUT_A, SUPPLY_PA)
    block = SineProfile(0.01, 0.97 * f_double, 3, 1)
    assert envelope_problem(block, DEFAULT_RIG, IUT_A, SUPPLY_PA) is None
    err = envelope_problem(block, SINGLE, IUT_A, SUPPLY_PA)
    assert err is not None and err.field == "frequency_hz" and "valve capacity" in err.limit, str(err)
    assert max_frequency_hz(0.01, SINGLE, IUT_A, SUPPLY_PA) < 0.97 * f_double
    t = np.arange(0.0, 4.0 + 1e-9, 0.001)
    history = prepare_history(t, 0.01 * np.sin(2 * np.pi * 0.97 * f_double * t), 1e-3)
    assert history_envelope_problem(history, DEFAULT_RIG, IUT_A, SUPPLY_PA) is None
    err = history_envelope_problem(history, SINGLE, IUT_A, SUPPLY_PA)
    assert err is not None and "valve capacity" in err.limit and err.value < 0.0, str(err)  # moving towards -y
