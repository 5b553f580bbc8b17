"""Protocols as data: shipped files, validation, blocks for the engine, acceptance verdicts naming the rule."""

import json

import numpy as np
import pytest

from sim.isolator import PRESETS, simulate_loop
from sim.metrics import cycle_metrics
from sim.profiles import SineProfile, pack_profile, target_series
from sim.protocols import (
    SHIPPED_PROTOCOLS,
    ProtocolError,
    acceptance_summary,
    evaluate_acceptance,
    load_protocol,
    profile_from_spec,
    protocol_from_dict,
)

DT = 1e-3


def loops(protocol, isolator, force_scale=None):
    """Per-cycle metrics of the isolator model driven by the protocol's target (optionally scaling the force
    of some planned cycles, to mimic a degrading isolator)."""
    t = np.arange(0.0, protocol.duration_s, DT)
    d = target_series(pack_profile(protocol.blocks), t)
    f = simulate_loop(isolator, d, DT)
    for cycle, scale in (force_scale or {}).items():
        p = protocol.cycle_plan()[cycle - 1]
        sel = (t >= p["t_start_s"] - DT / 2) & (t < p["t_end_s"] + DT / 2)
        f[sel] *= scale
    starts, end = protocol.cycle_starts_s()
    return cycle_metrics(t, d, f, starts, end)


def test_shipped_protocols_load_and_round_trip():
    assert {"en15129_type_test", "en15129_nominal", "quick_check"} <= set(SHIPPED_PROTOCOLS)
    for name in SHIPPED_PROTOCOLS:
        p = load_protocol(name)
        assert p.name == name and p.rules
        assert protocol_from_dict(json.loads(json.dumps(p.to_dict()))) == p


def test_en15129_levels_become_tapered_sine_blocks():
    p = load_protocol("en15129_type_test")
    blocks = p.blocks
    assert all(isinstance(b, SineProfile) for b in blocks)
    assert [b.amplitude_m for b in blocks] == pytest.approx([0.005, 0.01, 0.0134, 0.02])
    assert [(b.cycles, b.taper_cycles, b.frequency_hz) for b in blocks] == [(5, 1, 0.5)] * 4
    plan = p.cycle_plan()
    assert len(plan) == 20 and sum(c["test"] for c in plan) == 12
    assert [c["level_cycle"] for c in plan[:5]] == [None, 1, 2, 3, None]
    scaled = p.with_design_displacement(0.03)
    assert scaled.blocks[-1].amplitude_m == pytest.approx(0.03)
    assert scaled.blocks[0].amplitude_m == pytest.approx(0.0075)
    slower = scaled.with_frequency(0.25)  # EN 15129: the specimen's design frequency
    assert [b.frequency_hz for b in slower.blocks] == [0.25] * 4
    assert slower.blocks[-1].amplitude_m == pytest.approx(0.03)
    assert slower.duration_s == pytest.approx(2 * scaled.duration_s)
    assert slower.cycle_plan()[-1]["t_end_s"] == pytest.approx(2 * scaled.cycle_plan()[-1]["t_end_s"])
    with pytest.raises(ProtocolError) as err:
        scaled.with_frequency(0.0)
    assert err.value.field == "frequency_hz" and "Hz" in str(err.value)


def test_protocol_passes_on_a_steady_isolator():
    p = load_protocol("en15129_nominal")
    iso = PRESETS["IUT_a"]
    verdicts = evaluate_acceptance(p, loops(p, iso), isolator=iso)
    # 4 rules x 12 test cycles, minus the reference cycles of the two 3rd-cycle rules
    assert len(verdicts) == 4 * 12 - 2 * 4
    assert all(v["status"] == "pass" for v in verdicts), [v["message"] for v in verdicts if not v["passed"]]
    summary = acceptance_summary(verdicts)
    assert summary["passed"] is True and summary["failed_rules"] == []


