"""Per-cycle loop metrics on loops with closed-form answers, noisy, partial and tapered records."""

import math

import numpy as np
import pytest

from sim.isolator import PRESETS, simulate_loop
from sim.metrics import (
    CYCLE_KEYS,
    METRIC_KEYS,
    cycle_metrics,
    loop_area_j,
    loop_metrics,
    profile_cycle_starts_s,
    split_cycles,
)
from sim.profiles import SineProfile, pack_profile, target_series

DT = 1e-3


def bilinear_force(d, ku, kd, qd):
    """Ideal bilinear hysteresis: post-yield spring kd in parallel with an elastic-perfectly-plastic
    element of stiffness ku - kd and strength qd (yield displacement qd / (ku - kd))."""
    out = np.empty_like(d)
    fp, prev = 0.0, d[0]
    for i, x in enumerate(d):
        fp = min(max(fp + (ku - kd) * (x - prev), -qd), qd)
        prev = x
        out[i] = kd * x + fp
    return out


def sine(amplitude, frequency, cycles, phase=0.0):
    t = np.arange(0.0, cycles / frequency, DT)
    return t, amplitude * np.sin(2 * np.pi * frequency * t + phase)


def rel(a, b):
    return abs(a / b - 1.0)


@pytest.mark.parametrize("amplitude", [0.01, 0.02, 0.05])
def test_bilinear_loop_matches_closed_form(amplitude):
    ku, kd, qd = 2.0e7, 1.0e6, 2.0e4
    t, d = sine(amplitude, 0.5, 4)
    f = bilinear_force(d, ku, kd, qd)
    dy = qd / (ku - kd)
    keff = (qd + kd * amplitude) / amplitude
    edc = 4 * qd * (amplitude - dy)
    xi = edc / (2 * math.pi * keff * amplitude ** 2)
    cycles = cycle_metrics(t, d, f)
    assert len(cycles) >= 3
    for c in cycles[1:]:  # the first cycle starts from the virgin state
        assert set(CYCLE_KEYS) <= set(c)
        assert rel(c["k_eff_n_per_m"], keff) < 0.01
        assert rel(c["edc_j"], edc) < 0.01
        assert rel(c["xi_eff"], xi) < 0.01
        assert rel(c["qd_n"], qd) < 0.01
        assert rel(c["kd_n_per_m"], kd) < 0.03
        assert c["d_max_m"] == pytest.approx(amplitude, rel=1e-6)
        assert c["d_min_m"] == pytest.approx(-amplitude, rel=1e-6)


def test_spring_plus_viscous_damper():
    """F = k d + c d': EDC = pi c omega D^2, K_eff = k (forces at peak displacement), xi = c omega / (2 k)."""
    k, c, amplitude, frequency = 1.0e6, 3.0e5, 0.02, 0.5
    omega = 2 * math.pi * frequency
    t, d = sine(amplitude, frequency, 4)
    f = k * d + c * amplitude * omega * np.cos(omega * t)
    starts = np.arange(4) / frequency
    cycles = cycle_metrics(t, d, f, cycle_starts_s=starts, end_s=4 / frequency)
    assert [x["cycle"] for x in cycles] == [1, 2, 3, 4]
    for x in cycles:
        assert rel(x["edc_j"], math.pi * c * omega * amplitude ** 2) < 1e-3
        assert rel(x["k_eff_n_per_m"], k) < 1e-3
        assert rel(x["xi_eff"], c * omega / (2 * k)) < 1e-3
        # the peak force is larger than the force at peak displacement for a rate-dependent loop
        assert x["f_peak_max_n"] > 1.2 * x["f_max_n"]
        # Q_d of this ellipse is c omega D (the force at d = 0)
        assert rel(x["qd_n"], c * omega * amplitude) < 1e-2


def test_bouc_wen_edc_against_high_resolution_integral():
    iso = PRESETS["IUT_a"]
    amplitude, frequency, n = 0.02, 1.0, 4
    t, d = sine(amplitude, frequency, n)
    f = simulate_loop(iso, d, DT)
    cycles = cycle_metrics(t, d, f, cycle_starts_s=np.arange(n) / frequency, end_s=n / frequency)
    # reference: the last cycle at 100x the time resolution, trapezoidal work integral
    h = 1e-5
    th = np.arange(0.0, n / frequency + h / 2, h)
    dh = amplitude * np.sin(2 * np.pi * frequency * th)
    fh = simulate_loop(iso, dh, h, substeps=1)
    last = th >= (n - 1) / frequency - h / 2
    reference = float(np.sum(0.5 * (fh[last][1:] + fh[last][:-1]) * np.diff(dh[last])))
    assert reference > 0
    assert rel(cycles[-1]["edc_j"], reference) < 0.01
    # hardening loading branch: peak force is at peak displacement, K_d close to the model's k_d
    assert cycles[-1]["f_peak_max_n"] == pytest.approx(cycles[-1]["f_max_n"], rel=1e-3)
    assert rel(cycles[-1]["kd_n_per_m"], iso.kd_n_per_m) < 0.1


