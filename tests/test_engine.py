import numpy as np
import pytest

from sim.engine import Scenario, Simulation, run_batch
from sim.profiles import ProfileError, SineProfile, pack_profile, target, target_series
from sim.samples import SAMPLE_FIELDS, Samples


def test_taper_profile_starts_and_ends_at_rest():
    blocks = pack_profile([SineProfile(0.02, 1.0, 5, 1)])
    r0, v0 = target(0.0, blocks)
    r1, v1 = target(5.0, blocks)
    assert abs(r0) < 1e-12 and abs(v0) < 1e-12 and abs(r1) < 1e-9 and abs(v1) < 1e-9
    t = np.arange(0, 5, 1e-3)
    r = target_series(blocks, t)
    assert np.max(np.abs(r)) == pytest.approx(0.02, rel=1e-4)
    # the rate is the derivative of the target
    slope = (target(2.3 + 1e-6, blocks)[0] - target(2.3 - 1e-6, blocks)[0]) / 2e-6
    assert target(2.3, blocks)[1] == pytest.approx(slope, rel=1e-5)


def test_offset_is_held_after_first_cycle():
    blocks = pack_profile([SineProfile(0.01, 1.0, 3, 0, offset_m=0.02)])
    assert target(0.0, blocks)[0] == 0.0
    assert target(2.0, blocks)[0] == pytest.approx(0.02, abs=1e-9)


def test_a_test_can_start_where_the_table_rests():
    """start_m: the target begins there and moves to the offset over the first cycle; start_m = offset_m runs
    about the table's present position from the first period, velocity continuous."""
    blocks = pack_profile([SineProfile(0.01, 1.0, 3, 1, offset_m=0.03, start_m=0.012)])
    assert target(0.0, blocks) == (pytest.approx(0.012), pytest.approx(0.0))
    assert target(2.0, blocks)[0] == pytest.approx(0.03, abs=1e-9)
    held = pack_profile([SineProfile(0.01, 1.0, 3, 1, offset_m=0.012, start_m=0.012)])
    t = np.arange(0, 3.0, 1e-3)
    r = target_series(held, t)
    assert r[0] == pytest.approx(0.012) and r[-1] == pytest.approx(0.012, abs=1e-6)
    np.testing.assert_allclose(r - 0.012, target_series(pack_profile([SineProfile(0.01, 1.0, 3, 1)]), t), atol=1e-15)
    scenario = Scenario.sine("IUT_a", 100.0, 0.01, 1.0, 3, offset_m=0.012)
    with pytest.raises(ProfileError, match="only the first block"):
        Scenario(scenario.isolator, scenario.supply_pa, [SineProfile(0.01, 1.0, 2, 1),
                                                         SineProfile(0.01, 1.0, 2, 1, start_m=0.01)]).validate()
    with pytest.raises(ProfileError, match="start_m = 0.12 m reaches 0.16 m"):
        Scenario(scenario.isolator, scenario.supply_pa, [SineProfile(0.04, 0.1, 2, 1, start_m=0.12)]).validate()


@pytest.mark.parametrize("kwargs, field", [
    (dict(amplitude_m=0.1, frequency_hz=1.0), "frequency_hz"),  # pump flow
    (dict(amplitude_m=0.12, frequency_hz=0.1, supply_bar=30), "amplitude_m"),  # force A_p P_s
    (dict(amplitude_m=0.02, frequency_hz=1.0, supply_bar=250), "supply_bar"),
    (dict(amplitude_m=0.02, frequency_hz=1.0, cycles=3, taper_cycles=2), "taper_cycles"),
])
def test_envelope_refuses_with_field_and_limit(kwargs, field):
    args = dict(isolator="IUT_a", supply_bar=100.0, cycles=4)
    args.update(kwargs)
    s = Scenario.sine(**args)
    with pytest.raises(ProfileError) as exc:
        s.validate()
    assert exc.value.field == field
    assert exc.value.limit
    assert field in str(exc.value)


