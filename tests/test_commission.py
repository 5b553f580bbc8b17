"""Commissioning a rig (sim.commission, sim.controllers.excitation, isorig identify rig): the excitation keeps
its bounds on rigs unlike the declared one, the fit finds the rig's parameters, and a fit that cannot be
trusted writes no rig file."""

import json
import math
import subprocess
import sys

import numpy as np
import pytest

from sim.commission.identify import Conditions, excitation_scenario, identify
from sim.engine import Simulation
from sim.isolator import NO_SPECIMEN, PRESETS
from sim.rig import DEFAULT_RIG
from sim.rigfile import load_rig_file, rig_file_data, write_rig_file

#: a heavy table on a soft oil column (22 Hz), a slow valve with a wide dead zone, a late position reading
SOFT_SLOW = {"mass_kg": 3000.0, "bulk_modulus_pa": 4.5e8, "valve_natural_frequency_rad_s": 2 * math.pi * 45,
             "dead_zone_v": 1.15, "position_latency_s": 1.8e-3, "flow_gain_m3_per_s_v_sqrt_pa": 2.2e-7}
#: a light, stiff, fast rig with no dead zone and a valve null off by 60 mV
LIGHT_FAST = {"mass_kg": 850.0, "bulk_modulus_pa": 1.5e9, "half_volume_m3": 1.4e-3,
              "valve_natural_frequency_rad_s": 2 * math.pi * 140, "dead_zone_v": 0.0, "driver_offset_v": -0.06,
              "flow_gain_m3_per_s_v_sqrt_pa": 3.5e-7}


def run_excitation(plant: dict, isolator=PRESETS["IUT_a"], supply_bar=100.0, stroke_m=0.002, velocity=0.02):
    c = Conditions("simulated", supply_bar * 1e5, 1.25e5, isolator.name, 0.0, stroke_m, velocity)
    result = Simulation(excitation_scenario(isolator, c, DEFAULT_RIG, plant), validate=False).run()
    return c, result.samples


def motion_peaks(samples) -> tuple[float, float]:
    """(largest |y|, largest |velocity| as the velocity detector reads it: 5-period difference of the reading)."""
    y = samples["measured_displacement_m"]
    return float(np.max(np.abs(samples["displacement_m"]))), float(np.max(np.abs(y[5:] - y[:-5]) / 5e-3))


@pytest.mark.parametrize("plant", [SOFT_SLOW, LIGHT_FAST, {}], ids=["soft-slow", "light-fast", "declared"])
def test_the_excitation_keeps_its_bounds_on_rigs_it_was_not_told_of(plant):
    _c, s = run_excitation(plant)
    y_max, v_max = motion_peaks(s)
    assert y_max <= 0.75 * 0.002 + 2e-4  # the guard is 75 % of the stroke bound; the valve's lag may add a little
    assert v_max < 0.02
    phase = s["as_hat"]
    assert np.any(phase == 1.0) and phase[-1] == 3.0  # it found the valve both ways, dithered, and came to rest
    assert abs(s["displacement_m"][-1]) < 2e-4  # back where it started


def test_smaller_bounds_are_kept_too():
    _c, s = run_excitation(SOFT_SLOW, stroke_m=0.001, velocity=0.01)
    y_max, v_max = motion_peaks(s)
    assert y_max <= 0.75 * 0.001 + 1e-4
    assert v_max < 0.01


