"""Issue 32 item 5: a sustained oscillation is stopped within 2 s, told by its signature (sim.follow, the tone rule:
what does not repeat with the test repeats every period of its own, sustained over the window), not by its size
alone: one that hovers about the 40 um floor is stopped as quickly as a large one, and a good run is not."""

import numpy as np
import pytest

from sim.engine import Scenario, Simulation
from sim.follow import FollowLimits, FollowMonitor, is_tone, reference_for, tone_correlation
from sim.profiles import SineProfile
from sim.samples import N_FIELDS, Samples

AMPLITUDE_M, FREQUENCY_HZ, CYCLES = 0.005, 0.5, 8
FROM_S = 5.0  # in the steady cycles (the first cycle is the learning's, the second the first compared)


def _record(added_m, from_s=FROM_S):
    """A 5 mm 0.5 Hz sine the table follows exactly, plus ``added_m`` (a function of the time since ``from_s``) in
    the reading from ``from_s``."""
    n = int(round(CYCLES / FREQUENCY_HZ / 1e-3))
    t = np.arange(n) * 1e-3
    s = Samples(np.zeros((n, N_FIELDS)))
    r = AMPLITUDE_M * np.sin(2 * np.pi * FREQUENCY_HZ * t)
    s["time_s"][:] = t
    s["target_m"][:] = r
    s["measured_displacement_m"][:] = r + np.where(t >= from_s, added_m(t - from_s), 0.0)
    return s, [SineProfile(AMPLITUDE_M, FREQUENCY_HZ, CYCLES, 0)]


def _tone(rms_m, frequency_hz=26.3):
    return lambda t: rms_m * np.sqrt(2) * np.sin(2 * np.pi * frequency_hz * t)


def _judged(samples, profile, reference=False):
    limits = FollowLimits(rms_share=1.0)  # tracking not judged here: the oscillation rules alone
    return FollowMonitor(reference_for(profile), limits=limits).feed(samples, reference=reference)


def test_a_tone_below_the_size_floor_is_stopped_within_2_s():
    """A 26 Hz tone of 25 um RMS from 5 s (0.5 % of 5 mm, below the 40 um floor the size rule keeps) went on to
    the end of the test; as a tone (above 10 um, the labs' 0.1 % of the amplitude at least 10 um) it is stopped
    within a second, named near 26 Hz, on the compiled judge and the numpy path alike."""
    samples, profile = _record(_tone(25e-6))
    trip = _judged(samples, profile)
    assert trip is not None and trip.kind == "oscillation", trip
    assert FROM_S < trip.time_s <= FROM_S + 2.0
    assert 24.0 < trip.values["frequency_hz"] < 29.0 and trip.values["tone_correlation"] >= 0.9
    assert trip.values["value_m"] < FollowLimits().floor_m and "a tone of its own" in trip.message
    slow = _judged(samples, profile, reference=True)
    assert (slow.index, slow.time_s, slow.message, repr(slow.values)) == (
        trip.index, trip.time_s, trip.message, repr(trip.values))


def test_what_has_no_tones_signature_is_not_stopped():
    """The same 25 um RMS as noise (no period of its own), a tone below the tone's 10 um bound, and a harmonic of
    the test all along (the 25th, 12.5 Hz, at 25 um: it repeats every cycle, tracking error): none is stopped."""
    rng = np.random.default_rng(7)
    noise = rng.normal(size=20000) * 25e-6
    harmonic = _tone(25e-6, 25 * FREQUENCY_HZ)
    for name, added, from_s in [("noise", lambda t: noise[:t.size], FROM_S), ("small tone", _tone(6e-6), FROM_S),
                                ("harmonic", harmonic, 0.0)]:
        samples, profile = _record(added, from_s)
        assert _judged(samples, profile) is None, name


def test_a_ring_that_dies_is_not_a_sustained_tone():
    """A 60 Hz ring that dies in 0.25 s (25 um RMS over its first 0.5 s) repeats every period of it, but its window's
    halves differ by more than tone_sustain: not stopped; judged without that condition it would be."""
    def ring(t):
        return 71e-6 * np.sin(2 * np.pi * 60.3 * t) * np.exp(-t / 0.25)

    window = ring(np.arange(500) * 1e-3)
    assert 20e-6 < np.sqrt(np.mean(window ** 2)) < 30e-6 and tone_correlation(window) > 0.9
    samples, profile = _record(ring)
    assert _judged(samples, profile) is None
    unsustained = FollowLimits(rms_share=1.0, tone_sustain=0.0)
    assert FollowMonitor(reference_for(profile), limits=unsustained).feed(samples) is not None


def test_tone_correlation():
    t = np.arange(500) * 1e-3
    assert tone_correlation(np.sin(2 * np.pi * 26.3 * t)) > 0.99
    assert abs(tone_correlation(np.random.default_rng(3).normal(size=500))) < 0.2
    assert tone_correlation(np.zeros(500)) == 0.0 and tone_correlation(np.ones(500)) == 0.0
    assert is_tone(np.sin(2 * np.pi * 26.3 * t), 0.9, 0.25)


def test_the_oscillation_that_hovered_at_the_floor_is_stopped_within_2_s():
    """scripts/bench_detectors.py --oscillations' slow case: our rig's oil column at 2.5e8 Pa from 4.3 s of a
    5 mm 0.5 Hz test; the servo then oscillates near 26 Hz at 20-45 um RMS, about the 40 um floor, and was stopped
    5.7 s after the change. As a tone it is stopped within 2 s; the same test unchanged runs to the end."""
    def scenario(timed):
        return Scenario.sine("IUT_a", 100.0, AMPLITUDE_M, FREQUENCY_HZ, CYCLES, timed_changes=timed)

    changed_at_s = 4.3
    trip = Simulation(scenario([(changed_at_s, "bulk_modulus_pa", 2.5e8)]), validate=False).run(follow=True).trip
    assert trip is not None and trip.values["kind"] == "oscillation", trip and trip.message
    assert changed_at_s < trip.time_s <= changed_at_s + 2.0
    assert trip.values["frequency_hz"] > 15.0
    assert Simulation(scenario([]), validate=False).run(follow=True).trip is None


def test_an_indicated_tone_is_not_indicated_again():
    """After a trip the operator set to indicate, the monitor judges tracking only (FollowMonitor.resume)."""
    samples, profile = _record(_tone(25e-6))
    monitor = FollowMonitor(reference_for(profile), limits=FollowLimits(rms_share=1.0))
    trip = monitor.feed(samples)
    assert trip is not None
    monitor.resume()
    assert monitor.feed(samples[trip.index // 10 * 10 + 10:]) is None


@pytest.mark.parametrize("limit", ["tone_share", "tone_floor_m"])
def test_the_tone_rule_is_one_of_the_shown_thresholds(limit):
    assert limit in FollowLimits().to_dict()