def test_a_refusal_advises_only_what_fits_every_limit():
    """The advice at the end of a refusal is checked against every limit, not only the one that failed: the
    suggested frequency (or, when no frequency fits, the suggested amplitude) is accepted. 100 mm at 1 Hz on
    IUT_a at 100 bar broke the pump and was told 0.622 Hz, where the cylinder's force refuses it at any frequency."""
    import re

    from sim.isolator import PRESETS
    from sim.profiles import envelope_problem
    from sim.rig import DEFAULT_RIG

    iso = PRESETS["IUT_a"]
    advised = {"frequency": 0, "amplitude": 0}
    for a in (0.01, 0.03, 0.05, 0.08, 0.1, 0.14):
        for f in (0.2, 0.6, 1.0, 2.0, 5.0):
            block = SineProfile(a, f, 5, 1)
            problem = envelope_problem(block, DEFAULT_RIG, iso, 100e5)
            if problem is None:
                continue
            text = str(problem)
            m = re.search(r"frequency_hz must be <= ([\d.e+-]+) Hz", text)
            if m:
                advised["frequency"] += 1
                fitted = SineProfile(a, 0.999 * float(m.group(1)), 5, 1)
            else:
                m = re.search(r"no frequency fits amplitude_m = [\d.]+ m; at this frequency amplitude_m must be "
                              r"<= ([\d.e+-]+) m", text)
                assert m, text
                advised["amplitude"] += 1
                fitted = SineProfile(0.999 * float(m.group(1)), f, 5, 1)
            assert envelope_problem(fitted, DEFAULT_RIG, iso, 100e5) is None, (block, text)
    assert advised["frequency"] >= 3 and advised["amplitude"] >= 3, advised
    hundred = str(envelope_problem(SineProfile(0.1, 1.0, 5, 1), DEFAULT_RIG, iso, 100e5))
    assert "no frequency fits amplitude_m = 0.1 m" in hundred and "0.622" not in hundred, hundred


def test_chunks_equal_one_run_and_are_deterministic():
    s = Scenario.sine("IUT_b", 70.0, 0.03, 1.0, 3)
    whole = Simulation(s).run().samples
    sim = Simulation(s)
    parts = []
    while not sim.done:
        parts.append(sim.advance(333))
    np.testing.assert_array_equal(Samples.concatenate(parts).array, whole.array)
    assert len(whole) == 3000


def test_rows_written_into_a_given_buffer_equal_new_ones():
    s = Scenario.sine("IUT_a", 100.0, 0.02, 1.0, 2, controller="pid")
    fresh = Simulation(s).advance(1500)
    buffer = np.full((2000, len(SAMPLE_FIELDS)), -1.0)
    sim = Simulation(s)
    first = sim.advance(700, out=buffer)
    second = sim.advance(800, out=buffer[700:])
    assert len(first) == 700 and len(second) == 800 and np.shares_memory(second.array, buffer)
    np.testing.assert_array_equal(buffer[:1500], fresh.array)
    assert np.all(buffer[1500:] == -1.0)  # nothing written past the periods run
    assert len(sim.advance(10_000, out=buffer[1500:])) == 500 and sim.done  # the buffer bounds the periods run
    with pytest.raises(ValueError, match="C-contiguous"):
        Simulation(s).plant.run_closed(Simulation(s).loop, 10, out=buffer[:, :5])


def test_a_run_that_grows_longer_while_it_runs_keeps_every_row():
    """run() writes into one buffer of the planned length; a stop that lengthens the test (brake, return home,
    hold) grows it, and the rows equal a run advanced by hand."""
    s = Scenario.sine("IUT_a", 100.0, 0.02, 1.0, 6)
    sim = Simulation(s)

    def shutdown_late(_fraction):  # progress is called after the first chunk and then every 5000 periods
        if sim.period >= 5000:
            sim.loop.brake(home_m=0.0)

    grown = sim.run(chunk_periods=100, progress=shutdown_late).samples
    by_hand = Simulation(s)
    rows = [by_hand.advance(5100)]
    by_hand.loop.brake(home_m=0.0)
    rows.append(by_hand.advance(100_000))
    expected = Samples.concatenate(rows)
    assert len(grown) > 6000 and sim.done and by_hand.done
    np.testing.assert_array_equal(grown.array, expected.array)
    assert grown["target_m"][-1] == 0.0