def test_the_fit_finds_a_rig_it_was_not_told_of():
    c, s = run_excitation(SOFT_SLOW)
    ident = identify(s, DEFAULT_RIG, c)
    assert ident.trusted, ident.problems
    fitted = ident.rig
    for name, true in SOFT_SLOW.items():
        assert getattr(fitted, name) == pytest.approx(true, rel=0.05, abs=2e-4), name
    assert fitted.driver_offset_v == pytest.approx(DEFAULT_RIG.driver_offset_v, abs=0.01)
    assert ident.fit.flow_r2 > 0.999
    assert ident.response.velocity_nrmse < 0.1
    # the uncertainties are honest enough: within 4 sigma of the truth
    for name in ("mass_kg", "bulk_modulus_pa", "dead_zone_v", "position_latency_s"):
        e = ident.fit.estimates[name]
        assert abs(e.value - SOFT_SLOW[name]) < 4 * e.std, name
    # the measured and modelled frequency responses agree where the dither put its lines
    r = ident.response
    assert r.frequency_hz.size >= 20
    ratio = np.abs(r.velocity_model) / np.abs(r.velocity_measured)
    low = r.frequency_hz <= 50.0
    assert np.all((ratio[low] > 0.9) & (ratio[low] < 1.1))
    # above 50 Hz within 30 %, but where the measured response has a notch (a tenth of its neighbours' level; at
    # 64 Hz here) a ratio of two small numbers says little: there the difference is judged against the largest
    measured = np.abs(r.velocity_measured)
    notch = np.zeros(measured.size, dtype=bool)
    notch[1:-1] = measured[1:-1] < 0.2 * np.minimum(measured[:-2], measured[2:])
    assert np.all((ratio[~notch] > 0.7) & (ratio[~notch] < 1.4))
    assert np.all(np.abs(r.velocity_model - r.velocity_measured)[notch] < 0.05 * np.max(measured))


@pytest.mark.slow  # two whole commissionings: scripts/test.sh --quick leaves it out
def test_a_bare_rig_and_a_rig_without_dead_zone():
    c = Conditions("simulated", 100e5, 0.0, "none", 0.0)
    s = Simulation(excitation_scenario(NO_SPECIMEN, c, DEFAULT_RIG, LIGHT_FAST), validate=False).run().samples
    ident = identify(s, DEFAULT_RIG, c)
    assert ident.trusted, ident.problems
    assert ident.rig.dead_zone_v < 0.01
    assert ident.rig.driver_offset_v == pytest.approx(-0.06, abs=0.005)
    assert ident.rig.mass_kg == pytest.approx(850.0, rel=0.05)


def test_a_run_cut_short_is_not_fitted():
    c, s = run_excitation({})
    ident = identify(s[: 4000], DEFAULT_RIG, c)  # stopped during the sweeps: no dither
    assert not ident.trusted
    assert ident.fit is None and "did not run to its end" in ident.problems[0]


def test_a_run_whose_sweeps_never_found_the_valve_both_ways_is_not_fitted():
    """The excitation rests at 0 V when its sweeps cannot find the valve both ways: the run ends, but no dither ran
    (foreign rig 46 was trusted from its sweeps alone, with a valve of 215 against 796 rad/s)."""
    from sim.samples import SAMPLE_FIELDS, Samples

    c, s = run_excitation({})
    arr = s.array.copy()
    phase = arr[:, SAMPLE_FIELDS.index("as_hat")]
    phase[(phase == 1.0) | (phase == 2.0)] = 3.0  # as if it had rested after its sweeps
    ident = identify(Samples(arr), DEFAULT_RIG, c)
    assert not ident.trusted and ident.fit is None
    assert "the dither never ran" in ident.problems[0]


def test_a_noisy_position_sensor_gives_a_refusal_that_says_why():
    c, s = run_excitation({"position_noise_rms_m": 5e-5})  # 50 um of noise on a 2 mm excitation
    ident = identify(s, DEFAULT_RIG, c)
    assert not ident.trusted
    # 50 um of noise is read as motion by the sweeps' 5-period velocity: they do not find the valve's edges, and
    # no dither runs (before, what the sweeps and the rest recorded was fitted, and refused as too uncertain)
    assert any(w in p for p in ident.problems for w in ("uncertain", "explains", "reproduces", "dither never ran")), \
        ident.problems


def test_the_excitation_is_not_a_test_controller():
    from sim.controllers import CONTROLLER_NAMES, make_controller

    assert "excitation" not in CONTROLLER_NAMES
    assert make_controller("excitation").name == "excitation"