def test_noisy_loop_gives_no_spurious_cycles_and_stable_metrics():
    ku, kd, qd, amplitude = 2.0e7, 1.0e6, 2.0e4, 0.02
    t, d = sine(amplitude, 1.0, 6)
    f = bilinear_force(d, ku, kd, qd)
    clean = cycle_metrics(t, d, f)
    rng = np.random.default_rng(7)
    dn = d + rng.normal(0.0, 50e-6, d.size)  # 0.25 % of the amplitude, around every zero crossing
    fn = f + rng.normal(0.0, 0.01 * np.max(f), d.size)  # 1 % of the peak force
    noisy = cycle_metrics(t, dn, fn)
    assert abs(len(noisy) - len(clean)) <= 1  # only the record's ends may differ
    assert len(noisy) >= 5
    reference = clean[2]
    for c in noisy[1:5]:
        for key, tol in (("k_eff_n_per_m", 0.03), ("edc_j", 0.02), ("qd_n", 0.03), ("kd_n_per_m", 0.05)):
            assert rel(c[key], reference[key]) < tol, key


def test_partial_cycles_are_dropped():
    t, d = sine(0.02, 1.0, 8)
    part = slice(1250, 6700)  # starts a quarter into cycle 2, stops 70 % into cycle 7
    by_crossing = split_cycles(t[part], d[part])
    assert len(by_crossing) == 4  # cycles 3..6 are complete
    for i0, i1 in by_crossing:
        assert abs((i1 - i0) - 1000) <= 2
        assert abs(d[part][i0]) < 0.05 * 0.02 and d[part][i0 + 5] > d[part][i0]  # upward, near the centre
    by_phase = split_cycles(t[part], d[part], cycle_starts_s=np.arange(8.0), end_s=8.0)
    assert [t[part][i0] for i0, _ in by_phase] == pytest.approx([2.0, 3.0, 4.0, 5.0])


def test_tapered_cycles_are_split_and_full_cycles_exact():
    iso = PRESETS["IUT_a"]
    blocks = [SineProfile(0.02, 1.0, 8, 2)]
    t = np.arange(0.0, 8.0, DT)
    d = target_series(pack_profile(blocks), t)
    f = simulate_loop(iso, d, DT)
    starts, end = profile_cycle_starts_s(blocks)
    by_phase = cycle_metrics(t, d, f, starts, end)
    assert len(by_phase) == 8
    amplitudes = [c["d_max_m"] for c in by_phase]
    assert amplitudes[0] < 0.1 * 0.02 and amplitudes[-1] < 0.5 * 0.02  # taper-in / taper-out
    assert amplitudes[0] < amplitudes[1] < amplitudes[2] and amplitudes[-1] < amplitudes[-2] < amplitudes[-3]
    full = by_phase[3:6]
    for c in full:
        assert rel(c["d_max_m"], 0.02) < 1e-6 and c["closure"] < 1e-3
    assert max(c["edc_j"] for c in full) == pytest.approx(min(c["edc_j"] for c in full), rel=1e-3)
    assert by_phase[0]["closure"] > 0.05  # an open taper loop is flagged by its closure
    by_crossing = cycle_metrics(t, d, f)
    assert len(by_crossing) in (7, 8)  # the last cycle ends a hair before the centre line
    for c in by_crossing[3:6]:
        assert rel(c["edc_j"], full[0]["edc_j"]) < 1e-3


def test_offset_loop_uses_its_centre():
    ku, kd, qd = 2.0e7, 1.0e6, 2.0e4
    t, d = sine(0.02, 1.0, 4)
    f = bilinear_force(d, ku, kd, qd)
    shifted = cycle_metrics(t, d + 0.005, f)
    centred = cycle_metrics(t, d, f)
    for a, b in zip(shifted[1:], centred[1:], strict=False):
        for key in ("k_eff_n_per_m", "edc_j", "xi_eff", "qd_n", "kd_n_per_m"):
            assert rel(a[key], b[key]) < 1e-3, key


