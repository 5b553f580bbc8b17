"""Campaigns on dask.distributed (sim.campaign): the same numbers as the process pool, Monte Carlo draws on the
plant only, campaign files refused with one clear message, an unreachable scheduler, the CSV and the figure."""

import json
import math
import socket
import time

import pytest

from isorig.cli import main
from sim import campaign as cpg
from sim import compare
from sim.isolator import LIMITS
from sim.rig import DEFAULT_RIG

CYCLES = 4


@pytest.fixture(scope="module")
def engine():
    """A local cluster of one worker thread in this process (fast to start; the same engine code)."""
    with cpg.Engine(workers=1, processes=False) as e:
        yield e


def small_campaign(**changes) -> dict:
    data = {"runs": 3, "seed": 7, "controller": ["servo", "pid"], "isolator": "IUT_a", "supply_bar": 100,
            "amplitude_m": 0.02, "frequency_hz": 1.5, "cycles": CYCLES,
            "rig": {"piston_area_m2": {"normal": [0.01334, 0.001]}, "bulk_modulus_pa": {"uniform": [5e8, 1.5e9]}},
            "isolator_parameters": {"kd_n_per_m": {"lognormal": [1.25e6, 0.2]}}}
    data.update(changes)
    return data


def write(tmp_path, data, name="campaign.json") -> str:
    path = tmp_path / name
    path.write_text(data if isinstance(data, str) else json.dumps(data))
    return str(path)


def test_grid_robust_and_ablation_give_the_process_pools_numbers(engine):
    grid = compare.grid_points(controllers=("servo", "pid"), isolators=("IUT_a",), supplies_bar=(100.0,),
                               frequencies_hz=(1.5,))
    robust = compare.grid_points(robust=True, isolators=("HDRB_soft",), supplies_bar=(50.0,),
                                 frequencies_hz=(1.0,), rigs=("nominal",))[:3]
    ablation = [p for p in compare.ablation_points() if p.isolator == "IUT_b" and p.supply_bar == 150.0
                and p.frequency_hz == 1.5 and p.rig == "2x_flow_gain"][::7]
    points = grid + robust + ablation
    assert len(points) == 4 + 3 + 3 and len({p.label for p in points}) == len(points)
    rows, wall = engine.run(points, cycles=CYCLES)
    pool_rows, _ = compare.run_grid(points, cycles=CYCLES, processes=2)  # sim.engine.run_batch's process pool
    assert wall > 0 and [r["corner"] for r in rows] == [p.corner for p in points]
    assert cpg.same_rows(rows, pool_rows)
    assert all(math.isfinite(r["rms_last2"]) for r in rows)
    # the check can fail: one figure off in the last digit is a difference
    changed = [dict(r) for r in rows]
    changed[-1]["rms_last2"] = math.nextafter(changed[-1]["rms_last2"], 1.0)
    assert not cpg.same_rows(changed, pool_rows)


def test_monte_carlo_draws_change_the_plant_only_and_match_the_process_pool(engine):
    campaign = cpg.campaign_from_mapping(small_campaign())
    points = campaign.points()
    assert [(p.run, p.controller) for p in points] == [(r, c) for r in range(3) for c in ("servo", "pid")]
    for p in points:
        s = p.scenario(CYCLES)
        assert s.rig == DEFAULT_RIG and s.isolator.kd_n_per_m == 1.25e6  # the controller's rig: nominal
        assert set(s.plant_changes) == {"piston_area_m2", "bulk_modulus_pa", "kd_n_per_m"}
        assert s.plant_rig.piston_area_m2 == p.plant["piston_area_m2"] != DEFAULT_RIG.piston_area_m2
        assert s.plant_isolator.kd_n_per_m == p.plant["kd_n_per_m"]
        assert 5e8 <= p.plant["bulk_modulus_pa"] <= 1.5e9
    assert points[0].plant == points[1].plant != points[2].plant  # both controllers on the same plant
    rows, _ = engine.run(points, cycles=CYCLES)
    pool_rows, _ = compare.run_grid(points, cycles=CYCLES, processes=2)
    assert cpg.same_rows(rows, pool_rows)
    nominal = compare.run_grid([compare.GridPoint("servo", "IUT_a", 100.0, 1.5, 0.02, "nominal")], cycles=CYCLES,
                               processes=1)[0][0]
    assert rows[0]["rms_last2"] != nominal["rms_last2"]  # the drawn plant is the one simulated
    # the same file and seed give the same draws; another seed others
    assert [p.plant for p in cpg.campaign_from_mapping(small_campaign()).points()] == [p.plant for p in points]
    assert cpg.campaign_from_mapping(small_campaign(seed=8)).points()[0].plant != points[0].plant