def test_a_rig_file_keeps_its_commissioning(tmp_path):
    rig = DEFAULT_RIG.with_changes(mass_kg=2000.0)
    data = rig_file_data(rig, "lab rig", "commissioned", {"date": "2026-11-27T08:00:00+00:00", "rig": "simulated",
                                                          "fit": {"flow_r2": 0.9999}}, always=("dead_zone_v",))
    path = write_rig_file(tmp_path / "rig.json", data)
    back = load_rig_file(path)
    assert back.parameters.mass_kg == 2000.0 and back.parameters.dead_zone_v == DEFAULT_RIG.dead_zone_v
    assert back.commissioning["rig"] == "simulated"
    assert back.to_dict()["commissioning"] == {"date": "2026-11-27T08:00:00+00:00", "rig": "simulated",
                                               "flow_r2": 0.9999}
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps({"commissioning": "yesterday"}))
    with pytest.raises(ValueError, match="commissioning must be an object"):
        load_rig_file(bad)


def isorig(*args, cwd):
    return subprocess.run([sys.executable, "-m", "isorig", *args], capture_output=True, text=True, cwd=cwd,
                          timeout=300)


@pytest.mark.slow  # the CLI's commissioning and fit: scripts/test.sh --quick leaves it out
def test_identify_rig_writes_a_rig_file_that_the_controller_then_follows(tmp_path):
    plant = ["--plant-set", "mass_kg=3000", "--plant-set", "bulk_modulus_pa=4.5e8"]
    out = isorig("identify", "rig", "--supply-bar", "100", *plant, "--out", "rig.json", cwd=tmp_path)
    assert out.returncode == 0, out.stdout + out.stderr
    assert "verdict: trusted" in out.stdout
    described = load_rig_file(tmp_path / "rig.json")
    assert described.parameters.mass_kg == pytest.approx(3000.0, rel=0.05)
    assert described.parameters.bulk_modulus_pa == pytest.approx(4.5e8, rel=0.05)
    c = described.commissioning
    assert c["trusted"] and c["supply_pa"] == 100e5 and c["rig_time_s"] <= 60.0
    assert set(c["estimates"]) >= {"mass_kg", "dead_zone_v", "position_latency_s", "valve_natural_frequency_rad_s"}


@pytest.mark.slow  # the CLI's commissioning, several times: scripts/test.sh --quick leaves it out
def test_identify_rig_refuses_bad_bounds_and_writes_nothing(tmp_path):
    out = isorig("identify", "rig", "--supply-bar", "100", "--max-stroke-m", "0.5", "--out", "rig.json",
                 cwd=tmp_path)
    assert out.returncode == 2 and "max_stroke_m" in out.stderr and "Traceback" not in out.stderr
    out = isorig("identify", "rig", "--supply-bar", "100", "--out", "rig.toml", cwd=tmp_path)
    assert out.returncode == 2 and "must end in .json" in out.stderr
    out = isorig("identify", "rig", "--supply-bar", "100", "--plant-set", "position_noise_rms_m=5e-5",
                 "--out", "rig.json", cwd=tmp_path)
    assert out.returncode == 1 and "NOT trusted" in out.stdout
    assert not (tmp_path / "rig.json").exists()


#: the noise of real transducers (issue 32; docs/commissioning.md, "Sensor noise"): position 0.3 um RMS read at
#: 1 um resolution, load pressure 0.28 bar RMS (two transducers of 0.2 bar each)
REAL_TRANSDUCERS = {"position_noise_rms_m": 3e-7, "position_resolution_m": 1e-6, "pressure_noise_rms_pa": 2.8e4}


