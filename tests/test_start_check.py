"""Issue 34 item 5: a sine without a taper starts at full velocity from rest; a start whose catch-up is expected to
trip a limit is refused at set-up (sim.profiles.start_problem, `isorig simulate`), naming taper_cycles; and the
CSV's model_m, ar_hat, ay_hat, as_hat columns say what the chosen controller puts in them (sim.records)."""

import csv

import pytest

from isorig.cli import main
from sim.engine import Scenario
from sim.profiles import ProfileError, start_problem, start_velocity_m_per_s
from sim.records import column_key, column_labels
from sim.rig import DEFAULT_RIG
from sim.safety import default_limits, make_limits
from sim.samples import RECORD_FIELDS

# measured on main: IUT_b at 100 bar, 20 mm at 1.25 Hz, no taper: 410 mm/s 20 ms in against the pump's 391 mm/s
MEASURED = {"isolator": "IUT_b", "supply_bar": 100, "amplitude_m": 0.02, "frequency_hz": 1.25}
CLI = ["simulate", "--isolator", "IUT_b", "--supply-bar", "100", "--amplitude-m", "0.02", "--frequency-hz", "1.25"]


def scenario(taper_cycles: int, cycles: int = 10, controller: str = "servo") -> Scenario:
    return Scenario.sine(MEASURED["isolator"], MEASURED["supply_bar"], MEASURED["amplitude_m"],
                         MEASURED["frequency_hz"], cycles, controller=controller, taper_cycles=taper_cycles)


def test_the_measured_untapered_start_is_refused_on_taper_cycles():
    assert start_velocity_m_per_s(scenario(0).profile[0]) == pytest.approx(0.157, abs=1e-3)
    problem = start_problem(scenario(0), default_limits(DEFAULT_RIG))
    assert isinstance(problem, ProfileError) and problem.field == "taper_cycles" and problem.value == 0
    text = str(problem)
    assert text.startswith("taper_cycles >= 1 needed")
    assert "157 mm/s from rest" in text and "velocity limit tripped" in text and "391.1 mm/s" in text
    assert "taper_cycles >= 1" in problem.limit


def test_a_tapered_start_and_a_start_without_limits_pass():
    assert start_velocity_m_per_s(scenario(1).profile[0]) == 0.0
    assert start_problem(scenario(1), default_limits(DEFAULT_RIG)) is None
    assert start_problem(scenario(0), None) is None  # --no-limit-detectors: nothing to trip
    indicate = make_limits(DEFAULT_RIG, {"actions": {"velocity_m_per_s": "indicate"}})
    assert start_problem(scenario(0), indicate) is None  # the velocity limit only indicates


@pytest.mark.parametrize("case", [("IUT_a", 100, 0.02, 0.5), ("IUT_a", 100, 0.02, 1.0)])
def test_the_papers_untapered_starts_within_the_limits_still_run(case):
    """docs/paper-results.md: the paper starts at rest (taper 0); where that stays within the limits it runs."""
    iso, bar, a, f = case
    s = Scenario.sine(iso, bar, a, f, 10, controller="mrac", taper_cycles=0)
    assert start_problem(s, default_limits(DEFAULT_RIG)) is None


def test_simulate_refuses_the_measured_start_before_it_runs(tmp_path, capsys):
    out = tmp_path / "run"
    assert main([*CLI, "--cycles", "10", "--taper-cycles", "0", "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert "--taper-cycles 0" in err and "taper_cycles >= 1 needed" in err and "157 mm/s from rest" in err
    assert "--no-limit-detectors" in err
    assert not out.exists()  # refused before anything ran


def test_a_tapered_servo_run_names_the_servos_quantities_in_its_csv(tmp_path, capsys):
    assert main([*CLI, "--cycles", "2", "--taper-cycles", "1", "--out", str(tmp_path)]) == 0, capsys.readouterr()
    with open(tmp_path / "timeseries.csv") as fh:
        header = next(csv.reader(fh))
    from sim.controllers import ADAPTED

    declared = {a.column: a for a in ADAPTED["servo"]}
    for column in ("model_m", "ar_hat", "ay_hat", "as_hat"):  # e.g. "as_hat: learned frequency (Hz)"
        a = declared[column]
        assert header[RECORD_FIELDS.index(column)] == f"{column}: {a.name} ({a.unit})"
    assert tuple(column_key(c) for c in header) == RECORD_FIELDS
    # the readers find the columns by their keys: isorig analyze reads the file as before
    assert main(["analyze", str(tmp_path / "timeseries.csv"), "--json", "--frequency-hz", "1.25"]) == 0


def test_an_mrac_run_keeps_the_papers_column_names(tmp_path):
    assert main(["simulate", "--controller", "mrac", "--cycles", "2", "--out", str(tmp_path)]) in (0, 1)
    with open(tmp_path / "timeseries.csv") as fh:
        header = next(csv.reader(fh))
    assert tuple(header) == RECORD_FIELDS


def test_labels_per_controller():
    assert column_labels("mrac") == list(RECORD_FIELDS) == column_labels("pid") == column_labels(None)
    excitation = column_labels("excitation")
    assert "ar_hat: dither gate (-)" in excitation and "as_hat: phase (-)" in excitation
    assert all("," not in c for c in column_labels("servo") + excitation)  # one plain CSV header row