def test_a_distribution_slightly_past_its_range_is_truncated_and_counted():
    # sigma_bw >= 0.01: normal(0.035, 0.01) puts 0.6 % of its mass below
    data = small_campaign(runs=1500, rig={}, isolator_parameters={"sigma_bw": {"normal": {"mean": 0.035,
                                                                                          "std": 0.01}}})
    campaign = cpg.campaign_from_mapping(data)
    draws = campaign.draws()
    lo, _hi, _ = LIMITS["sigma_bw"]
    assert len(draws) == 1500 and min(d["sigma_bw"] for d, _seed in draws) >= lo
    assert 0 < campaign.redrawn["sigma_bw"] < 30


@pytest.mark.parametrize("changes, message", [
    ({"rig": {"piston_area_m2": {"normal": [0.01334, -0.001]}}}, "std = -0.001 m2 is negative"),
    ({"rig": {"bulk_modulus_pa": {"uniform": [1.5e9, 5e8]}}}, "low = 1.5e+09 is not below high = 5e+08"),
    ({"rig": {"bulk_modulus_pa": {"gaussian": [1e9, 1e8]}}}, "unknown distribution 'gaussian'"),
    ({"rig": {"piston_area": {"normal": [0.01334, 0.001]}}}, "did you mean piston_area_m2"),
    ({"rig": {"kd_n_per_m": 1e6}}, "it is an isolator parameter: put it under isolator_parameters"),
    ({"isolator_parameters": {"mass_kg": 1000}}, "it is a rig parameter: put it under rig"),
    ({"runs": "ten"}, "runs = 'ten' is not a whole number"),
    ({"runs": 0}, "runs = 0 is outside"),
    ({"controller": 5}, "is not a controller name"),
    ({"controller": ["servo", "lqr"]}, "unknown controller 'lqr'"),
    ({"supply_bar": "100"}, "supply_bar = '100' is not a number"),
    ({"rig": {"bulk_modulus_pa": {"normal": ["1e9", 1e8]}}}, "is not a number"),
    ({"rig": {"bulk_modulus_pa": {"normal": [1e9]}}}, "is not [mean, std]"),
    ({"rig": {"bulk_modulus_pa": [1e9, 1e8]}}, "is not a number (a fixed value) or one distribution"),
    ({"rig": {"piston_area_m2": {"normal": [0.002, 0.001]}}}, "of its draws outside the allowed range"),
    ({"isolator_parameters": {"sigma_bw": {"uniform": [0.0, 1.0]}}}, "leaves the allowed range [0.01, 100]"),
    ({"isolator_parameters": {"n": {"lognormal": [-1.0, 0.1]}}}, "must both be > 0"),
    ({"rig": {"mass_kg": -5.0}}, "outside the allowed range [1, 1e+06] kg"),
    ({"rig": {"dead_zone_v": {"uniform": [5.0, 15.0]}}}, "cannot be a rig"),
    ({"amplitude_m": 0.5}, "amplitude"),
    ({"sead": 3}, "unknown key 'sead' (did you mean seed?)"),
])
def test_a_campaign_file_that_cannot_run_is_refused_with_one_message(tmp_path, changes, message):
    path = write(tmp_path, small_campaign(**changes))
    with pytest.raises(cpg.CampaignError) as err:
        cpg.load_campaign(path).points()
    assert message in str(err.value) and path in str(err.value)