def test_loop_area_sign_and_degenerate_input():
    # a counter-clockwise loop in the d-F plane returns energy: negative area
    theta = np.linspace(0, 2 * np.pi, 400, endpoint=False)
    assert loop_area_j(np.cos(theta), np.sin(theta)) == pytest.approx(-np.pi, rel=1e-3)
    assert loop_area_j(np.cos(theta), -np.sin(theta)) == pytest.approx(np.pi, rel=1e-3)
    flat = loop_metrics(np.zeros(10), np.ones(10))
    assert flat["k_eff_n_per_m"] is None and flat["xi_eff"] is None
    with pytest.raises(ValueError, match="force_n"):
        loop_metrics([0, 1, 2], [0, 1])
    with pytest.raises(ValueError, match="non-finite"):
        loop_metrics([0, np.nan, 2], [0, 1, 2])
    with pytest.raises(ValueError, match="increase"):
        split_cycles([0, 1, 1, 2, 3, 4, 5, 6, 7], np.zeros(9))


# --- `isorig analyze` ---

def _write(path, header, rows):
    path.write_text(header + "\n" + "\n".join(",".join(str(v) for v in r) for r in rows) + "\n")
    return str(path)


def test_analyze_json_on_a_record_with_extra_columns(tmp_path, capsys):
    import json

    from isorig.cli import main

    ku, kd, qd, amplitude = 2.0e7, 1.0e6, 2.0e4, 0.02
    t, d = sine(amplitude, 1.0, 4)
    f = bilinear_force(d, ku, kd, qd)
    rows = [(f"{a:.6f}", "x", f"{b:.9g}", f"{c:.9g}") for a, b, c in zip(t, d, f, strict=True)]
    path = _write(tmp_path / "rec.csv", "time_s,comment,displacement_m,force_n", rows)
    assert main(["analyze", path, "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert len(out["cycles"]) == 4
    assert set(out["cycles"][0]) == {"cycle", "d_max_m", "d_min_m", "f_max_n", "f_min_n", "k_eff_n_per_m",
                                     "edc_j", "xi_eff", "qd_n", "kd_n_per_m"}
    assert rel(out["cycles"][2]["edc_j"], 4 * qd * (amplitude - qd / (ku - kd))) < 0.01
    assert main(["analyze", path]) == 0
    table = capsys.readouterr().out
    assert "K_eff kN/mm" in table and len(table.strip().splitlines()) == 2 + 4


def test_analyze_works_on_simulate_output(tmp_path, capsys):
    import json

    from isorig.cli import main
    from sim.engine import Scenario, Simulation
    from sim.records import write_csv

    scenario = Scenario.sine("IUT_a", 100.0, 0.02, 1.0, 4, taper_cycles=1)
    write_csv(tmp_path / "timeseries.csv", Simulation(scenario).run().samples)
    assert main(["analyze", str(tmp_path / "timeseries.csv"), "--json", "--frequency-hz", "1"]) == 0
    cycles = json.loads(capsys.readouterr().out)["cycles"]
    assert [c["cycle"] for c in cycles] == [1, 2, 3, 4]
    assert 0.015 < cycles[2]["d_max_m"] < 0.025 and cycles[2]["edc_j"] > 100


@pytest.mark.parametrize("header, rows, message", [
    ("time_s,displacement_m", [(i, 0.0) for i in range(20)], "missing column(s) force_n"),
    ("time_s,displacement_m,force_n", [(i, 0.0, "abc" if i == 5 else 1.0) for i in range(20)],
     "line 7, column force_n: 'abc' is not a number"),
    ("time_s,displacement_m,force_n", [(i, 0.0, 1.0) for i in range(3)], "at least 10"),
    ("time_s,displacement_m,force_n", [(i if i != 8 else 2, 0.0, 1.0) for i in range(20)],
     "time_s must increase strictly"),
    ("time_s,displacement_m,force_n", [(i, "" if i == 4 else 0.0, 1.0) for i in range(20)],
     "column displacement_m"),
])
def test_analyze_rejects_malformed_csv(tmp_path, capsys, header, rows, message):
    from isorig.cli import main

    path = _write(tmp_path / "bad.csv", header, rows)
    assert main(["analyze", path]) == 2
    err = capsys.readouterr().err
    assert message in err
    assert len(err.strip().splitlines()) == 1 and "Traceback" not in err


def test_analyze_missing_file(tmp_path, capsys):
    from isorig.cli import main

    assert main(["analyze", str(tmp_path / "nope.csv")]) == 2
    assert "cannot read" in capsys.readouterr().err


def test_optional_columns_with_empty_cells_after_an_unused_column(tmp_path):
    """numpy's converters are keyed by the file's column numbers: an optional column that is not where its place
    among the read columns says still takes empty cells."""
    from sim.metrics import read_csv_columns

    path = tmp_path / "r.csv"
    path.write_text("time_s,displacement_m,force_n,note,ar_hat\n0,0,0,a,1\n0.1,0,0,b,\n0.2,0,0,c,2\n")
    cols = read_csv_columns(path, optional=("ar_hat",), min_rows=1)
    np.testing.assert_array_equal(cols["ar_hat"], [1.0, np.nan, 2.0])
    only = read_csv_columns(path, required=(), optional=("ar_hat",), min_rows=1)
    assert list(only) == ["ar_hat"]
    np.testing.assert_array_equal(only["ar_hat"], [1.0, np.nan, 2.0])


def test_cycle_phases_and_headline_figures_from_steady_cycles_only():
    from sim.engine import Scenario, Simulation
    from sim.metrics import headline_figures
    from sim.tracking import cycle_phase

    assert [cycle_phase(c, 6, 1) for c in range(6)] == ["taper_in"] + ["steady"] * 4 + ["taper_out"]
    assert cycle_phase(3, 4, 1, planned_cycles=10) == "ramp_out"  # a stop cut the block to 4 cycles
    assert cycle_phase(0, 3, 0) == "steady"
    summary = Simulation(Scenario.sine("IUT_a", 100.0, 0.02, 1.0, 6, taper_cycles=1)).run().summary()
    cycles = summary["cycles"]
    assert [c["phase"] for c in cycles] == ["taper_in", "steady", "steady", "steady", "steady", "taper_out"]
    keff = [c["k_eff_n_per_m"] for c in cycles]
    assert keff[0] > 1.05 * max(keff[1:5])  # a taper cycle is smaller and stiffer: it would bias the headline
    head = summary["headline"]
    assert head["steady_cycles"] == 4 and head["excluded_cycles"] == {"taper_in": 1, "taper_out": 1}
    assert head["means"]["k_eff_n_per_m"] == pytest.approx(np.mean(keff[1:5]))
    # cycles whose metrics failed, or with no phase (older records), are handled
    mixed = [{"phase": "steady", "k_eff_n_per_m": 2.0}, {"phase": "steady", "error": "non-finite"},
             {"k_eff_n_per_m": 4.0}, {"phase": "ramp_out", "k_eff_n_per_m": 100.0}]
    head = headline_figures(mixed)
    assert head["means"]["k_eff_n_per_m"] == 3.0 and head["steady_cycles"] == 3
    assert head["excluded_cycles"] == {"ramp_out": 1}


def test_cycle_metrics_can_skip_a_cycle_with_a_failed_sensor():
    from sim.metrics import cycle_metrics

    t = np.arange(0.0, 3.0, 1e-3)
    d = 0.01 * np.sin(2 * np.pi * t)
    f = 1e5 * d
    d[1500] = np.nan  # the second cycle has a NaN reading
    with pytest.raises(ValueError, match="non-finite"):
        cycle_metrics(t, d, f, [0.0, 1.0, 2.0], 3.0)
    cycles = cycle_metrics(t, d, f, [0.0, 1.0, 2.0], 3.0, skip_bad=True)
    assert [("error" in c) for c in cycles] == [False, True, False]
    assert cycles[0]["k_eff_n_per_m"] == pytest.approx(1e5, rel=1e-3)


def test_closed_loop_error_leaves_out_the_open_loop_ramp():
    """|y - r| over the rows with a target; the valve ramp after a trip has none and is not judged."""
    import numpy as np

    from sim.samples import Samples
    from sim.tracking import closed_loop_error

    rows = Samples(np.zeros((6, len(Samples.empty().fields))))
    rows["target_m"] = [0.0, 0.001, 0.002, 0.003, np.nan, np.nan]
    rows["displacement_m"] = [0.0, 0.002, 0.002, 0.002, 0.05, 0.05]
    rows["voltage_v"] = [0.0, 1.0, -2.0, 0.5, 9.0, 9.0]
    err = closed_loop_error(rows)
    assert err["peak_abs_y_minus_r_m"] == 0.001 and err["peak_abs_voltage_v"] == 2.0
    assert abs(err["rms_y_minus_r_m"] - np.sqrt(2 * 0.001 ** 2 / 4)) < 1e-15
    rows["target_m"] = np.nan
    assert closed_loop_error(rows) == {}


def test_tracking_figures_leave_out_the_periods_whose_measurement_was_lost():
    """Per-cycle errors, the last two cycles' fit and |y - r| are taken over the measured rows: a lost period
    (FLAG_LOST) holds an older reading, and a host stall must not read as the table's tracking error."""
    import numpy as np

    from sim.engine import Scenario
    from sim.measurement import FLAG_LOST
    from sim.samples import Samples
    from sim.tracking import closed_loop_error, tracking_summary

    scenario = Scenario.sine("IUT_a", 100, 0.02, 1.0, 4, taper_cycles=1)
    t = np.arange(0, 4.0, 1e-3)
    rows = Samples(np.zeros((t.size, len(Samples.empty().fields))))
    rows["time_s"] = t
    rows["target_m"] = 0.02 * np.sin(2 * np.pi * t)
    rows["model_m"] = rows["target_m"]
    rows["displacement_m"] = 0.02 * np.sin(2 * np.pi * (t - 0.001))
    lost = slice(2000, 2012)  # in the third cycle (a steady one), at full speed
    rows["flags"][lost] = FLAG_LOST
    clean = tracking_summary(rows, scenario)
    clean_error = closed_loop_error(rows)
    rows["displacement_m"][lost] = rows["displacement_m"][1999]  # what a lost period's row holds
    judged = tracking_summary(rows, scenario)
    assert judged["lost_periods"] == 12 and clean["lost_periods"] == 12
    assert judged["cycles"] == clean["cycles"] and judged["last_two_cycles"] == clean["last_two_cycles"]
    assert judged["rms_y_minus_r_m"] == clean["rms_y_minus_r_m"]
    assert closed_loop_error(rows) == clean_error
    # the measured rows alone: a 1 ms lag on 20 mm at 1 Hz peaks at 2 sin(pi / 1000) 20 mm = 0.126 mm
    assert judged["cycles"][2]["peak_abs_y_minus_r_m"] == pytest.approx(0.02 * 2 * np.sin(np.pi * 1e-3), rel=1e-3)
    rows["flags"][lost] = 0  # the same held rows taken as measurements: the stall reads as a 1.5 mm error
    assert tracking_summary(rows, scenario)["cycles"][2]["peak_abs_y_minus_r_m"] > 1e-3


def test_loops_leave_out_the_rows_of_lost_periods():
    """A lost period's row holds the previous reading (FLAG_LOST): a point of the loop repeated, which weights
    the fitted branches (Q_d, K_d) towards it. The loop is judged on the measured rows only, in the per-cycle
    metrics of a record (sim.metrics.scenario_cycle_metrics) as in cycle_metrics."""
    from sim.engine import Scenario
    from sim.measurement import FLAG_LOST
    from sim.metrics import scenario_cycle_metrics
    from sim.samples import Samples

    iso = PRESETS["IUT_a"]
    scenario = Scenario.sine("IUT_a", 100, 0.02, 1.0, 4, taper_cycles=1)
    starts, end = profile_cycle_starts_s(scenario.profile)
    t = np.arange(0.0, end, DT)
    d = target_series(pack_profile(scenario.profile), t)
    f = simulate_loop(iso, d, DT)
    lost = np.zeros(t.size, dtype=bool)
    lost[2100:2250] = True  # 150 ms in the third cycle (a steady one), on the loading branch
    held_d, held_f = d.copy(), f.copy()
    held_d[lost], held_f[lost] = d[2099], f[2099]  # what the rows of lost periods hold

    judged = cycle_metrics(t, held_d, held_f, starts, end, measured=~lost)
    third = np.flatnonzero(~lost[2000:3001]) + 2000  # the third cycle's loop (closed by the next cycle's first row)
    expected = loop_metrics(d[third], f[third])
    assert (judged[2]["i_start"], judged[2]["i_end"]) == (2000, 3000)
    for key in METRIC_KEYS:
        assert judged[2][key] == pytest.approx(expected[key], rel=1e-12), key
    as_measured = cycle_metrics(t, held_d, held_f, starts, end)  # the held rows taken as readings
    assert abs(as_measured[2]["kd_n_per_m"] / expected["kd_n_per_m"] - 1) > 1e-4  # 0.045 % (a small bias)
    assert [c["edc_j"] for c in judged[:2]] == [c["edc_j"] for c in as_measured[:2]]  # no lost row there

    rows = Samples(np.zeros((t.size, len(Samples.empty().fields))))
    rows["time_s"], rows["displacement_m"], rows["force_n"] = t, held_d, held_f
    rows["flags"][lost] = FLAG_LOST
    from_record = scenario_cycle_metrics(rows, scenario)
    assert from_record[2]["kd_n_per_m"] == pytest.approx(expected["kd_n_per_m"], rel=1e-12)
    with pytest.raises(ValueError, match="measured has 5 rows"):
        cycle_metrics(t, d, f, starts, end, measured=np.ones(5, dtype=bool))
