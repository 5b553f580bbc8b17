"""A rig the controller cannot follow (sim.follow): the detector stops such a test, with the reason and the
advice to commission the rig, and never one whose table follows; every test gets a tracking verdict."""

import numpy as np
import pytest

from isorig.cli import main
from sim.engine import Scenario, Simulation
from sim.follow import FollowMonitor, reference_for, tracking_verdict
from sim.profiles import SineProfile
from sim.rig import DEFAULT_RIG
from sim.samples import Samples

SOFT = {"mass_kg": 3000.0, "bulk_modulus_pa": 4.5e8}  # a ~22 Hz oil column where the default rig has 55 Hz
#: a drawn rig (tests/test_commission.py's kind): soft column, slow valve, a wide dead zone, a late reading
HARD = {"mass_kg": 1686.0, "bulk_modulus_pa": 3.9e8, "valve_natural_frequency_rad_s": 2 * np.pi * 52.7,
        "dead_zone_v": 0.75, "position_latency_s": 1.83e-3}


def run(plant: dict, declared=DEFAULT_RIG, amplitude_m=0.02, frequency_hz=0.5, cycles=10, follow=True):
    s = Scenario.sine("IUT_a", 100.0, amplitude_m, frequency_hz, cycles, rig=declared, plant_changes=plant)
    return Simulation(s, validate=False).run(follow=follow)


def test_a_rig_softer_than_declared_is_stopped_with_the_advice_to_commission_it():
    result = run(SOFT)
    trip = result.trip
    assert trip is not None and trip.time_s <= 6.0  # the end of the second steady cycle at 0.5 Hz
    assert "does not follow its target" in trip.message and "isorig identify rig" in trip.message
    s = result.samples
    after = s["time_s"] > trip.time_s + 0.0105  # the detectors run every 10 periods
    assert np.all(s["voltage_v"][after] == 0.0)  # the valve closed at once: no ramp from an oscillating command
    assert len(s) * 1e-3 < trip.time_s + 0.2  # and the run ended there
    verdict = result.summary()["tracking_verdict"]
    assert verdict["verdict"] == "did_not_follow" and verdict["rms_share"] > 0.01


def test_an_oscillating_small_test_is_stopped_within_a_second():
    result = run(HARD, amplitude_m=0.002, frequency_hz=1.0)
    assert result.trip is not None and result.trip.values["kind"] == "oscillation" and result.trip.time_s < 1.0
    assert result.trip.values["frequency_hz"] > 10.0


@pytest.mark.parametrize("amplitude_m, frequency_hz", [(0.02, 0.5), (0.002, 1.0)])
def test_the_same_rigs_told_exactly_run_to_the_end(amplitude_m, frequency_hz):
    for plant in (SOFT, HARD):
        result = run(plant, DEFAULT_RIG.with_changes(**plant), amplitude_m, frequency_hz)
        assert result.trip is None, result.trip.message
        assert result.summary()["tracking_verdict"]["verdict"] in ("followed", "outside_target")


def test_a_late_reading_is_judged_against_the_target_it_shows():
    """2 ms late at 1.5 Hz is 1.9 % of the amplitude between the reading and the target of now: the monitor
    compares the reading with the target of 2 ms ago, as the servo aims (docs/controller.md)."""
    late = DEFAULT_RIG.with_changes(position_latency_s=0.002)
    s = Scenario.sine("IUT_a", 100.0, 0.02, 1.5, 12, rig=late)
    result = Simulation(s).run(follow=True)
    assert result.trip is None
    monitor = FollowMonitor(reference_for(s.profile), latency_s=0.0)  # told nothing of the latency
    assert monitor.feed(result.samples) is not None


def test_verdicts():
    good = run({}, follow=False)
    v = good.summary()["tracking_verdict"]
    assert v["verdict"] == "followed" and v["rms_share"] < 0.001 and "within the 0.1 % target" in v["words"]
    assert v["rms_share"] == pytest.approx(good.summary()["last_two_cycles"]["rms_y_minus_r_over_amplitude"])
    bad = run(SOFT, follow=False)
    assert bad.summary()["tracking_verdict"]["verdict"] == "did_not_follow"
    assert tracking_verdict(good.samples[:1000], good.scenario.profile)["verdict"] == "not_judged"
    j = tracking_verdict(None, [], {"j2_rms_percent": 0.4})
    assert j["verdict"] == "followed" and "J2" in j["words"]
    assert tracking_verdict(None, [], {"j2_rms_percent": 3.0})["verdict"] == "did_not_follow"


