"""The robustness suite of issue 15 (sim.robustness): its cases, its limit-cycle measure, a few cases run short,
and `isorig compare --robustness`. The suite's figures are measured by the command (docs/compare.md), not here:
these tests check that the suite asks what the issue asks and that its verdicts can fail."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from isorig.cli import main
from sim import robustness as rb
from sim.compare import point_figures
from sim.engine import CONTROL_PERIOD_S, Scenario, Simulation
from sim.rig import DEFAULT_RIG


def run_case(point: rb.RobustnessPoint) -> dict:
    return point_figures(point, Simulation(point.scenario()).run())


def case(group: str, name: str, **options) -> rb.RobustnessPoint:
    point = next(p for p in rb.robustness_points(groups=(group,)) if p.corner == name)
    point.options = dict(options)
    return point


def test_the_cases_cover_the_ranges_of_the_issue():
    points = rb.robustness_points()
    by_group = {g: [p for p in points if p.group == g] for g in rb.GROUPS}
    assert {g: len(v) for g, v in by_group.items()} == {"small amplitude": 24, "soft oil column": 24,
                                                        "sensor latency": 18, "stiffness change": 12}
    small = by_group["small amplitude"]
    assert min(p.amplitude_m for p in small) == 0.0005 and max(p.amplitude_m for p in small) == 0.005
    assert {p.frequency_hz for p in small} == {0.1, 0.5, 1.0}
    oil = [rb.oil_column_hz(p.declared_rig) for p in by_group["soft oil column"]]
    assert min(oil) == pytest.approx(19.4, abs=0.1) and rb.oil_column_hz(DEFAULT_RIG) > 50.0
    latency = by_group["sensor latency"]
    assert max(p.declared_rig.position_latency_s for p in latency) == 0.002
    assert max(p.frequency_hz for p in latency) == 1.5
    for p in by_group["stiffness change"]:  # the change at the start of a cycle, after the learning has settled
        (t_s, name, value), *_ = p.timed
        assert t_s == pytest.approx(rb.CHANGE_AT_CYCLE / p.frequency_hz) and name == "kd_n_per_m"
        assert value / getattr(p.scenario().isolator, name) in (0.5, 2.0)
    assert all(p.target == rb.TARGETS[p.group] for p in points)
    assert {g: rb.TARGETS[g] for g in rb.GROUPS} == {"small amplitude": 0.01, "soft oil column": 0.005,
                                                     "sensor latency": 0.005, "stiffness change": 0.005}
    rb.check_points(points)  # every case inside its rig's envelope
    with pytest.raises(ValueError, match="unknown robustness group"):
        rb.robustness_points(groups=("big amplitude",))


def test_a_lab_rig_and_plant_changes_reach_every_case():
    lab = DEFAULT_RIG.with_changes(piston_area_m2=0.02)
    points = rb.robustness_points(base_rig=lab, plant={"bulk_modulus_pa": 8e8}, groups=("soft oil column",))
    assert all(p.declared_rig.piston_area_m2 == 0.02 for p in points)
    s = points[0].scenario()
    assert s.rig.piston_area_m2 == 0.02 and s.plant_rig.bulk_modulus_pa == 8e8
    assert s.rig.bulk_modulus_pa != 8e8  # the controller is not told


def test_the_non_repeating_band_measure_ignores_a_periodic_error_and_finds_a_free_oscillation():
    s = Scenario.sine("IUT_a", 100, 0.01, 1.0, 8, taper_cycles=1)
    t = np.arange(int(round(s.duration_s / CONTROL_PERIOD_S))) * CONTROL_PERIOD_S
    periodic = 1e-5 * np.sin(2 * np.pi * 12.0 * t) + 1e-4 * np.sin(2 * np.pi * t)
    assert rb.non_repeating_band_rms(periodic, s) < 1e-9
    free = periodic + 2e-5 * np.sin(2 * np.pi * 13.7 * t)  # not a harmonic of the test: it does not repeat
    assert rb.non_repeating_band_rms(free, s) / 0.01 > rb.LIMIT_CYCLE_SHARE


def test_sample_cases_meet_their_targets_and_the_verdict_can_fail():
    """One case of each group on a short run; the same cases with the piece that serves them taken away miss."""
    latency = case("sensor latency", "2 ms IUT_a 100 bar 20 mm 1.5 Hz")
    row = run_case(latency)
    assert row["met"] and row["figure"] < 0.005 and not row["limit_cycle"]
    # the controller told of no latency (the plant's reading is still 2 ms late) tracks the late reading
    blind = run_case(case("sensor latency", "2 ms IUT_a 100 bar 20 mm 1.5 Hz", position_latency_s=0.0))
    assert not blind["met"] and blind["figure"] > 0.01

    oil = case("soft oil column", "heavy table (20.0 Hz) IUT_a 100 bar 20 mm 1 Hz")
    row = run_case(oil)
    assert row["met"] and not row["limit_cycle"]
    undamped = run_case(case("soft oil column", "heavy table (20.0 Hz) IUT_a 100 bar 20 mm 1 Hz",
                             pressure_feedback_max_damping=0.0, min_gain_margin=0.0))  # the servo would refuse it
    assert not undamped["met"] and undamped["limit_cycle"]  # the oil column oscillates without the feedback

    row = run_case(case("small amplitude", "IUT_a 100 bar 1 mm 1 Hz"))
    assert row["met"] and row["figure"] < 0.01

    row = run_case(case("stiffness change", "k_d x2 IUT_a 100 bar 20 mm 1 Hz"))
    assert row["met"] and row["figure"] < 0.005 and math.isfinite(row["band_error_share"])


def test_summary_per_group_names_the_worst_case():
    rows = [{"group": "g", "controller": "servo", "case": name, "figure": f, "target": 0.005, "met": f <= 0.005,
             "limit_cycle": lc, "limit_cycle_error_share": 0.0, "limit_cycle_command_v": 0.001, "diverged": False,
             "band_error_share": 0.0} for name, f, lc in (("a", 0.001, False), ("b", 0.009, False),
                                                           ("c", float("nan"), True))]
    (s,) = rb.group_summary(rows)
    assert s["cases"] == 3 and s["met"] == 1 and s["worst_case"] == "c" and s["worst_figure"] == math.inf
    assert s["limit_cycles"] == 1
    assert "NOT MET (limit cycle)" in rb.robustness_table(rows, markdown=False)


@pytest.mark.parametrize("args, words", [
    (["--robustness", "--robust"], "choose one of --robust, --robustness"),
    (["--groups", "sensor latency"], "--groups applies to --robustness only"),
    (["--robustness", "--groups", "big amplitude"], "unknown robustness group(s) big amplitude"),
    (["--robustness", "--cycles", "6"], "--cycles cannot go with --robustness"),
    (["--robustness", "--figure", "x.png"], "--figure draws the grid's error distribution"),
    (["--robustness", "--plant-set", "kd_n_per_m=1e6"], "'kd_n_per_m' is not a rig parameter"),
    (["--robustness", "--rig-set", "mass_kg=-5"], "mass_kg"),
    (["--robustness", "--controller-option", "gamma=1"], "unknown servo option"),
    (["--robustness", "--controller-option", "kp_per_s=nan"], "kp_per_s"),
])
def test_cli_refuses_bad_robustness_arguments_with_one_line(args, words, capsys):
    assert main(["compare", *args]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and words in err[0], err


@pytest.mark.slow  # the CLI's robustness runs: scripts/test.sh --quick leaves it out
def test_cli_runs_one_group_and_prints_its_figures(capsys):
    assert main(["compare", "--robustness", "--groups", "stiffness change", "--processes", "1", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["robustness"]["targets"]["stiffness change"] == 0.005
    (summary,) = out["summary"]
    assert summary["group"] == "stiffness change" and summary["cases"] == 12
    assert {r["case"] for r in out["rows"]} == {p.corner for p in rb.robustness_points(groups=("stiffness change",))}
    assert all(r["figure"] is not None and r["target"] == 0.005 for r in out["rows"])
    assert out["rig"]["source"] == "sim.rig defaults"


def test_an_undeclared_valve_null_offset_is_found_at_small_amplitudes():
    """The plant's valve null (v_e0 of eq. 2) 20 mV off the declared one: at 1 mm and 0.5 Hz (3 mm/s peak) the
    estimate finds it on the steady sine; held at the declared value, the table limit-cycles at the valve's edge."""
    point = case("small amplitude", "IUT_a 100 bar 1 mm 0.5 Hz")
    point.plant = {"driver_offset_v": 0.0}
    assert run_case(point)["met"]
    point.options = {"null_offset_adaptive": 0.0}
    row = run_case(point)
    assert not row["met"] and row["limit_cycle"]


def test_sensitivity_groups_change_the_plant_only_and_are_not_run_by_default():
    assert not set(rb.SENSITIVITY_GROUPS) & {p.group for p in rb.robustness_points()}
    null = rb.robustness_points(groups=("valve null off",))
    oil = rb.robustness_points(groups=("more oil than declared",))
    assert len(null) == 24 and len(oil) == 24
    s = null[0].scenario()
    assert s.plant_rig.driver_offset_v == pytest.approx(DEFAULT_RIG.driver_offset_v - 0.02)
    assert s.rig.driver_offset_v == DEFAULT_RIG.driver_offset_v  # the controller assumes the declared null
    for p in oil:
        s = p.scenario()
        assert s.plant_rig.half_volume_m3 == pytest.approx(1.5 * s.rig.half_volume_m3)
        assert rb.oil_column_hz(s.plant_rig) < 0.83 * rb.oil_column_hz(s.rig)
