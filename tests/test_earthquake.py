"""Earthquake tests in the engine and the command line: time-history targets and virtual hybrid simulation."""

from __future__ import annotations

import csv
import json

import numpy as np
import pytest

from isorig.cli import main
from sim.engine import Scenario, Simulation
from sim.history import prepare_history
from sim.hybrid import rest_periods
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


def test_isorig_hybrid_refuses_a_building_heavier_than_the_jack_before_computing(tmp_path, capsys, monkeypatch):
    """Without --vertical-load-n the load is the building's weight: 1226 kN against the jack's 850 kN is exit 2
    with one line naming both in kN and the flag, before the reference is computed (no output folder)."""
    heavy = json.loads(open(DEMO).read())
    heavy.update(base_mass_kg=50_000.0, masses_kg=[25_000.0, 25_000.0, 25_000.0])  # 125 t
    path = tmp_path / "heavy.json"
    path.write_text(json.dumps(heavy))
    import sim.hybrid

    def not_now(*_args, **_kwargs):
        raise AssertionError("the reference was computed before the refusal")

    monkeypatch.setattr(sim.hybrid, "reference", not_now)
    code = main(["hybrid", "--structure", str(path), "--ground-motion", "soft_site", "--out", str(tmp_path / "o")])
    err = capsys.readouterr().err
    assert code == 2, err
    assert "the building weighs 1226 kN" in err and "at most 850 kN" in err and "--vertical-load-n" in err, err
    assert "Traceback" not in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "o").exists()
    # a load set beyond the jack is refused as the field it is, at once too
    code = main(["hybrid", "--structure", str(path), "--ground-motion", "soft_site", "--vertical-load-n", "9e5",
                 "--out", str(tmp_path / "o")])
    err = capsys.readouterr().err
    assert code == 2 and "vertical_load_n = 900000 N" in err and "building weighs" not in err, err
    assert not (tmp_path / "o").exists()


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


def _virtual_hybrid(drop_every: int = 0, stop_at_s: float | None = None, duration_s: float = 4.0):
    """The demo building on IUT_a in the simulated rig, run period by period as the worker does; every
    ``drop_every``-th measurement is lost (the plant goes on with the held command); an operator's stop at
    ``stop_at_s``. Returns (substructure, samples, ground acceleration)."""
    from sim.controllers import make_controller
    from sim.hybrid import HybridSubstructure, ground_at_periods
    from sim.loop import ClosedLoop
    from sim.plant import SimulatedPlant
    from sim.rig import DEFAULT_RIG
    from sim.samples import Samples
    from sim.structure import load_structure

    t = np.arange(0.0, duration_s, 0.005)
    ag = ground_at_periods(t, 2.0 * np.sin(2 * np.pi * 1.2 * t) * np.exp(-((t - 2.0) / 1.0) ** 2))
    sub = HybridSubstructure(load_structure(DEMO), PRESETS["IUT_a"], ag)
    loop = ClosedLoop([], make_controller("servo", learning_gain=0.0, integral_per_s=1.0), 10.0,
                      table=sub.target_table())
    plant = SimulatedPlant(DEFAULT_RIG, PRESETS["IUT_a"], 100e5)
    parts, u = [], 0.0
    for k in range(loop.total_periods):
        if loop.done:
            break
        if stop_at_s is not None and k == int(round(stop_at_s * 1000)):
            loop.ramp_out()
        m = plant.measure()
        if drop_every and k % drop_every == drop_every // 2 and k + 1 < loop.total_periods:
            plant.advance(u)  # lost: the rig holds the previous command
            continue
        sub.on_measurement(m, loop)
        u, rows = loop.step(m)
        parts.append(rows)
        plant.advance(u)
    return sub, Samples.concatenate(parts), ag


def test_lost_measurements_keep_the_structure_commanding_every_period():
    sub, s, _ = _virtual_hybrid()
    lossy, s_lost, _ = _virtual_hybrid(drop_every=97)
    assert len(s_lost) == len(s)
    peak = np.max(np.abs(s["target_m"]))
    # every period has the structure's target (a lost one was stepped with the held force): no drop to zero
    assert np.max(np.abs(np.diff(s_lost["target_m"]))) < 1.5 * np.max(np.abs(np.diff(s["target_m"])))
    assert np.max(np.abs(s_lost["target_m"] - s["target_m"])) < 0.02 * peak
    assert lossy.periods_run == sub.periods_run == len(s) - rest_periods()  # then the table rests