def test_a_ramp_out_is_not_judged_as_a_steady_cycle():
    s = Scenario.sine("IUT_a", 100.0, 0.02, 1.0, 10)
    sim = Simulation(s)
    first = sim.advance(4500)
    sim.loop.ramp_out()
    samples = Samples.concatenate([first, sim.run().samples])
    assert len(samples) == 6000  # the stop tapered cycle 6 out
    v = tracking_verdict(samples, s.profile)
    assert v["verdict"] == "followed"
    full = tracking_verdict(Simulation(s).run().samples, s.profile)
    assert v["rms_share"] != full["rms_share"]  # judged on cycles 4 and 5, not on the ramp-out


def test_a_protocol_judges_each_level_against_its_own_amplitude():
    blocks = [SineProfile(0.002, 1.0, 5, 1), SineProfile(0.02, 1.0, 5, 1)]
    ref = reference_for(blocks)
    k = np.array([0, 4999, 5000, 9999])
    assert list(ref.amplitudes[ref.span(k)]) == [0.002, 0.002, 0.02, 0.02]
    _b, cycle, steady = ref.cycle(k)
    assert list(cycle) == [0, 4, 0, 4] and list(steady) == [False, False, False, False]


def test_simulate_says_the_table_did_not_follow_and_exits_1(tmp_path, capsys):
    code = main(["simulate", "--cycles", "10", "--frequency-hz", "0.5", "--plant-set", "mass_kg=3000",
                 "--plant-set", "bulk_modulus_pa=4.5e8", "--out", str(tmp_path)])
    out = capsys.readouterr().out
    assert code == 1 and "test aborted: the table does not follow" in out and "tracking error: did not follow" in out
    assert main(["simulate", "--cycles", "4", "--out", str(tmp_path / "ok")]) == 0
    assert "tracking error: followed" in capsys.readouterr().out


def test_a_hosts_lost_periods_are_not_taken_for_a_rig_that_does_not_follow():
    """Issue 21: a loaded host lost 15 % of its periods (each holds an older reading) and the monitor stopped
    a test whose table followed, as an oscillation. Lost periods are bridged for the oscillation detector and
    skipped by the tracking figures; the same held readings not flagged lost still trip."""
    from sim.measurement import FLAG_LOST

    s = Scenario.sine("IUT_a", 100.0, 0.01, 2.0, 8, rig=DEFAULT_RIG)
    samples = Simulation(s).run().samples
    y = samples["measured_displacement_m"].copy()
    flags = np.zeros(len(y))
    rng = np.random.default_rng(3)
    k = 1
    while k < len(y):
        if rng.random() < 0.06:  # a stall of 1-5 periods
            n = int(rng.integers(1, 6))
            y[k:k + n] = y[k - 1]
            flags[k:k + n] = FLAG_LOST
            k += n
        k += 1
    assert 0.1 < np.mean(flags != 0) < 0.3
    held = Samples(samples.array.copy())
    held["measured_displacement_m"][:] = y
    held["flags"][:] = flags
    assert FollowMonitor(reference_for(s.profile)).feed(held) is None
    held["flags"][:] = 0.0  # the same readings, not flagged lost
    assert FollowMonitor(reference_for(s.profile)).feed(held) is not None


def test_a_trip_among_many_lost_periods_blames_the_link_not_the_rig():
    from sim.measurement import FLAG_LOST

    result = run(SOFT, follow=False)  # a rig that does not follow, recorded whole
    samples = Samples(result.samples.array.copy())
    monitor = FollowMonitor(reference_for(Scenario.sine("IUT_a", 100.0, 0.02, 0.5, 10).profile))
    trip = monitor.feed(samples)
    assert trip is not None and "commission it" in trip.message and trip.values["lost_periods_last_s"] == 0
    samples["flags"][::20] = FLAG_LOST  # 5 % of the periods lost on the link
    trip = FollowMonitor(reference_for(Scenario.sine("IUT_a", 100.0, 0.02, 0.5, 10).profile)).feed(samples)
    assert trip is not None and "lost on the link" in trip.message and "commission it" not in trip.message
    assert trip.values["lost_periods_last_s"] >= 40