@pytest.mark.slow  # a whole commissioning: scripts/test.sh --quick leaves it out
def test_a_rig_read_by_real_transducers_is_commissioned_with_its_values_and_its_noise_measured():
    """The load pressure's noise is a regressor's noise in the flow balance: least squares pulled the oil column's
    compliance towards zero and the record was refused (flow balance 94 %, replay 26 %). The fit measures each
    reading's noise above 350 Hz, takes its share out of the normal equations and judges the balance against
    what the noise leaves to explain."""
    from sim.commission.signals import signals_from_samples

    c, s = run_excitation(REAL_TRANSDUCERS)
    noise = signals_from_samples(s, 1e-3).noise
    assert noise["load_pressure_pa"] == pytest.approx(2.8e4, rel=0.1)
    assert noise["position_m"] == pytest.approx(math.hypot(3e-7, 1e-6 / math.sqrt(12)), rel=0.15)
    ident = identify(s, DEFAULT_RIG, c)
    assert ident.trusted, ident.problems
    for name in ("mass_kg", "bulk_modulus_pa", "valve_natural_frequency_rad_s", "dead_zone_v"):
        e = ident.fit.estimates[name]
        assert abs(e.value - getattr(DEFAULT_RIG, name)) < 3.0 * e.std, (name, e.value, e.std)


def test_a_link_that_loses_measurements_and_commands_is_fitted_on_what_the_rig_did():
    """On a loaded host 2 % of the periods lose their measurement (the reading is held) or their command (the
    rig holds the one before): the held readings are interpolated, the command is the one the rig applied,
    and the fit leaves their neighbourhood out (an emulator record on a loaded machine: mass 20 % off before)."""
    from sim.commission.signals import signals_from_samples
    from sim.measurement import FLAG_LOST, STATUS_COMMAND_MISSED

    c, s = run_excitation(SOFT_SLOW)
    arr = s.array.copy()
    flags_col = s.array.shape[1] - 1
    rng = np.random.default_rng(3)
    lost = np.sort(rng.choice(np.arange(100, len(s) - 100), size=len(s) // 50, replace=False))
    names = ("measured_displacement_m", "load_pressure_pa", "force_n")
    from sim.samples import SAMPLE_FIELDS, Samples

    for k in lost:
        for name in names:
            j = SAMPLE_FIELDS.index(name)
            arr[k, j] = arr[k - 1, j]
        arr[k, flags_col] = FLAG_LOST
    missed = np.array([1000, 5000, 9000])
    arr[missed + 1, flags_col] = STATUS_COMMAND_MISSED
    damaged = Samples(arr)
    sig = signals_from_samples(damaged, 1e-3)
    assert np.all(sig.u[missed] == arr[missed - 1, SAMPLE_FIELDS.index("voltage_v")])
    assert not sig.valid[lost].any() and not sig.valid[missed].any()
    ident = identify(damaged, DEFAULT_RIG, c)
    assert ident.trusted, ident.problems
    assert ident.rig.mass_kg == pytest.approx(SOFT_SLOW["mass_kg"], rel=0.05)
    assert ident.rig.position_latency_s == pytest.approx(SOFT_SLOW["position_latency_s"], abs=1e-4)
    arr[::5, flags_col] = FLAG_LOST  # a link that loses a fifth of the periods is not fitted
    worse = identify(Samples(arr), DEFAULT_RIG, c)
    assert not worse.trusted and "link is not good enough" in worse.problems[0]


def test_a_sweep_does_not_take_the_spring_back_for_the_valve_opening():
    """A stiff specimen on a heavy table with a narrow dead zone rings back when a sweep's valve closes: the next
    sweep once took that motion for the valve opening, each edge crept inwards (0.37, 0.31 ... 0.10 V for a
    0.34 V dead zone) and the dither then stayed inside the dead zone (drawn rig 19 of the campaign)."""
    plant = {"mass_kg": 3372.0, "bulk_modulus_pa": 9.37e8, "half_volume_m3": 1.81e-3, "dead_zone_v": 0.342,
             "flow_gain_m3_per_s_v_sqrt_pa": 3.22e-7, "valve_natural_frequency_rad_s": 350.2,
             "position_latency_s": 1.01e-3, "coulomb_force_n": 1109.0, "friction_coefficient": 0.0113}
    c, s = run_excitation(plant)
    assert np.nanmax(s["ay_hat"][s["as_hat"] == 1.0]) == pytest.approx(0.342, abs=0.05)  # the dead zone it saw
    ident = identify(s, DEFAULT_RIG, c)
    assert ident.trusted, ident.problems
    assert ident.response.opening_share > 0.5
