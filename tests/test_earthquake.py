"""Earthquake tests in the engine and the command line: time-history targets and virtual hybrid simulation."""

from __future__ import annotations

import csv
import json

import numpy as np
import pytest

from isorig.cli import main
from sim.engine import Scenario, Simulation
from sim.history import prepare_history
from sim.isolator import PRESETS
from sim.profiles import ProfileError

DEMO = "docs/examples/structure_3_storey.json"


def pulse_history(amplitude_m=0.015, duration_s=4.0):
    """A smooth two-sided pulse train: r, r' and r'' all nonzero, no repeating cycle."""
    t = np.arange(0.0, duration_s, 0.01)
    d = amplitude_m * np.sin(2 * np.pi * 0.7 * t) * np.exp(-((t - 2.0) / 1.2) ** 2) + 0.3 * amplitude_m * np.sin(
        2 * np.pi * 1.9 * t) * np.exp(-((t - 2.5) / 0.6) ** 2)
    return prepare_history(t, d, taper_in_s=0.5, taper_out_s=0.5, source="test pulse")


def test_a_history_is_tracked_in_the_servos_tracking_mode():
    history = pulse_history()
    scenario = Scenario(PRESETS["IUT_a"], 100e5, [], history=history)
    scenario.validate()
    assert scenario.duration_s == pytest.approx(history.n_samples * 1e-3)
    options = scenario.effective_controller_options()
    assert options["learning_gain"] == 0.0 and options["integral_per_s"] > 0  # chosen for a history
    result = Simulation(scenario).run()
    s = result.samples
    np.testing.assert_allclose(s["target_m"], history.r_m, atol=1e-15)
    summary = result.summary()
    c = summary["criteria"]
    assert abs(c["j1_delay_ms"]) < 1.0 and c["j2_rms_percent"] < 3.0 and c["j3_peak_percent"] < 5.0
    assert summary["scenario"]["history"]["source"] == "test pulse" and summary["cycles"] == []
    assert summary["scenario"]["controller_options_in_force"]["learning_gain"] == 0.0


def test_a_history_beyond_the_rig_is_refused_naming_the_sample():
    big = pulse_history(amplitude_m=0.2)
    with pytest.raises(ProfileError) as exc:
        Scenario(PRESETS["IUT_a"], 100e5, [], history=big).validate()
    assert exc.value.field == "history" and " s" in str(exc.value)


def test_a_stop_fades_a_history_out(tmp_path):
    from backend.safety import default_limits
    from backend.worker import AbortSwitch, Collector, Run
    from sim.rig import DEFAULT_RIG

    history = pulse_history()
    job = {"test_id": 1, "rig": "simulated", "speed": 50.0,
           "scenario": {"isolator": PRESETS["IUT_a"].to_dict(), "supply_pa": 100e5, "profile": [],
                        "controller": "servo", "history_target": history},
           "limits": default_limits(DEFAULT_RIG).to_dict()}
    switch = AbortSwitch()
    out = Collector()
    run = Run(job, out, switch)
    original = run.loop.table[:, 0].copy()

    class StopAt:
        def poll(self, *_):
            return run.loop.time_s >= 1.5 and not run.loop.stopping

        def recv(self):
            return "stop"

    run.commands = StopAt()
    status, _ = run.execute()
    s = out.samples()
    assert status == "stopped" and s["time_s"][-1] == pytest.approx(1.5 + 1.0, abs=0.05)
    assert abs(s["target_m"][-1]) < 1e-9 and np.allclose(s["target_m"][:1500], original[:1500])