def test_pid_closed_loop_tracks_the_target():
    s = Scenario.sine("IUT_a", 100.0, 0.02, 0.5, 4, controller="pid")
    res = Simulation(s).run()
    y, r = res.samples["displacement_m"], res.samples["target_m"]
    assert np.all(np.isfinite(res.samples.select(["displacement_m", "voltage_v"])))
    assert np.max(np.abs(y)) > 0.015  # it moved
    assert np.sqrt(np.mean((y - r) ** 2)) < 0.1 * 0.02
    assert np.all(np.isnan(res.samples["model_m"]))  # no reference model


def test_mrac_closed_loop_converges_to_reference_model():
    s = Scenario.sine("IUT_b", 70.0, 0.03, 1.0, 8, controller="mrac", taper_cycles=0)
    res = Simulation(s).run()
    cycles = res.summary()["cycles"]
    rms = [c["rms_y_minus_ym_m"] for c in cycles]
    assert all(np.isfinite(rms))
    assert rms[-1] < 0.6 * rms[1]  # adaptation reduces y - y_m cycle after cycle
    assert np.all(np.isfinite(res.samples.select(["model_m", "ar_hat"])))


def test_batch_matches_serial_runs():
    scenarios = [Scenario.sine(iso, bar, 0.02, 1.0, 2) for iso in ("IUT_a", "IUT_b") for bar in (70.0, 100.0)]
    batch = run_batch(scenarios, processes=2)
    for s, b in zip(scenarios, batch, strict=False):
        np.testing.assert_array_equal(Simulation(s).run().samples.array, b.samples.array)


def test_a_refusal_raised_in_a_batch_worker_reaches_the_caller_in_its_own_words():
    """A controller the rig cannot carry is refused when the run is built, in the worker: the pool used to
    report a worker "terminated abruptly" (a FieldError did not survive pickling)."""
    import pickle

    from sim.controllers.servo import LoopMarginError
    from sim.history import HistoryError

    too_stiff = {"kp_per_s": 500.0, "min_kp_share": 1.0}
    scenarios = [Scenario.sine("IUT_a", 100.0, 0.01, 1.0, 2, controller_options=too_stiff) for _ in range(2)]
    with pytest.raises(LoopMarginError) as refused:
        run_batch(scenarios, processes=2)
    assert refused.value.field == "controller_options.kp_per_s" and "gain margin" in str(refused.value)
    again = pickle.loads(pickle.dumps(HistoryError("line 3: not a number", path="a.csv", line=3, value="x")))
    assert (type(again), str(again), again.line, again.path, again.field, again.value) == (
        HistoryError, "line 3: not a number", 3, "a.csv", "history", "x")


def test_command_ramp_runs_open_loop_on_the_plant_and_leaves_the_controller_idle():
    from sim.plant import PLANT_SUBSTEPS
    from sim.rig import rk4_step, valve_command

    sim = Simulation(Scenario.sine("IUT_a", 100.0, 0.02, 1.0, 2, controller="pid"))
    while abs(sim.loop.last_command_v) < 0.5 and sim.period < 1500:  # a command worth ramping down
        sim.advance(10)
    u0 = sim.loop.last_command_v
    assert abs(u0) > 0.5
    controller_before = sim.loop.controller_state.copy()
    x = sim.plant.state.copy()
    sim.loop.begin_command_ramp(0.1)
    rows = sim.advance(5000)
    assert len(rows) == 100 and sim.done  # the ramp is the loop's end
    np.testing.assert_array_equal(sim.loop.controller_state, controller_before)  # not stepped
    expected = u0 * (1.0 - np.arange(1, 101) / 100)
    np.testing.assert_allclose(rows["voltage_v"], expected, rtol=0, atol=1e-15)
    assert rows["voltage_v"][-1] == 0.0
    assert np.all(np.isnan(rows["target_m"]))
    # the same plant stepped by hand with each command held
    for i in range(100):
        assert rows["displacement_m"][i] == x[0]
        for _ in range(PLANT_SUBSTEPS):
            rk4_step(x, valve_command(expected[i], sim.plant.params), sim.plant.params, 1e-3 / PLANT_SUBSTEPS)


