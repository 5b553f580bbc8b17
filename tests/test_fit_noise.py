"""The flow balance under the noise of real pressure transducers (issue 32 item 3), on foreign rigs (written from
the physics, not isorig's model).

The P_L' column carries the transducers' noise. Least squares over the non-linear parameters minimised a cost
that holds the noise's share C^2 N sigma^2, which falls with C: it moved the latency and the valve's lag towards
whatever shrank C. On overlapped rigs 84, 147, 204, 230 the latency came 0.3-0.5 ms late with the noise and
right without it (the latency then refused 141 of rigs 0-299). The fit now minimises the bias-compensated cost
(sim.commission.flow._projected_residual) at a 35 Hz low-pass, and states how far each value moves with the
noise doubled (sim.commission.fit.noise_shifts), which the jackknife cannot see.
"""

import numpy as np
import pytest

from foreign_rigs import draw_rig
from foreign_rigs import physics as ph
from sim.commission import foreign_campaign as fc
from sim.commission import identify as identify_module
from sim.commission.flow import fit_flow
from sim.commission.force import latency_from_force
from sim.commission.identify import START_SHIFT_SHARE
from sim.commission.signals import Signals

OVERLAPPED_NOISY = 204  # overlapped valve, 0.087 bar per transducer, latency 1.69 ms
NOISE_MOVES_THE_VALVE = 321  # its valve's frequency (truth 316 rad/s) moves about 700 rad/s with the noise doubled
NOISE_MOVED_THE_VALVE = 237  # before the flow fit settled (sim.commission.flow.fit_flow), the noise moved it 403 rad/s


def _clean_record(seed, monkeypatch):
    """Rig ``seed`` commissioned with its pressure transducers' noise off: (spec, declared, the fit's Signals,
    the transducers' drawn noise per reading, Pa)."""
    spec = draw_rig(seed)
    noise_pa = float(spec.params[ph.P_PRESSURE_NOISE])
    spec.params[[ph.P_PRESSURE_NOISE, ph.P_SUPPLY_NOISE]] = 0.0
    captured = {}
    fit_rig = identify_module.fit_rig

    def capturing(sig, declared, **kwargs):
        captured["sig"] = sig
        return fit_rig(sig, declared, **kwargs)

    monkeypatch.setattr(identify_module, "fit_rig", capturing)
    declared = fc.declared_rig(spec.lab_knows())
    fc.commission(spec, declared, fc.DEFAULT_MAX_STROKE_M, fc.DEFAULT_MAX_VELOCITY_M_PER_S)
    return spec, declared, captured["sig"], noise_pa


@pytest.mark.slow  # a whole commissioning: scripts/test.sh --quick leaves it out
def test_pressure_noise_does_not_pull_the_flow_balance_latency_late(monkeypatch):
    spec, declared, sig, noise_pa = _clean_record(OVERLAPPED_NOISY, monkeypatch)
    area, dp_reg, ratio = declared.piston_area_m2, declared.orifice_regularisation_pa, declared.area_ratio_b
    truth_s = spec.equivalents(fc.SUPPLY_PA)["position_latency_s"]
    # P_L of two transducers, each with the rig's own noise
    p_noise = np.random.default_rng(1).normal(0.0, noise_pa * np.sqrt(2.0), len(sig))
    noisy = Signals(sig.dt_s, sig.u, sig.y, sig.p_load + p_noise, sig.force, sig.p_supply, sig.valid)
    latencies = {}
    for name, s in (("clean", sig), ("noisy", noisy)):
        fit = fit_flow(s, area, dp_reg, latency_guess_s=latency_from_force(s, area), area_ratio_b=ratio)
        latencies[name] = fit.latency_s
    assert abs(latencies["clean"] - truth_s) < 1e-4, latencies
    # the plain least-squares cost put it 0.47 ms late here
    assert abs(latencies["noisy"] - latencies["clean"]) < 1.5e-4, (latencies, truth_s)


@pytest.mark.slow  # a whole commissioning: scripts/test.sh --quick leaves it out
def test_an_overlapped_rig_with_noisy_transducers_is_commissioned_with_its_latency():
    """Rig 84 (overlapped, 0.13 bar per transducer) was refused: latency 0.62 +- 0.35 ms against a true 0.31."""
    spec, declared, ident = fc.first_attempt(84)
    assert ident.trusted, ident.problems
    values = fc.judged_values(ident, spec, declared)
    assert fc.wrong_values(values) == [], values
    latency, std, truth = values["position_latency_s"]
    # stated without the valley's share (sim.commission.fit.start_shifts: begun 0.5 ms away, its fit stops up to
    # 0.34 ms away), the noise leaves it sure to 0.15 ms
    valley = START_SHIFT_SHARE * ident.fit.start_shift["position_latency_s"]
    assert abs(latency - truth) < 1e-4 and (std ** 2 - valley ** 2) ** 0.5 < 1.5e-4, (values, valley)


@pytest.mark.slow  # a whole commissioning: scripts/test.sh --quick leaves it out
def test_a_value_the_noise_moves_is_stated_with_that_uncertainty():
    """Rig 321's valve, fitted again with the noise doubled, moves by more than its own value: the stated
    uncertainty holds that (so it is refused for it, or its truth lies within 3 sigma). Rig 237 was the example
    until the flow fit settled: 1424 rad/s (true 838), +-155 from the jackknife alone, trusted 3.8 sigma off."""
    spec, declared, ident = fc.first_attempt(NOISE_MOVES_THE_VALVE)
    shift = ident.fit.noise_shift["valve_natural_frequency_rad_s"]
    value, std, truth = fc.judged_values(ident, spec, declared)["valve_natural_frequency_rad_s"]
    assert shift > 0.2 * truth, shift
    assert std >= shift
    assert abs(value - truth) <= 3.0 * std or not ident.trusted, (value, std, truth)
    assert not ident.trusted or fc.wrong_values(fc.judged_values(ident, spec, declared)) == []


@pytest.mark.slow  # a whole commissioning: scripts/test.sh --quick leaves it out
def test_a_valve_the_noise_moved_is_fitted_once_the_fit_settles():
    """Rig 237: where the variable projection stopped, its valve came out 1453 +- 436 rad/s against a true 838 and
    moved 403 rad/s with the noise doubled; the alternation at C held settles it at the rig's own valve."""
    spec, declared, ident = fc.first_attempt(NOISE_MOVED_THE_VALVE)
    value, std, truth = fc.judged_values(ident, spec, declared)["valve_natural_frequency_rad_s"]
    assert abs(value - truth) < 0.1 * truth, (value, std, truth)
    assert ident.fit.noise_shift["valve_natural_frequency_rad_s"] < 0.1 * truth, ident.fit.noise_shift
    assert not ident.trusted or fc.wrong_values(fc.judged_values(ident, spec, declared)) == []