def test_a_skipped_period_number_steps_the_structure_with_the_held_force_before_the_loop_runs_it():
    """The measurement of period 203 arrives after 200's (201 and 202 lost): the loop will run 201 and 202 on the
    held measurement, so their rows must hold the structure's targets (never-set rows are zeros: a target spike
    that the stability monitor trips on). The structure steps 201 and 202 with the force held from 200, exactly
    as if those measurements had arrived with that force."""
    from sim.controllers import make_controller
    from sim.hybrid import HybridSubstructure, ground_at_periods
    from sim.loop import ClosedLoop
    from sim.measurement import Measurement
    from sim.structure import load_structure

    t = np.arange(0.0, 1.0, 0.005)
    ag = ground_at_periods(t, 3.0 * np.sin(2 * np.pi * 2.0 * t))
    isolator = PRESETS["IUT_a"]

    def run(lost: tuple[int, ...]):
        sub = HybridSubstructure(load_structure(DEMO), isolator, ag)
        loop = ClosedLoop([], make_controller("servo", learning_gain=0.0), 10.0, table=sub.target_table())
        held = None
        for k in range(260):
            # the specimen: a linear spring at the command, read one period late (a deterministic stand-in)
            x = loop.table[k, 0]
            m = Measurement(k, k * 1e-3, x, 1.5e6 * x, 0.0, 100e5)
            if k in lost:
                continue
            sub.on_measurement(m, loop)
            loop.step(m)
            if k == 200:
                held = sub._last_force  # the force that closed 200: held over the lost periods
        return sub, loop, held

    whole, whole_loop, _ = run(())
    lossy, lossy_loop, held = run((201, 202))
    r = lossy_loop.table[:261, 0]
    assert np.all(r[2:261] != 0.0)  # every period the loop ran had the structure's target (r[1] = 0 from rest)
    assert np.max(np.abs(np.diff(r))) < 1.5 * np.max(np.abs(np.diff(whole_loop.table[:261, 0])))  # no spike
    assert not lossy.tripped and not lossy.monitor.tripped
    assert lossy.periods_run == whole.periods_run == 260
    # 201 and 202 were closed with the force of 200: the same as a loop fed that force in those periods
    check = HybridSubstructure(load_structure(DEMO), isolator, ag)
    check_loop = ClosedLoop([], make_controller("servo", learning_gain=0.0), 10.0, table=check.target_table())
    for k in range(204):
        x = check_loop.table[k, 0]
        if k in (201, 202):
            check._step(k, held, check_loop)
        else:
            check._step(k, check.corrected_force(Measurement(k, k * 1e-3, x, 1.5e6 * x, 0.0, 100e5), x), check_loop)
        check_loop.period = k + 1
    np.testing.assert_allclose(lossy.channels[:204], check.channels[:204], rtol=1e-8, atol=1e-12)


def test_the_structure_is_replayed_from_the_record():
    from sim.hybrid import replay
    from sim.structure import load_structure

    sub, s, ag = _virtual_hybrid(drop_every=211)
    rep = replay(load_structure(DEMO), PRESETS["IUT_a"], ag, s)
    n = len(s) - rest_periods()  # the structure's record ends with its ground motion; the table then rests
    assert rep["periods"] == sub.periods_run == n and rep["command_difference_m"] < 1e-12
    for j, name in enumerate(sub.names):
        np.testing.assert_allclose(rep["channels"][name], sub.channels[:n, j], rtol=0, atol=1e-9)
    assert rep["monitor"]["added_energy_j"] == pytest.approx(sub.monitor.added_energy_j, abs=1e-9)


def test_a_stop_freezes_the_structure_and_brakes_the_table_to_rest():
    sub, s, _ = _virtual_hybrid(stop_at_s=2.0)
    r = s["target_m"]
    assert sub.stopped_period == 2000 and len(s) == 3000 and abs(r[-1]) < 1e-12
    assert np.all(np.isnan(sub.channels[2000:, 0])) or sub.periods_run == 2000
    step = np.abs(np.diff(r))
    assert step[1995:].max() < 1.5 * step[:1995].max()  # braked and faded: no jump
    assert abs(s["displacement_m"][-1]) < 2e-4