def test_degraded_cycle_fails_the_third_cycle_rules_at_that_cycle():
    p = load_protocol("en15129_type_test")
    iso = PRESETS["IUT_a"]
    level4_first = next(c["cycle"] for c in p.cycle_plan() if c["level"] == 4 and c["level_cycle"] == 1)
    verdicts = evaluate_acceptance(p, loops(p, iso, {level4_first: 0.75}))
    failed = [v for v in verdicts if not v["passed"]]
    assert {v["rule"] for v in failed} == {"keff_vs_3rd_cycle", "edc_vs_3rd_cycle"}
    assert {v["cycle"] for v in failed} == {level4_first}
    k = next(v for v in failed if v["rule"] == "keff_vs_3rd_cycle")
    assert k["deviation_fraction"] == pytest.approx(-0.25, abs=0.01)
    assert k["message"].startswith("keff_vs_3rd_cycle failed at level 4 cycle 1")
    summary = acceptance_summary(verdicts)
    assert summary["passed"] is False
    assert [r["rule"] for r in summary["failed_rules"]] == ["keff_vs_3rd_cycle", "edc_vs_3rd_cycle"]


def test_wrong_isolator_fails_the_nominal_rules_only():
    p = load_protocol("en15129_nominal")
    verdicts = evaluate_acceptance(p, loops(p, PRESETS["IUT_b"]), isolator=PRESETS["IUT_a"])
    failed_rules = {v["rule"] for v in verdicts if not v["passed"]}
    assert failed_rules == {"keff_vs_nominal", "edc_vs_nominal"}
    assert evaluate_acceptance(p, loops(p, PRESETS["IUT_a"]))[-1]["status"] == "not_evaluated"


def test_nominal_values_and_missing_cycles():
    iso = PRESETS["IUT_a"]
    base = load_protocol("quick_check")
    measured = loops(base, iso)
    edc_level2 = next(c["edc_j"] for c in measured if c["cycle"] == 9)
    data = base.to_dict()
    data["acceptance"] = [{"name": "edc_declared", "quantity": "edc_j", "reference": "value",
                           "values": [None, edc_level2 * 1.1], "tolerance_fraction": 0.05}]
    p = protocol_from_dict(data)
    verdicts = evaluate_acceptance(p, measured)
    assert len(verdicts) == 3 and all(v["level"] == 2 for v in verdicts)
    assert all(v["status"] == "fail" and "edc_declared failed" in v["message"] for v in verdicts)
    # a test that stopped after 7 cycles: the later judged cycles are "missing", not passed
    short = evaluate_acceptance(base, measured[:7])
    assert {v["status"] for v in short if v["level"] == 2} == {"missing"}
    assert all(v["passed"] for v in short if v["level"] == 1)


def test_matching_by_time_tolerates_differently_numbered_cycles():
    p = load_protocol("quick_check")
    measured = loops(p, PRESETS["IUT_a"])
    renumbered = [{**c, "cycle": c["cycle"] + 100} for c in measured[1:]]  # e.g. split by zero crossings
    verdicts = evaluate_acceptance(p, renumbered)
    assert verdicts and all(v["passed"] for v in verdicts)


@pytest.mark.parametrize("change, field", [
    ({"tolerence": 0.1}, "tolerence"),
    ({"levels": []}, "levels"),
    ({"levels": [{"fraction": 0.5}]}, "levels[1].cycles"),
    ({"levels": [{"fraction": 0.5, "amplitude_m": 0.01, "cycles": 3}]}, "levels[1]"),
    ({"design_displacement_m": -0.02}, "design_displacement_m"),
    ({"acceptance": [{"name": "r", "quantity": "stiffness", "reference": "cycle", "tolerance_fraction": 0.1}]},
     "acceptance[1].quantity"),
    ({"acceptance": [{"name": "r", "quantity": "edc_j", "reference": "cycle", "reference_cycle": 4,
                      "tolerance_fraction": 0.1}]}, "acceptance[1].reference_cycle"),
    ({"acceptance": [{"name": "r", "quantity": "edc_j", "reference": "value", "values": [1.0],
                      "tolerance_fraction": 0.1}]}, "acceptance[1].values"),
])
def test_malformed_protocols_name_the_field(change, field):
    data = {**load_protocol("quick_check").to_dict(), **change}
    with pytest.raises(ProtocolError) as err:
        protocol_from_dict(data)
    assert err.value.field == field
    assert field.split(".")[-1].split("[")[0] in str(err.value)