def test_campaign_files_in_toml_and_broken_ones(tmp_path):
    toml = ('runs = 2\nisolator = "IUT_b"\nsupply_bar = 100\namplitude_m = 0.01\nfrequency_hz = 1.0\n'
            'controller = "servo"\n[rig]\nbulk_modulus_pa = { lognormal = { median = 1e9, sigma = 0.3 } }\n')
    campaign = cpg.load_campaign(write(tmp_path, toml, "lab.toml"))
    assert campaign.name == "lab" and campaign.controllers == ("servo",) and campaign.cycles == compare.CYCLES
    assert campaign.distributions["bulk_modulus_pa"] == cpg.Distribution("lognormal", 1e9, 0.3)
    with pytest.raises(cpg.CampaignError, match="not valid JSON"):
        cpg.load_campaign(write(tmp_path, '{"runs": 3,', "broken.json"))
    with pytest.raises(cpg.CampaignError, match="'runs' is missing"):
        cpg.load_campaign(write(tmp_path, {"isolator": "IUT_a"}))
    with pytest.raises(cpg.CampaignError, match="cannot read"):
        cpg.load_campaign(tmp_path / "absent.json")


def test_cli_refuses_a_bad_campaign_before_anything_runs(tmp_path, capsys):
    path = write(tmp_path, small_campaign(rig={"piston_area_m2": {"normal": [0.01334, -1]}}))
    out = tmp_path / "out"
    out.mkdir()
    t0 = time.perf_counter()
    code = main(["compare", "--monte-carlo", path, "--csv", str(out / "runs.csv"), "--figure", str(out / "e.png")])
    assert code == 2 and time.perf_counter() - t0 < 5
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "std = -1 m2 is negative" in err
    assert list(out.iterdir()) == []
    assert main(["compare", "--monte-carlo", path, "--robust"]) == 2
    assert "cannot go with --monte-carlo" in capsys.readouterr().err
    assert main(["compare", "--figure", str(out / "e.gif")]) == 2
    assert "must end in .png" in capsys.readouterr().err
    assert main(["compare", "--csv", str(tmp_path / "nowhere" / "runs.csv")]) == 2
    assert "does not exist" in capsys.readouterr().err


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_a_scheduler_that_does_not_answer_is_one_clear_message_within_seconds(tmp_path, capsys):
    out = tmp_path / "out"
    out.mkdir()
    address = f"tcp://127.0.0.1:{free_port()}"  # nobody listens there
    t0 = time.perf_counter()
    code = main(["compare", "--monte-carlo", write(tmp_path, small_campaign()), "--scheduler", address,
                 "--scheduler-timeout", "1", "--csv", str(out / "runs.csv"), "--figure", str(out / "e.png")])
    assert code == 2 and time.perf_counter() - t0 < 6
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and f"no dask scheduler answered at {address} within 1 s" in err
    assert list(out.iterdir()) == []
    assert main(["compare", "--scheduler", "tcp://127.0.0.1:notaport", "--scheduler-timeout", "1"]) == 2
    assert "not a scheduler address" in capsys.readouterr().err


def test_a_port_that_accepts_and_never_speaks_dask_is_not_a_hang():
    with socket.socket() as listener:  # the kernel completes the connection; nobody ever answers
        listener.bind(("127.0.0.1", 0))
        listener.listen(4)
        address = f"tcp://127.0.0.1:{listener.getsockname()[1]}"
        t0 = time.perf_counter()
        with pytest.raises(cpg.CampaignError, match="no dask scheduler answered .* within 1 s .nothing answered"):
            cpg.Engine(scheduler=address, timeout_s=1.0).__enter__()
        assert time.perf_counter() - t0 < 3


