"""A lab's own rig: rig files, NAME=VALUE changes, plant-only and timed plant changes."""

from __future__ import annotations

import json

import numpy as np
import pytest

from isorig.cli import main
from sim.engine import Scenario, Simulation
from sim.rig import DEFAULT_RIG, RigError
from sim.rigfile import load_rig_file, parse_assignment, with_assignments


def test_a_rig_file_in_json_or_toml_changes_what_it_names(tmp_path):
    (tmp_path / "lab.json").write_text(json.dumps({"name": "Lab B", "piston_area_m2": 0.02,
                                                   "position_latency_s": 0.002}))
    (tmp_path / "lab.toml").write_text('name = "Lab B"\npiston_area_m2 = 0.02\nposition_latency_s = 0.002\n')
    for name in ("lab.json", "lab.toml"):
        rig = load_rig_file(tmp_path / name)
        assert rig.name == "Lab B" and rig.parameters.piston_area_m2 == 0.02
        assert rig.parameters.bulk_modulus_pa == DEFAULT_RIG.bulk_modulus_pa  # the rest: the defaults
        assert rig.changed() == {"piston_area_m2": 0.02, "position_latency_s": 0.002}


@pytest.mark.parametrize(("content", "words"), [
    ({"piston_area": 0.02}, "did you mean piston_area_m2"),
    ({"mass_kg": "heavy"}, "mass_kg = 'heavy' is not a number"),
    ({"mass_kg": -5}, "mass_kg = -5 kg is outside the allowed range"),
    ({"bulk_modulus_pa": float("inf")}, "not a finite number"),
    ({"dead_zone_v": 10.0}, "valve could never open"),
    ({"min_supply_pa": 300e5}, "not below max_supply_pa"),
    ([1, 2], "not an object"),
])
def test_a_file_that_is_not_a_rig_gets_one_clear_error(tmp_path, content, words):
    path = tmp_path / "bad.json"
    path.write_text(json.dumps(content))
    with pytest.raises(RigError, match=words) as exc:
        load_rig_file(path)
    assert str(path) in str(exc.value)


def test_unreadable_and_malformed_files(tmp_path):
    with pytest.raises(RigError, match="cannot read"):
        load_rig_file(tmp_path / "missing.json")
    (tmp_path / "x.toml").write_text("piston_area_m2 = = 3")
    with pytest.raises(RigError, match="not valid TOML"):
        load_rig_file(tmp_path / "x.toml")


def test_name_value_changes():
    assert parse_assignment("stroke_m=0.2") == ("stroke_m", 0.2)
    for bad, words in (("stroke_m", "NAME=VALUE"), ("stroke=0.2", "did you mean stroke_m"),
                       ("stroke_m=abc", "not a number"), ("stroke_m=nan", "not a finite number")):
        with pytest.raises(ValueError, match=words):
            parse_assignment(bad)
    rig = with_assignments(DEFAULT_RIG, ["stroke_m=0.2", "mass_kg=900"], "--rig-set")
    assert (rig.stroke_m, rig.mass_kg) == (0.2, 900.0)
    with pytest.raises(RigError, match="--rig-set"):
        with_assignments(DEFAULT_RIG, ["stroke_m=50"], "--rig-set")


def test_plant_changes_reach_the_plant_and_never_the_controller():
    base = Scenario.sine("IUT_a", 100.0, 0.02, 1.0, 3)
    softer = Scenario.sine("IUT_a", 100.0, 0.02, 1.0, 3, plant_changes={"bulk_modulus_pa": 5e8,
                                                                       "kd_n_per_m": 2.5e6})
    sim = Simulation(softer)
    assert sim.plant.rig.bulk_modulus_pa == 5e8 and sim.plant.isolator.kd_n_per_m == 2.5e6
    assert sim.loop.controller.options["piston_area_m2"] == DEFAULT_RIG.piston_area_m2
    assert softer.describe()["plant_changes"] == {"bulk_modulus_pa": 5e8, "kd_n_per_m": 2.5e6}
    force = Simulation(softer).run().samples["force_n"]
    assert np.max(force) > 1.4 * np.max(Simulation(base).run().samples["force_n"])
    # what the controller assumes follows the rig file (the servo's nominal values)
    lab = Scenario.sine("IUT_a", 100.0, 0.02, 1.0, 3, rig=DEFAULT_RIG.with_changes(piston_area_m2=0.015))
    assert Simulation(lab).loop.controller.options["piston_area_m2"] == 0.015
    assert lab.describe()["rig_changes"] == {"piston_area_m2": 0.015}


def test_a_timed_change_acts_from_its_time_on():
    still = Scenario.sine("IUT_a", 100.0, 0.02, 1.0, 4)
    heated = Scenario.sine("IUT_a", 100.0, 0.02, 1.0, 4, timed_changes=[(2.0, "kd_n_per_m", 6.25e5)])
    a, b = Simulation(still).run().samples, Simulation(heated).run().samples
    np.testing.assert_array_equal(a.array[:2000], b.array[:2000])  # identical before
    assert np.max(np.abs(b["force_n"][2200:])) < 0.8 * np.max(np.abs(a["force_n"][2200:]))  # softer after
    with pytest.raises(RigError, match="outside the test"):
        Scenario.sine("IUT_a", 100.0, 0.02, 1.0, 4, timed_changes=[(9.0, "kd_n_per_m", 6e5)]).validate()
    with pytest.raises(ValueError, match="kd_n_per_m"):
        Scenario.sine("IUT_a", 100.0, 0.02, 1.0, 4, timed_changes=[(1.0, "kd_n_per_m", -6e5)]).validate()


def test_simulate_takes_the_rig_flags(tmp_path, capsys):
    rig = tmp_path / "lab.toml"
    rig.write_text("half_volume_m3 = 0.004\n")
    assert main(["simulate", "--rig-file", str(rig), "--rig-set", "position_latency_s=0.001", "--plant-change",
                 "1.5:kw_n=2e4", "--cycles", "3", "--out", str(tmp_path / "o")]) == 0
    scenario = json.loads((tmp_path / "o" / "summary.json").read_text())["scenario"]
    assert scenario["rig_changes"] == {"half_volume_m3": 0.004, "position_latency_s": 0.001}
    assert scenario["timed_changes"] == [[1.5, "kw_n", 2e4]]
    for args, words in ((["--plant-change", "kw_n=2e4"], "TIME_S:NAME=VALUE"),
                        (["--plant-set", "kd=1"], "did you mean kd_n_per_m"),
                        (["--rig-file", str(tmp_path / "none.json")], "cannot read")):
        assert main(["simulate", *args, "--out", str(tmp_path / "x")]) == 2
        assert words in capsys.readouterr().err