# ---- the compiled judge against the per-block numpy path -----------------------------------------------------
def _state(monitor):
    """All a monitor carries from one block to the next, as bytes and numbers (NaN compared bit for bit)."""
    return (np.array(monitor.z).tobytes(), monitor.r_hist.tobytes(), monitor.e_hf.tobytes(),
            monitor.e_comb.tobytes(), monitor.hf_ring.tobytes(),
            monitor.lost_recent.tobytes(), monitor.last_fresh, monitor.cycle_key, monitor.cycle_sum, monitor.cycle_n,
            monitor.cycle_steady, monitor.previous_share, monitor.best_shares, monitor.steady_judged)


def _trip(trip):
    return None if trip is None else (trip.index, trip.time_s, trip.kind, trip.message, repr(trip.values))


def _records():
    """(name, reference, latency_s, samples): records that trip on an oscillation and on tracking, that follow,
    with lost periods (bridged, at block ends too), non-finite readings, a late reading and a time history."""
    from sim.measurement import FLAG_LOST

    out = []
    for name, plant, amplitude_m, frequency_hz, controller in [
            ("soft servo", SOFT, 0.02, 0.5, "servo"), ("soft pid", SOFT, 0.02, 0.5, "pid"),
            ("soft mrac", SOFT, 0.02, 0.5, "mrac"), ("hard 2 mm", HARD, 0.002, 1.0, "servo"),
            ("told exactly", {}, 0.01, 2.0, "servo")]:
        s = Scenario.sine("IUT_a", 100.0, amplitude_m, frequency_hz, 10, controller=controller,
                          plant_changes=plant)
        samples = Simulation(s, validate=False).run().samples
        out.append((name, reference_for(s.profile), 0.0, samples))
    samples = Samples(out[-1][3].array.copy())
    rng = np.random.default_rng(5)
    y = samples["measured_displacement_m"]
    for k in rng.choice(np.arange(1, len(samples) - 6), 400, replace=False):  # stalls of 1-5 periods
        n = int(rng.integers(1, 6))
        y[k:k + n] = y[k - 1]
        samples["flags"][k:k + n] = FLAG_LOST
    samples["flags"][9::500] = FLAG_LOST  # the last period of a block
    y[3000:3003] = np.nan  # a reading that is not a number: not judged, and the window waits
    profile = Scenario.sine("IUT_a", 100.0, 0.01, 2.0, 10).profile
    out.append(("lost periods", reference_for(profile), 0.0, samples))
    late_rig = DEFAULT_RIG.with_changes(position_latency_s=0.00183)
    s = Scenario.sine("IUT_a", 100.0, 0.02, 1.5, 8, rig=late_rig, plant_changes=HARD)
    out.append(("late reading", reference_for(s.profile), 0.00183, Simulation(s, validate=False).run().samples))
    soft = out[0][3]
    out.append(("time history", reference_for([], soft["target_m"]), 0.0, soft))
    samples, profile = _synthetic(harmonic_share=0.0, tone_hz=26.3, tone_share=0.0015)  # a tone (the tone rule)
    out.append(("tone", reference_for(profile), 0.0, samples))
    samples, profile = _cycle_errors([0.2, 0.095, 0.027, 0.077, 0.03, 0.028, 0.027])  # stops gaining: tracking
    out.append(("learning stuck", reference_for(profile), 0.0, samples))
    return out