def test_profile_forms_and_files(tmp_path):
    blocks, protocol = profile_from_spec({"kind": "sine", "amplitude_m": 0.02, "frequency_hz": 1, "cycles": 5})
    assert protocol is None and blocks == [SineProfile(0.02, 1.0, 5, 1, 0.0)]
    blocks, protocol = profile_from_spec({"kind": "protocol", "name": "quick_check", "design_displacement_m": 0.01})
    assert protocol.name == "quick_check" and blocks[-1].amplitude_m == pytest.approx(0.01)
    blocks, protocol = profile_from_spec({"kind": "protocol", "name": "quick_check", "frequency_hz": 1.5})
    assert {b.frequency_hz for b in blocks} == {1.5} and {lv.frequency_hz for lv in protocol.levels} == {1.5}
    with pytest.raises(ProtocolError) as err:
        profile_from_spec({"kind": "protocol", "name": "quick_check", "frequency_hz": 11})
    assert err.value.field == "profile.frequency_hz"
    inline = load_protocol("quick_check").to_dict()
    _, protocol = profile_from_spec({"kind": "protocol", "protocol": inline})
    assert protocol == load_protocol("quick_check")
    with pytest.raises(ProtocolError, match="unknown protocol"):
        profile_from_spec({"kind": "protocol", "name": "nope"})
    with pytest.raises(ProtocolError, match="cycles"):
        profile_from_spec({"kind": "sine", "amplitude_m": 0.02, "frequency_hz": 1})
    toml = tmp_path / "p.toml"
    toml.write_text('name = "t1"\ndesign_displacement_m = 0.02\n[[levels]]\nfraction = 1.0\ncycles = 3\n'
                    '[[acceptance]]\nname = "k"\nquantity = "k_eff_n_per_m"\nreference = "cycle"\n'
                    'tolerance_fraction = 0.15\n')
    assert load_protocol(toml).blocks == [SineProfile(0.02, 0.5, 5, 1)]
    with pytest.raises(ProtocolError, match="unknown protocol"):
        load_protocol(tmp_path / "missing.json")


def test_protocol_runs_in_the_engine_and_is_judged():
    from sim.engine import Scenario, Simulation
    from sim.metrics import scenario_cycle_metrics

    p = load_protocol("quick_check")
    scenario = Scenario(PRESETS["IUT_a"], 100e5, p.blocks, controller="pid")
    result = Simulation(scenario).run()
    cycles = scenario_cycle_metrics(result.samples, scenario)
    assert len(cycles) == len(p.cycle_plan()) == 10
    verdicts = evaluate_acceptance(p, cycles)
    assert len(verdicts) == 2 * 2 * 2
    assert all(v["status"] == "pass" for v in verdicts), [v["message"] for v in verdicts if not v["passed"]]


def test_shipped_protocols_are_package_data():
    """A wheel only carries the JSON files that pyproject's package-data names."""
    import fnmatch
    import tomllib
    from pathlib import Path

    import sim.protocols as protocols

    root = Path(__file__).resolve().parent.parent
    patterns = tomllib.loads((root / "pyproject.toml").read_text())["tool"]["setuptools"]["package-data"]["sim"]
    for name in SHIPPED_PROTOCOLS:
        rel = (protocols.DATA_DIR / f"{name}.json").relative_to(root / "sim").as_posix()
        assert any(fnmatch.fnmatch(rel, p) for p in patterns), rel
