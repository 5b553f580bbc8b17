"""The comparison grid: its points, its limit-cycle detector, a tiny run and the command line."""

import json
import math

import numpy as np
import pytest

from isorig.cli import main
from sim import compare
from sim.engine import CONTROL_PERIOD_S, Scenario
from sim.rig import DEFAULT_RIG
from sim.samples import Samples


def test_grid_points_cover_the_issue_grid_within_the_envelope():
    points = compare.grid_points()
    assert len(points) == 4 * 3 * 4 * 2 * 3
    assert {p.isolator for p in points} == {"IUT_a", "IUT_b", "LRB_example", "HDRB_soft"}
    assert {p.rig for p in points} == {"nominal", "2x_flow_gain"}
    for p in points:
        assert 0.0 < p.amplitude_m <= compare.AMPLITUDE_CAP_M
        p.scenario(4).validate()  # raises ProfileError if outside the envelope
    variant = compare.rig_variant("2x_flow_gain")
    assert variant.flow_gain_m3_per_s_v_sqrt_pa == 2 * DEFAULT_RIG.flow_gain_m3_per_s_v_sqrt_pa


def test_robust_corners_perturb_only_the_nominal_values_by_30_percent():
    corners = compare.robust_corners()
    assert len(corners) == 8
    areas = sorted({round(c["options"]["piston_area_m2"] / DEFAULT_RIG.piston_area_m2, 9) for c in corners})
    assert areas == pytest.approx([0.7, 1.3])
    points = compare.grid_points(robust=True)
    assert len(points) == 96 * 8 and {p.controller for p in points} == {"servo"}
    assert all(p.scenario(4).rig in (DEFAULT_RIG, compare.rig_variant("2x_flow_gain")) for p in points[:16])


def synthetic_samples(scenario, error):
    n = scenario.n_periods
    s = Samples.empty(n)
    t = np.arange(n) * CONTROL_PERIOD_S
    s["time_s"] = t
    s["target_m"] = 0.02 * np.sin(2 * np.pi * t)
    s["displacement_m"] = s["target_m"] + error(t)
    return s


def test_limit_cycle_detector_ignores_periodic_error_and_finds_a_free_oscillation():
    s = Scenario.sine("IUT_a", 100.0, 0.02, 1.0, 6)
    periodic = synthetic_samples(s, lambda t: 2e-4 * np.sin(2 * np.pi * 15 * t) + 1e-4 * np.sin(2 * np.pi * t))
    assert compare.limit_cycle_rms_m(periodic, s) < 1e-9
    free = synthetic_samples(s, lambda t: 5e-5 * np.sin(2 * np.pi * 37.3 * t))  # not locked to the 1 Hz test
    rms = compare.limit_cycle_rms_m(free, s)
    assert rms == pytest.approx(5e-5 / math.sqrt(2), rel=0.3)
    row = {"limit_cycle_rms_m": rms, "amplitude_m": 0.02}
    assert compare.limit_cycle(row)


def test_a_small_grid_runs_and_tabulates():
    points = compare.grid_points(controllers=("servo", "pid"), isolators=("IUT_a",), supplies_bar=(100.0,),
                                 frequencies_hz=(1.5,), rigs=("nominal",))
    rows, wall = compare.run_grid(points, cycles=4, processes=1)
    assert wall > 0 and len(rows) == 2
    servo, pid = rows
    for key in ("rms_last2", "rms_from_cycle3", "first_cycle_peak_m", "amplitude_error", "phase_error_deg",
                "saturated_share", "peak_flow_l_per_min", "limit_cycle_rms_m"):
        assert math.isfinite(servo[key])
    assert servo["rms_last2"] < pid["rms_last2"]
    table = compare.markdown_table(rows)
    assert table.count("\n") == 3 and "RMS last2 %" in table
    worst = compare.worst_case(rows)
    assert worst["runs"] == 2 and worst["rms_last2"] == max(servo["rms_last2"], pid["rms_last2"])
    summary = compare.summary_table({"servo": [servo], "pid": [pid]})
    assert summary.count("\n") == 3 and summary.splitlines()[2].startswith("| servo | 1 |")


