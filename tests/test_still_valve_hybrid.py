"""Issue 32, item 4, a hybrid test's quiet end: the building rings down by 0.1-0.3 mm at about 2 Hz for seconds
before the table's rest. By default (still_share 0) the table follows that ringing, and its valve crosses the dead
zone at every reversal (command std 0.87 V over any second: the target of <= 0.2 V is not met; following swings
that reverse within the dead zone cannot be done with a still valve). With the still valve switched on
(still_share 1) the table holds still; it used to hold where the stillness caught it, a swing's extreme, and the
dead zone's side then took seconds at 0.5 V/s to bring it back (near_field_short x1: 156 um RMS from the target in
the quiet end, J2 0.67 -> 1.54 %). It now holds the centre of the swings (still_centre_share): the side follows the
table's error from that centre, at the held target's faster rate for an error of many bands (60 um, J2 0.84 %).
Measured by scripts/still_valve.py, whose hybrid case (the `isorig hybrid` command's run) this test uses."""

import importlib.util
from pathlib import Path

import numpy as np
import pytest
from test_servo import burst_history

from sim.engine import Scenario, Simulation
from sim.isolator import load_isolator
from sim.rig import BAR_PA

ROOT = Path(__file__).resolve().parents[1]


def still_valve_script():
    """scripts/still_valve.py as a module."""
    spec = importlib.util.spec_from_file_location("still_valve_script", ROOT / "scripts" / "still_valve.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.mark.slow  # two hybrid tests to their end (about 20 s each)
def test_the_still_valve_holds_the_centre_of_a_hybrid_tests_quiet_end():
    script = still_valve_script()
    centre = script.hybrid_case(1.0, "near_field_short", {"still_share": 1.0})
    extreme = script.hybrid_case(1.0, "near_field_short", {"still_share": 1.0, "still_centre_share": 0.0})
    assert centre["status"] == extreme["status"] == "completed"
    # the quiet end's error from the target: about the swings' half-size at their centre, far more at an extreme
    assert centre["end_rms_error_um"] < 100 < extreme["end_rms_error_um"], (centre, extreme)
    assert centre["j2_pct"] < 1.0 < extreme["j2_pct"], (centre, extreme)  # docs/earthquake.md: J2 <= 1 %
    # the valve stays still over the seconds that follow a still second (the first quiet seconds hold the last
    # reversals the table followed); 0.2 V is the target, 0.05 V the window's noise over the runs measured
    assert centre["end_settled_std_v"] <= 0.25, centre


def test_the_still_valve_holds_the_centre_of_a_ringing_target():
    """A time history ringing by +-0.15 mm at 2 Hz around 0 after a burst (tests/test_servo.py's burst_history): the
    still valve holds the table near 0, the centre (52 um RMS from the target, the table's mean 18 um off it);
    taking the error from the target itself (still_centre_share 0, the law before) it held 99 um off, 110 um RMS."""
    figures = {}
    for centre in (1.0, 0.0):
        options = {"still_share": 1.0, "still_centre_share": centre}
        samples = Simulation(Scenario(load_isolator("IUT_a"), 100 * BAR_PA, [], controller_options=options,
                                      history=burst_history(ringing_m=0.15e-3, rest_s=4.0))).run().samples
        quiet = samples["time_s"] >= 4.0
        error = (samples["displacement_m"] - samples["target_m"])[quiet]
        figures[centre] = (float(np.sqrt(np.mean(error ** 2))), abs(float(np.mean(samples["displacement_m"][quiet]))))
    (rms, off), (rms_before, off_before) = figures[1.0], figures[0.0]
    assert rms < 75e-6 < rms_before and off < 50e-6 < off_before, figures