def test_cli_monte_carlo_on_a_cluster_writes_the_table_csv_and_figure(engine, tmp_path, capsys):
    path = write(tmp_path, small_campaign())
    csv_path, fig_path = tmp_path / "runs.csv", tmp_path / "errors.png"
    code = main(["compare", "--monte-carlo", path, "--scheduler", engine.cluster.scheduler_address,
                 "--csv", str(csv_path), "--figure", str(fig_path), "--markdown"])
    assert code == 0
    out = capsys.readouterr().out
    assert "| piston_area_m2 | 0.01334 m2 | normal(mean 0.01334, std 0.001) |" in out
    assert "| servo | 3 |" in out and "| pid | 3 |" in out and "RMS last2 % median" in out
    lines = csv_path.read_text().splitlines()
    header = lines[0].split(",")
    assert len(lines) == 1 + 6 and header[:2] == ["run", "controller"]
    assert {"rms_last2", "plant.piston_area_m2", "plant.kd_n_per_m", "meets_targets"} <= set(header)
    first = dict(zip(header, lines[1].split(","), strict=True))
    expected = cpg.campaign_from_mapping(small_campaign()).points()[0].plant["piston_area_m2"]
    assert float(first["plant.piston_area_m2"]) == expected and first["controller"] == "servo"
    assert fig_path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and fig_path.stat().st_size > 10_000
    assert sorted(p.name for p in tmp_path.iterdir()) == ["campaign.json", "errors.png", "runs.csv"]  # no temps
    code = main(["compare", "--monte-carlo", path, "--scheduler", engine.cluster.scheduler_address, "--json"])
    data = json.loads(capsys.readouterr().out)
    assert code == 0 and data["campaign"]["runs"] == 3 and set(data["groups"]) == {"servo", "pid"}
    assert data["groups"]["servo"]["error_distribution"]["runs"] == 3


def test_outputs_are_whole_or_absent(tmp_path, monkeypatch):
    rows = [{"controller": "servo", "rms_last2": 0.001, "diverged": False, "rms_from_cycle3": 0.002,
             "amplitude_error": 0.0, "phase_error_deg": 0.0, "saturated_share": 0.0, "limit_cycle_rms_m": 0.0,
             "amplitude_m": 0.02}]
    outputs = cpg.Outputs(str(tmp_path / "runs.csv"), str(tmp_path / "errors.svg"))

    def broken(*_args):
        raise RuntimeError("disk full")

    monkeypatch.setattr(cpg, "error_figure", broken)
    with pytest.raises(RuntimeError):
        outputs.write(rows, {"servo": rows}, "t")
    assert list(tmp_path.iterdir()) == []  # the CSV was complete, but not renamed: nothing is half-written
    monkeypatch.undo()
    assert outputs.write(rows, {"servo": rows}, "t") == [tmp_path / "runs.csv", tmp_path / "errors.svg"]
    assert (tmp_path / "errors.svg").read_text().lstrip().startswith("<?xml")
    assert (tmp_path / "runs.csv").read_text().splitlines()[1].endswith(",True,False")


def test_compare_backends_measures_both_paths_on_the_same_runs(engine):
    points = compare.grid_points(controllers=("servo",), isolators=("IUT_a",), supplies_bar=(100.0,),
                                 frequencies_hz=(1.5,))
    b = cpg.compare_backends(points, CYCLES, engine)
    assert b["runs"] == 2 and b["identical"] is True
    for key in ("inline", "process_pool", "distributed"):
        assert b[key]["wall_s"] > 0 and b[key]["per_run_ms"] > 0
    assert "rows identical on the three paths: yes" in cpg.backends_table(b)


def test_the_documented_campaign_file_is_a_campaign():
    import re
    import tomllib
    from pathlib import Path

    doc = (Path(__file__).resolve().parents[1] / "docs" / "compare.md").read_text()
    section = doc[doc.index("### The campaign file"):]
    text = re.search(r"```toml\n(.*?)```", section, re.S).group(1)
    campaign = cpg.campaign_from_mapping(tomllib.loads(text))
    assert campaign.runs == 1000 and campaign.controllers == ("servo", "pid") and campaign.cycles == 10
    assert set(campaign.distributions) == {"piston_area_m2", "bulk_modulus_pa", "flow_gain_m3_per_s_v_sqrt_pa",
                                           "dead_zone_v", "mass_kg", "coulomb_force_n", "kd_n_per_m", "kw_n",
                                           "rho_bw_per_m"}
    campaign.runs = 20
    assert len(campaign.points()) == 40 and campaign.redrawn["inconsistent"] == 0