def test_cli_rejects_bad_arguments(capsys):
    assert main(["compare", "--controllers", "foo"]) == 2
    assert "allowed" in capsys.readouterr().err
    assert main(["compare", "--cycles", "2"]) == 2
    assert main(["compare", "--robust", "--ablation"]) == 2


def test_cli_rejects_engine_options_that_do_not_go_together(capsys):
    assert main(["compare", "--compare-backends", "--scheduler", "tcp://127.0.0.1:8786"]) == 2
    assert "measures both paths on this machine" in capsys.readouterr().err
    assert main(["compare", "--processes", "2", "--scheduler", "tcp://127.0.0.1:8786"]) == 2
    assert main(["compare", "--scheduler-timeout", "3"]) == 2
    assert main(["compare", "--scheduler", "tcp://127.0.0.1:8786", "--scheduler-timeout", "nan"]) == 2
    assert "--scheduler-timeout must be between" in capsys.readouterr().err


def test_the_twice_gain_valve_is_a_plant_change_the_controllers_are_not_told():
    lab = DEFAULT_RIG.with_changes(piston_area_m2=0.02)
    (point,) = [p for p in compare.grid_points(controllers=("servo",), isolators=("IUT_a",), supplies_bar=(100.0,),
                                               frequencies_hz=(1.0,), rigs=("2x_flow_gain",), base_rig=lab,
                                               plant={"bulk_modulus_pa": 7e8})]
    s = point.scenario()
    assert s.rig == lab  # what the controller assumes
    assert s.plant_rig.flow_gain_m3_per_s_v_sqrt_pa == 2.0 * lab.flow_gain_m3_per_s_v_sqrt_pa
    assert s.plant_rig.bulk_modulus_pa == 7e8 and s.plant_rig.piston_area_m2 == 0.02
    assert point.amplitude_m == compare.grid_amplitude_m("IUT_a", 100.0, 1.0, lab)  # the lab rig's envelope


@pytest.mark.slow  # the CLI's runs: scripts/test.sh --quick leaves it out
def test_a_rig_file_reaches_the_runs_and_a_bad_one_is_one_line(tmp_path, capsys):
    rig = tmp_path / "lab.toml"
    rig.write_text('name = "Lab B"\nmass_kg = 4000.0\n')
    assert main(["compare", "--robustness", "--groups", "sensor latency", "--rig-file", str(rig), "--rig-set",
                 "coulomb_force_n=1800", "--processes", "1", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["rig"]["name"] == "Lab B" and out["rig"]["changed"] == {"mass_kg": 4000.0}
    assert out["rig_set"] == ["coulomb_force_n=1800"]
    assert out["robustness"]["base_rig_oil_column_hz"] == pytest.approx(30.0, abs=0.1)  # the heavier table's
    assert len(out["rows"]) == 18 and all(r["met"] for r in out["rows"])
    bad = tmp_path / "bad.json"
    bad.write_text('{"mass_kg": -1}')
    for args, words in ((["--rig-file", str(bad)], "mass_kg"), (["--rig-file", str(tmp_path / "none.toml")], "none"),
                        (["--rig-set", "masskg=3"], "did you mean mass_kg"),
                        (["--plant-set", "dead_zone_v=20"], "dead_zone_v"),
                        (["--monte-carlo", str(rig), "--rig-file", str(rig)], "--rig-file cannot go with")):
        assert main(["compare", *args]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and words in err[0], err


def test_supplies_outside_the_rig_are_skipped():
    from isorig.commands.compare import supplies_in_range

    inside, skipped = supplies_in_range(DEFAULT_RIG.with_changes(max_supply_pa=120e5), compare)
    assert inside == (50.0, 100.0) and skipped == [150.0]
    assert supplies_in_range(DEFAULT_RIG, compare) == (compare.SUPPLIES_BAR, [])