def test_earthquake_profiles_are_rebuilt_the_same_and_refusals_name_the_field():
    from sim import earthquake
    from sim.history import HistoryError
    from sim.protocols import ProtocolError, profile_from_spec

    spec = {"kind": "history", "ground_motion": "soft_site", "scale": 0.5, "taper_in_s": 1.0}
    _, first = profile_from_spec(spec, PRESETS["IUT_b"], 125e3)
    earthquake._CACHE.clear()
    _, again = profile_from_spec(json.loads(json.dumps(spec)), PRESETS["IUT_b"], 125e3)
    assert again is not first and again.fingerprint == first.fingerprint
    assert first.target.ground_motion_scale == 0.5 and first.description["mass_kg"] == pytest.approx(125e3 / 9.80665)
    with pytest.raises(ProtocolError):
        profile_from_spec(spec)  # an earthquake kind needs the isolator
    for bad, field in (({**spec, "scale": 20}, "profile.scale"), ({**spec, "ground_motio": 1}, "profile.ground_motio"),
                       ({"kind": "hybrid", "structure": {"base_mass_kg": 1}, "ground_motion": "soft_site"},
                        "profile.structure.masses_kg"),
                       ({"kind": "hybrid", "structure": json.loads(open(DEMO).read()), "ground_motion": "soft_site",
                         "stability": {"limit_j": -1}}, "profile.stability.limit_j")):
        with pytest.raises(HistoryError) as exc:
            profile_from_spec(bad, PRESETS["IUT_a"], 125e3)
        assert exc.value.field == field, (exc.value.field, str(exc.value))


def test_the_worker_refuses_a_target_that_is_not_the_one_checked():
    from backend.worker import earthquake_from_job

    spec = {"kind": "history", "ground_motion": "near_field_short", "scale": 0.2}
    job = {"scenario": {"isolator": PRESETS["IUT_a"].to_dict(), "vertical_load_n": 125e3, "earthquake": spec}}
    profile = earthquake_from_job(job)
    job["scenario"]["earthquake_fingerprint"] = profile.fingerprint
    assert earthquake_from_job(job) is profile
    job["scenario"]["earthquake_fingerprint"] = "0" * 64
    with pytest.raises(ValueError, match="differs from the one checked"):
        earthquake_from_job(job)


def test_the_early_end_of_a_test_is_the_workers_own_event():
    from sim.earthquake import early_end_time_s

    events = [{"kind": "operator", "actor": "alice", "time_s": 1.40, "values": {"action": "stop"}},
              {"kind": "operator", "actor": "system", "time_s": 1.45, "values": {"action": "stop", "ends_at_s": 2.45}},
              {"kind": "operator", "actor": "alice", "time_s": 0.0, "values": {"action": "start"}}]
    assert early_end_time_s(events) == 1.45
    assert early_end_time_s(events[:1]) == 1.40  # the request's, when the worker's is missing
    assert early_end_time_s(events + [{"kind": "limit_trip", "time_s": 1.2, "values": {}}]) == 1.2
    assert early_end_time_s(events[2:]) is None


def test_warm_up_leaves_the_substructure_untouched_and_a_run_that_ended_at_once_still_has_a_summary():
    import math

    from sim.hybrid import HybridSubstructure, compare_with_reference
    from sim.samples import N_FIELDS, Samples
    from sim.structure import load_structure

    sub = HybridSubstructure(load_structure(DEMO), PRESETS["IUT_a"], np.full(50, 0.5))
    sub.warm_up()  # the worker calls it before the rig is armed (the kernels' first call is slow)
    assert sub.periods_run == 0 and np.all(np.isnan(sub.channels)) and sub.cr.time_s == 0.0
    res = sub.results(Samples(np.zeros((2, N_FIELDS))))  # e.g. a watchdog trip in the first periods
    assert all(math.isnan(v) for v in res["criteria"].values())
    assert all(math.isnan(v) for v in compare_with_reference(res, {"base_displacement_m": np.zeros(50)}).values())