def test_the_vertical_load_is_a_test_condition_and_sets_the_friction():
    from sim.isolator import PRESETS, Isolator
    from sim.rig import DEFAULT_RIG

    base = Scenario.sine("IUT_a", 100.0, 0.02, 1.0, 2)
    assert base.effective_vertical_load_n == DEFAULT_RIG.vertical_load_n == 1.25e5  # the paper's
    heavy = Scenario.sine("IUT_a", 100.0, 0.02, 1.0, 2, vertical_load_n=6e5)
    friction = heavy.plant_rig.friction_force_n
    assert friction - base.plant_rig.friction_force_n == pytest.approx(DEFAULT_RIG.friction_coefficient * 4.75e5)
    assert Simulation(heavy).plant.params[1] == friction  # P_FRICTION of the plant
    assert heavy.describe()["vertical_load_n"] == 6e5
    designed = Isolator(**{**PRESETS["IUT_b"].to_dict(), "design_vertical_load_n": 4e5})
    assert Scenario(designed, 70e5, base.profile).effective_vertical_load_n == 4e5  # the isolator's default
    assert Scenario(designed, 70e5, base.profile, vertical_load_n=0.0).effective_vertical_load_n == 0.0
    for bad in (-1.0, 9e5, float("nan")):
        with pytest.raises(ProfileError) as exc:
            Scenario.sine("IUT_a", 100.0, 0.02, 1.0, 2, vertical_load_n=bad).validate()
        assert exc.value.field == "vertical_load_n" and "850000" in exc.value.limit


PRESETS_KD_IUT_A = 1.25e6  # N/m, the paper's Table I


def test_the_envelope_counts_the_offset_and_the_friction_at_the_load():
    # the example (50 mm offset, 40 mm sine, 100 bar) on the rig of then; on today's larger A_p: 60 mm
    with pytest.raises(ProfileError, match="offset_m = 0.06 m") as exc:
        Scenario.sine("IUT_a", 100.0, 0.04, 0.1, 2, offset_m=0.06).validate()
    assert exc.value.field == "amplitude_m"
    Scenario.sine("IUT_a", 100.0, 0.04, 0.1, 2).validate()  # the same sine about zero fits
    # friction: a load the jack can give takes the margin away
    from sim.profiles import max_amplitude_m

    light, heavy = (Scenario.sine("IUT_a", 100.0, 0.02, 0.1, 2, vertical_load_n=n) for n in (0.0, 8.5e5))
    a_light = max_amplitude_m(0.1, light.plant_rig, light.isolator, 100e5)
    a_heavy = max_amplitude_m(0.1, heavy.plant_rig, heavy.isolator, 100e5)
    friction = heavy.plant_rig.friction_force_n - light.plant_rig.friction_force_n
    rig, w = light.plant_rig, 2 * np.pi * 0.1  # the force grows with a through k_d, sigma w and m w^2
    slope = PRESETS_KD_IUT_A + rig.viscous_n_s_per_m * w + rig.mass_kg * w * w
    assert a_light - a_heavy == pytest.approx(friction / slope, rel=1e-3)
    a = 0.5 * (a_light + a_heavy)
    Scenario.sine("IUT_a", 100.0, a, 0.1, 2, vertical_load_n=0.0).validate()
    with pytest.raises(ProfileError, match="vertical load of 850 kN"):
        Scenario.sine("IUT_a", 100.0, a, 0.1, 2, vertical_load_n=8.5e5).validate()