def test_simulate_takes_a_history_and_a_ground_motion(tmp_path, capsys):
    path = tmp_path / "h.csv"
    t = np.arange(0.0, 3.0, 0.005)
    rows = [("time_s", "displacement_m")] + [(f"{x:.3f}", f"{0.01 * np.sin(2 * np.pi * 0.8 * x) ** 3:.6g}")
                                              for x in t]
    with open(path, "w", newline="") as fh:
        csv.writer(fh).writerows(rows)
    assert main(["simulate", "--history", str(path), "--out", str(tmp_path / "h")]) == 0
    summary = json.loads((tmp_path / "h" / "summary.json").read_text())
    assert summary["criteria"]["j2_rms_percent"] < 5.0 and "J1 delay" in capsys.readouterr().out
    assert main(["simulate", "--ground-motion", "near_field_short", "--scale", "0.3", "--isolator", "IUT_b",
                 "--supply-bar", "70", "--out", str(tmp_path / "g")]) == 0
    summary = json.loads((tmp_path / "g" / "summary.json").read_text())
    assert "near_field_short x 0.3 through IUT_b" in summary["scenario"]["history"]["source"]
    bad = tmp_path / "bad.csv"
    bad.write_text("time_s,displacement_m\n0,0\n0.01,0\n0.005,0\n" + "".join(f"{0.01 * k},0\n" for k in range(3, 30)))
    assert main(["simulate", "--history", str(bad), "--out", str(tmp_path / "b")]) == 2
    err = capsys.readouterr().err
    assert "bad.csv" in err and "line" in err


def test_virtual_hybrid_simulation_follows_the_numerical_reference(tmp_path, capsys):
    gm = tmp_path / "pulse.csv"
    t = np.arange(0.0, 6.0, 0.005)
    acc = 2.0 * np.sin(2 * np.pi * 1.2 * t) * np.exp(-((t - 2.5) / 1.0) ** 2)  # m/s2
    gm.write_text("time_s,acceleration_m_per_s2\n" + "".join(f"{a:.4f},{b:.6g}\n" for a, b in zip(t, acc,
                                                                                                  strict=True)))
    code = main(["hybrid", "--structure", DEMO, "--ground-motion", str(gm), "--isolator", "IUT_a",
                 "--out", str(tmp_path / "o")])
    assert code == 0, capsys.readouterr().err
    summary = json.loads((tmp_path / "o" / "summary.json").read_text())
    c = summary["criteria"]
    assert c["j4_rms_percent"] < 10.0 and c["j5_peak_percent"] < 10.0  # the figures: scripts/earthquake_targets.py
    assert summary["status"] == "completed" and summary["stability"]["tripped"] is False
    with open(tmp_path / "o" / "timeseries.csv") as fh:
        header = next(csv.reader(fh))
    assert {"time_s", "target_m", "displacement_m", "force_n", "base_displacement_m"} <= set(header)
    assert "J4" in capsys.readouterr().out


def test_an_unstable_hybrid_loop_is_stopped_by_the_energy_monitor():
    from sim.controllers import make_controller
    from sim.hybrid import HybridSubstructure, ground_at_periods, run_virtual
    from sim.loop import ClosedLoop
    from sim.plant import SimulatedPlant
    from sim.rig import DEFAULT_RIG
    from sim.structure import load_structure

    t = np.arange(0.0, 8.0, 0.005)
    ag = ground_at_periods(t, 2.0 * np.sin(2 * np.pi * 1.2 * t) * np.exp(-((t - 3.0) / 1.5) ** 2))
    sub = HybridSubstructure(load_structure(DEMO), PRESETS["IUT_a"], ag)

    class DelayedActuator(SimulatedPlant):
        """The rig with a 30 ms delay between command and valve: the error feeds energy into the loop."""

        def __init__(self, *args, delay_periods=30):
            super().__init__(*args)
            self.queue = [0.0] * delay_periods

        def advance(self, command_v, *rest):
            self.queue.append(command_v)
            super().advance(self.queue.pop(0))

    loop = ClosedLoop([], make_controller("servo", learning_gain=0.0), 10.0, table=sub.target_table())
    samples, reason = run_virtual(sub, loop, DelayedActuator(DEFAULT_RIG, PRESETS["IUT_a"], 100e5))
    assert reason is not None and sub.tripped
    assert samples["voltage_v"][-1] == 0.0 and len(samples) < len(ag)  # stopped early, valve ramped to 0 V
