"""Issue 23, part 3: after a hybrid test's shaking the valve should be quiet: command std < 0.05 V over the last
second. Measured through the service's own path (backend.worker.run_here on the simulated rig, the job the
service builds for the console's default hybrid test: the demo building under near_field_short x 0.5 on IUT_a
at 100 bar).

NOT MET YET. Measured on this branch (and on main): 0.848 V, the valve crossing its dead zone 5 times in that
second. The target there still moves: the building rings on the isolator after the ground motion has died out
(40 um peak to peak in the last second of the full-numerical reference; 131 um under far_field_long, 162 um on
IUT_b), and following such a motion takes the whole dead zone at every reversal (b2ae0a6 quieted a target at
rest, std 0 V, not one that moves). Meeting the target means choosing not to follow motions below a band (the
feedback's dead-zone ramp, or a rest hold on the target), a change to the servo's time-history law whose cost on
the J criteria and on small histories is still to be measured (scripts/earthquake_targets.py, the robustness
suite)."""

import numpy as np
import pytest

from backend.safety import default_limits
from backend.worker import run_here
from sim.earthquake import earthquake_from_spec
from sim.isolator import load_isolator
from sim.rig import DEFAULT_RIG

DEMO = {"base_mass_kg": 4000, "masses_kg": [3000, 3000, 2750], "stiffness_n_per_m": [8e6, 6e6, 4e6],
        "damping_ratio": 0.05}  # frontend/static/js/earthquake.js DEMO_BUILDING


def last_second(isolator="IUT_a", ground_motion="near_field_short", scale=0.5, supply_bar=100.0) -> dict:
    """The command's std (V) and dead-zone crossings, the target's range (m) over the last second."""
    iso = load_isolator(isolator)
    spec = {"kind": "hybrid", "structure": DEMO, "ground_motion": ground_motion, "scale": scale}
    load = sum([DEMO["base_mass_kg"], *DEMO["masses_kg"]]) * 9.80665
    profile = earthquake_from_spec(spec, iso, load)
    scenario = {"isolator": iso.to_dict(), "supply_pa": supply_bar * 1e5, "vertical_load_n": load, "profile": [],
                "controller": "servo", "controller_options": {}, "rig_changes": {}, "earthquake": spec,
                "earthquake_fingerprint": profile.fingerprint}
    job = {"test_id": None, "rig": "simulated", "speed": 1e6, "scenario": scenario, "realtime": False,
           "limits": default_limits(DEFAULT_RIG).to_dict()}
    _run, sent, status, reason = run_here(job)
    assert status == "completed", reason
    s = sent.samples()
    last = s["time_s"] >= s["time_s"][-1] - 1.0
    u = s["voltage_v"][last]
    crossings = int(np.count_nonzero(np.diff(np.sign(u[np.abs(u) > 0.5])) != 0))
    return {"command_std_v": float(np.std(u)), "crossings": crossings,
            "target_range_m": float(np.ptp(s["target_m"][last]))}


@pytest.mark.xfail(strict=True, reason="issue 23 part 3 not done: command std 0.848 V over the last second "
                                       "(target < 0.05 V); see the module docstring")
def test_the_valve_is_quiet_after_a_hybrid_tests_shaking():
    figures = last_second()
    assert figures["command_std_v"] < 0.05, figures