def test_the_compiled_judge_is_the_numpy_path_bit_for_bit():
    """FollowMonitor.check / feed run compiled (sim.follow._judge_blocks); the per-block numpy path they replace
    stays as the reference: the same trips (row, time, kind, message, values) and the same state after every
    block, for the worker's blocks of ten and other sizes, and feed_to_trip stops where the reference is before
    the block that trips."""
    from sim.follow import fast_path

    assert fast_path(10), "the compiled judge is not used on this machine: nothing to compare"
    kinds, tones = set(), 0
    for name, reference, latency_s, samples in _records():
        for block in (10, 7, 15):
            fast = FollowMonitor(reference, latency_s)
            slow = FollowMonitor(reference, latency_s)
            trip = fast.feed(samples, block)
            assert _trip(trip) == _trip(slow.feed(samples, block, reference=True)), (name, block)
            assert _state(fast) == _state(slow), (name, block)
            if block == 10:
                kinds.add(trip.kind if trip is not None else None)
                tones += trip is not None and trip.values.get("tone_correlation") is not None
        worker, slow = FollowMonitor(reference, latency_s), FollowMonitor(reference, latency_s)
        for i in range(0, len(samples), 10):  # the worker's checks, one block at a time
            a, b = worker.check(samples[i:i + 10]), slow.check(samples[i:i + 10], reference=True)
            assert _trip(a) == _trip(b) and _state(worker) == _state(slow), (name, i)
            if a is not None:
                break
        primed, slow = FollowMonitor(reference, latency_s), FollowMonitor(reference, latency_s)
        at = primed.feed_to_trip(samples)
        whole = FollowMonitor(reference, latency_s).feed(samples, reference=True)
        assert at == (None if whole is None else whole.index), name
        slow.feed(samples if at is None else samples[:at // 10 * 10], reference=True)
        assert _state(primed) == _state(slow), name
        if at is not None:
            block = samples[at // 10 * 10: at // 10 * 10 + 10]
            assert _trip(primed.check(block)) == _trip(slow.check(block, reference=True)), name
    assert kinds == {"oscillation", "tracking", None} and tones >= 1


def test_the_compiled_sums_are_numpys():
    """The pieces the judge needs bit for bit: numpy's pairwise mean, numpy.interp, numpy.dot of a block."""
    from sim.follow import FAST_BLOCK_MAX, _interp, _pairwise_sum, _sum_of_squares, dot_is_fused

    rng = np.random.default_rng(11)
    for n in (1, 7, 8, 9, 127, 128, 129, 500, 1001):
        x = rng.normal(size=n) ** 2 * 10.0 ** rng.uniform(-12, 0, size=n)
        assert _pairwise_sum(np.concatenate([x, x]), 3 % n, n) / n == np.mean(np.roll(x, -(3 % n)))
    xp = np.cumsum(rng.integers(1, 4, size=12)).astype(float)
    fp = rng.normal(size=12)
    for x in np.linspace(xp[0] - 2, xp[-1] + 2, 97):
        assert _interp(x, xp, fp, xp.size) == np.interp(x, xp, fp)
    for n in range(1, FAST_BLOCK_MAX + 1):
        x = rng.normal(size=n) * 1e-4
        assert _sum_of_squares(x, n, dot_is_fused()) == float(np.dot(x, x))


# ---- issue 32 item 5: the right cause on a commissioned rig, and an oscillation stopped within 2 s -----------
#: a heavy table on a soft column (about 13 Hz: issue 32's rig 2 met a 13 Hz oscillation at 2 mm)
HEAVY = {"mass_kg": 5000.0, "bulk_modulus_pa": 3.0e8}
COMMISSIONED = {"date": "2026-11-27T10:00:00", "trusted": True, "max_velocity_m_per_s": 0.02,
                "estimates": {"position_latency_s": {"value": 0.0, "std": 5e-5, "unit": "s", "meaning": "L"}}}


def _onset_s(samples, scenario) -> float:
    """When the oscillation starts, from a record the monitor did not stop: the first time the 0.1 s RMS of the
    error above the monitor's corner (a fourth-order high-pass) reaches half the monitor's bound."""
    from scipy import signal

    from sim.follow import FollowLimits, late

    block = scenario.profile[0]
    lim = FollowLimits()
    e = samples["measured_displacement_m"] - late(samples["target_m"], scenario.rig.position_latency_s / 1e-3)
    corner = min(max(lim.corner_hz, lim.corner_harmonic * block.frequency_hz), 200.0)
    hp = signal.sosfilt(signal.butter(4, corner, btype="highpass", fs=1000.0, output="sos"), np.nan_to_num(e))
    c = np.concatenate([[0.0], np.cumsum(hp * hp)])
    rms = np.sqrt((c[100:] - c[:-100]) / 100)
    bound = max(lim.oscillation_share * block.amplitude_m, lim.floor_m)
    return float(samples["time_s"][99 + np.flatnonzero(rms > 0.5 * bound)[0]])


@pytest.mark.parametrize("plant, amplitude_m, frequency_hz", [(HEAVY, 0.002, 1.0), (HEAVY, 0.02, 0.5),
                                                              (SOFT, 0.002, 1.0), (HARD, 0.002, 1.0)])
def test_an_oscillation_is_stopped_within_2_s_of_its_start(plant, amplitude_m, frequency_hz):
    """Rigs the controller is not told of oscillate at 13-27 Hz; each is stopped as an oscillation, within 2 s of
    the oscillation's start (not by the tracking rule, 4-10 s in). Measured: 13 Hz 2 mm 0.37 s, 13 Hz 20 mm 0.22 s,
    20 Hz 2 mm 0.54 s, 19 Hz 0.40 s after the start."""
    free = run(plant, amplitude_m=amplitude_m, frequency_hz=frequency_hz, follow=False)
    onset = _onset_s(free.samples, free.scenario)
    trip = run(plant, amplitude_m=amplitude_m, frequency_hz=frequency_hz).trip
    assert trip is not None and trip.values["kind"] == "oscillation", trip and trip.message
    assert trip.time_s - onset <= 2.0, (onset, trip.time_s)


def test_an_oscillation_on_a_commissioned_rig_is_the_controllers():
    """Issue 32 item 5: a rig file written by isorig identify rig is what the controller was told; an oscillation
    there is the loop's own, named with its frequency and what a lab can change, never 'commission it'. The same
    rig without a commissioning keeps the advice to commission it."""
    s = Scenario.sine("IUT_a", 100.0, 0.002, 1.0, 10, plant_changes=HEAVY, rig_commissioning=COMMISSIONED)
    trip = Simulation(s, validate=False).run(follow=True).trip
    assert trip is not None and trip.values["kind"] == "oscillation" and trip.values["commissioned"] is True
    f = trip.values["frequency_hz"]
    assert 10.0 < f < 20.0 and f"at {f:.0f} Hz" in trip.message
    assert "commissioned on 2026-11-27" in trip.message and "controller's loop oscillating" in trip.message
    assert "--controller-option kp_per_s=15, half the 30 it ran with" in trip.message  # the loop gain, named
    assert "learning_gain=0.4" in trip.message
    assert "--max-velocity-m-per-s 0.04" in trip.message  # twice the bound it was commissioned at
    assert "commission it" not in trip.message and "not what the controller was told" not in trip.message
    plain = run(HEAVY, amplitude_m=0.002, frequency_hz=1.0).trip
    assert "commission it" in plain.message and plain.values["commissioned"] is False


def test_simulate_with_a_commissioned_rig_file_names_the_controller(tmp_path, capsys):
    """isorig simulate --rig-file passes the file's commissioning section to the monitor."""
    import json

    rig_file = tmp_path / "rig.json"
    rig_file.write_text(json.dumps({"name": "commissioned", "commissioning": COMMISSIONED}))
    code = main(["simulate", "--cycles", "10", "--frequency-hz", "1", "--amplitude-m", "0.002", "--rig-file",
                 str(rig_file), "--plant-set", "mass_kg=5000", "--plant-set", "bulk_modulus_pa=3e8",
                 "--out", str(tmp_path / "run")])
    out = capsys.readouterr().out
    assert code == 1 and "sustained oscillation" in out and "controller's loop oscillating" in out
    assert "commission it" not in out


# ---- issue 34 item 1: a component at a whole multiple of the test frequency is tracking error -----------------
@pytest.mark.parametrize("frequency_hz, taper_cycles", [(0.5, 0), (1.0, 1)])
def test_the_papers_mrac_is_not_stopped_as_an_oscillation(frequency_hz, taper_cycles):
    """The paper's MRAC on IUT_a (20 mm) is 100 % of the amplitude off in its first cycles; a second-order
    high-pass let that slow error's harmonics through and the test was stopped as 'a sustained oscillation near
    1 Hz' (0.5 Hz, 0.665 s) or 'near 4 Hz' (1 Hz, 1.41 s). It is tracking error: the tracking rule may stop it."""
    s = Scenario.sine("IUT_a", 100.0, 0.02, frequency_hz, 15, controller="mrac", taper_cycles=taper_cycles)
    trip = Simulation(s).run(follow=True).trip
    assert trip is None or trip.values["kind"] == "tracking", trip.message


def _synthetic(frequency_hz=0.5, cycles=10, harmonic_share=0.018, harmonic=25, tone_hz=13.3, tone_share=0.0,
               tone_from_s=5.0):
    """A 20 mm sine the table follows, with a steady error at a whole multiple of the test frequency (above the
    monitor's corner) and a tone of its own from ``tone_from_s``."""
    from sim.samples import N_FIELDS

    a = 0.02
    n = int(round(cycles / frequency_hz / 1e-3))
    t = np.arange(n) * 1e-3
    rows = np.zeros((n, N_FIELDS))
    s = Samples(rows)
    r = a * np.sin(2 * np.pi * frequency_hz * t)
    e = harmonic_share * a * np.sqrt(2) * np.sin(2 * np.pi * harmonic * frequency_hz * t + 0.3)
    e += np.where(t >= tone_from_s, tone_share * a * np.sqrt(2) * np.sin(2 * np.pi * tone_hz * (t - tone_from_s)), 0)
    s["time_s"][:] = t
    s["target_m"][:] = r
    s["measured_displacement_m"][:] = r + e
    return s, [SineProfile(a, frequency_hz, cycles, 0)]


def _cycle_errors(shares, frequency_hz=0.5):
    """A 20 mm sine whose error in cycle c is a sine at the test frequency of RMS ``shares[c]`` of the amplitude (in
    phase with the target, so it is 0 at every cycle's start: no step for the oscillation rules to see)."""
    from sim.samples import N_FIELDS

    a = 0.02
    per = int(round(1.0 / frequency_hz / 1e-3))
    n = per * len(shares)
    t = np.arange(n) * 1e-3
    s = Samples(np.zeros((n, N_FIELDS)))
    r = a * np.sin(2 * np.pi * frequency_hz * t)
    e = np.repeat(np.asarray(shares, dtype=float), per) * a * np.sqrt(2) * np.sin(2 * np.pi * frequency_hz * t)
    s["time_s"][:] = t
    s["target_m"][:] = r
    s["measured_displacement_m"][:] = r + e
    return s, [SineProfile(a, frequency_hz, len(shares), 0)]


def test_the_tracking_rule_lets_a_learning_that_gains_in_steps_go_on():
    """After the learning's two cycles, a cycle above 1 % is let go while it is 20 % below the cycle before or the
    smallest error so far is 36 % below the smallest of two cycles earlier (a learning that overshoots gains in
    steps: 9.5, 2.7, 7.7, 2.0 % on a foreign rig at 0.5 mm, which one cycle's comparison stopped at its third), for
    at most 8 more cycles; it is stopped when it no longer gains, or gains too slowly, or for too long. Compiled
    and numpy paths alike."""
    def first_trip(shares):
        samples, profile = _cycle_errors(shares)
        trips = [FollowMonitor(reference_for(profile)).feed(samples, 10, reference=reference)
                 for reference in (False, True)]
        assert _trip(trips[0]) == _trip(trips[1])
        return trips[0]

    steps = [0.2, 0.095, 0.027, 0.077, 0.015, 0.008, 0.006, 0.005, 0.005, 0.005]
    assert first_trip(steps) is None  # cycle 4 (7.7 %) grew, but the best (2.7 %) is far below 9.5 % two before
    stuck = first_trip([0.2, 0.095, 0.05, 0.045, 0.043, 0.042, 0.04, 0.04])  # 4.3 % is not 36 % below 5 %
    assert stuck is not None and stuck.kind == "tracking" and stuck.time_s == pytest.approx(10.0, abs=0.01)
    slow = first_trip([0.2, 0.1] + [0.1 * 0.92 ** k for k in range(1, 9)])  # 8 % a cycle: 15 % over two
    assert slow is not None and slow.kind == "tracking" and slow.time_s == pytest.approx(8.0, abs=0.01)
    long = [0.2, 0.1] + [0.1 * 0.78 ** k for k in range(1, 13)]  # 22 % a cycle: still 1.07 % at its 11th cycle
    trip = first_trip(long)
    assert trip is not None and trip.kind == "tracking" and trip.time_s == pytest.approx(22.0, abs=0.01)
    # the same steps with 2 cycles' patience (as before) are stopped at their fifth cycle, at 1.5 %
    import dataclasses

    from sim.follow import FollowLimits

    samples, profile = _cycle_errors(steps)
    impatient = dataclasses.replace(FollowLimits(), improving_cycles=2)
    trip = FollowMonitor(reference_for(profile), limits=impatient).feed(samples, 10)
    assert trip is not None and trip.kind == "tracking" and trip.time_s == pytest.approx(10.0, abs=0.01)


def test_a_harmonic_of_the_test_is_not_counted_as_an_oscillation():
    """A steady error at the 25th harmonic of a 0.5 Hz test (12.5 Hz, 1.8 % of the amplitude) and a tone of 13.3 Hz
    at 0.05 % from 5 s: together 1.8 % above the corner, but only the tone is an oscillation, and it is within the
    0.5 % bound of the steady cycles and below the tone rule's 0.1 % (it stays below after one test period too,
    where the tone less its value a period earlier is up to twice the tone). The same tone at 0.25 % is stopped
    by the tone rule and at 2.5 % by its size, named near 13 Hz. Tracking is not judged here."""
    from sim.follow import FollowLimits

    limits = FollowLimits(rms_share=1.0)
    samples, profile = _synthetic(tone_share=0.0005)
    assert FollowMonitor(reference_for(profile), limits=limits).feed(samples) is None
    for share, rule in [(0.0025, "tone"), (0.025, "size")]:
        samples, profile = _synthetic(tone_share=share)
        trip = FollowMonitor(reference_for(profile), limits=limits).feed(samples)
        assert trip is not None and trip.kind == "oscillation" and 5.0 < trip.time_s < 5.6, share
        assert 12.0 < trip.values["frequency_hz"] < 15.0
        assert (trip.values["tone_correlation"] is not None) == (rule == "tone"), share


# ---- issue 32 item 5: an oscillation that starts in the middle of a test --------------------------------------
#: the oil column loses its stiffness at 4.3 s (air in the oil, a hose that gives): the servo, told 1e9 Pa, then
#: oscillates at 21-25 Hz at 0.5-1.6 % of the amplitude, which the tracking rule stopped 3.7 s (20 mm, 0.5 Hz) and
#: 2.7 s (30 mm, 1 Hz) later
AIR_AT_S = 4.3


@pytest.mark.parametrize("amplitude_m, frequency_hz, bulk_modulus_pa", [(0.02, 0.5, 2.0e8), (0.03, 1.0, 2.5e8)])
def test_an_oscillation_that_starts_mid_test_is_stopped_within_2_s(amplitude_m, frequency_hz, bulk_modulus_pa):
    def scenario(timed):
        return Scenario.sine("IUT_a", 100.0, amplitude_m, frequency_hz, int(8 * max(1.0, frequency_hz)),
                             timed_changes=timed)

    trip = Simulation(scenario([(AIR_AT_S, "bulk_modulus_pa", bulk_modulus_pa)]), validate=False).run(follow=True).trip
    assert trip is not None and trip.values["kind"] == "oscillation", trip and trip.message
    assert AIR_AT_S < trip.time_s <= AIR_AT_S + 2.0
    assert trip.values["frequency_hz"] > 15.0 and "in the steady cycles" in trip.message
    assert Simulation(scenario([]), validate=False).run(follow=True).trip is None  # the same test, the rig unchanged
