"""The latency along the flow balance's valley (issue 32 item 3: "a latency estimate that can be biased never makes
the verdict more optimistic than the table"), on a foreign rig (written from the physics, not isorig's model).

Below the flow balance's 35 Hz corner a second-order valve and a delay differ in a cubic term only: the valve's lag
and the latency trade along a flat valley of the fit's cost, and where the fit stops in it depends on where it
began. The jackknife's groups all begin at the whole fit's solution and cannot see that. Foreign rig 121 (an
overlapped 118 Hz valve at damping 0.94, its position read 0.56 ms late) was trusted with 0.113 +- 0.083 ms, 5.4
sigma off, and its 20 mm verdict said 0.056 % where the table was 0.100 % off. The fit now starts again 0.5 ms
either side of its latency (sim.commission.fit.start_shifts) and states half the largest move beside the rest.

Why it stopped where it did: the variable projection's bias-compensated cost, minimised over the valve and the
latency, is ill-posed (it falls without end as the compensated C grows: 7.0 where the fit stopped, 0.12 after 400
evaluations). The fit now settles by alternating the non-linear parameters at C held with (K_q, C) at them
(sim.commission.flow.fit_flow): rig 121's latency 0.567 ms from its grid and 0.566-0.574 from 0.5 ms either side.
"""

import pytest

from sim.commission import foreign_campaign as fc
from sim.commission.identify import (
    LATENCY_PER_VALVE_LAG_UNEXPLAINED,
    RETRY_MAX_VELOCITY_M_PER_S,
    START_SHIFT_SHARE,
    valve_lag_s,
    with_systematic,
)

VALLEY_RIG = 121
VALVE_LAG_RIG = 231


@pytest.mark.slow  # a whole commissioning and a 20 mm run: scripts/test.sh --quick leaves it out
def test_a_latency_the_valve_took_a_share_of_is_stated_with_the_valley_and_judged_with_it():
    spec, declared, ident = fc.first_attempt(VALLEY_RIG)
    assert ident.fit is not None, ident.problems
    value, std, truth = fc.judged_values(ident, spec, declared)["position_latency_s"]
    shift = ident.fit.start_shift["position_latency_s"]
    assert shift > 0.0
    assert std >= START_SHIFT_SHARE * shift  # the valley's term is part of the stated uncertainty
    # the stated uncertainty holds the truth (before: 5.4 sigma off), trusted or not
    assert abs(value - truth) <= 3.0 * std, (value, std, truth, shift)
    assert not ident.trusted or fc.wrong_values(fc.judged_values(ident, spec, declared)) == []
    if ident.trusted:  # the verdict, judged with that uncertainty, says no better than the table did
        section = fc.commissioning_section(ident, fc.DEFAULT_MAX_VELOCITY_M_PER_S)
        label, amplitude_m, frequency_hz, _target = fc.CASES[0]  # 20 mm at 0.5 Hz
        run = fc.tested(spec, ident.rig, amplitude_m, frequency_hz, section)
        assert run["stopped_s"] is None, (label, run)
        assert run["share"] >= run["table_share"], (label, run)


@pytest.mark.slow  # a whole commissioning: scripts/test.sh --quick leaves it out
def test_the_flow_fit_settles_at_one_latency_from_either_side_of_the_valley():
    """Before the alternation the fit stopped at 0.113 ms and, begun 0.5 ms later, at 0.551 (truth 0.560)."""
    spec, declared, ident = fc.first_attempt(VALLEY_RIG)
    value, _std, truth = fc.judged_values(ident, spec, declared)["position_latency_s"]
    assert ident.fit.start_shift["position_latency_s"] < 3e-5, ident.fit.start_shift
    assert abs(value - truth) < 3e-5, (value, truth)
    valve, valve_std, valve_truth = fc.judged_values(ident, spec, declared)["valve_natural_frequency_rad_s"]
    assert abs(valve - valve_truth) < 0.05 * valve_truth, (valve, valve_std, valve_truth)  # before: 631 against 738


def test_the_valley_widens_the_latency_by_its_share_of_the_move():
    """with_systematic adds START_SHIFT_SHARE of the start shift, in quadrature, to the latency alone."""
    from sim.commission.fit import Estimate, RigFit
    from sim.rig import DEFAULT_RIG

    def fit(start_shift):
        estimates = {"position_latency_s": Estimate(1e-3, 0.0, "s", ""), "mass_kg": Estimate(1000.0, 0.0, "kg", "")}
        return RigFit(estimates, 1.0, 1.0, 1.0, DEFAULT_RIG, start_shift=start_shift)

    without, with_move = fit({}), fit({"position_latency_s": 4e-4})
    with_systematic(without)
    with_systematic(with_move)
    before = without.estimates["position_latency_s"].std
    after = with_move.estimates["position_latency_s"].std
    assert after ** 2 == pytest.approx(before ** 2 + (START_SHIFT_SHARE * 4e-4) ** 2)
    assert with_move.estimates["mass_kg"].std == without.estimates["mass_kg"].std


def test_the_latency_holds_the_valves_lag_as_far_as_the_flow_balance_leaves_it_unexplained():
    """with_systematic adds LATENCY_PER_VALVE_LAG_UNEXPLAINED sqrt(1 - R^2) of the fitted valve's lag 2 xi / w, in
    quadrature, to the latency alone; a flow balance that explains everything adds nothing."""
    from sim.commission.fit import Estimate, RigFit
    from sim.rig import DEFAULT_RIG

    def fit(flow_r2):
        estimates = {"position_latency_s": Estimate(1e-3, 1e-4, "s", ""), "mass_kg": Estimate(1000.0, 10.0, "kg", ""),
                     "valve_natural_frequency_rad_s": Estimate(300.0, 1.0, "rad/s", ""),
                     "valve_damping_ratio": Estimate(0.75, 0.01, "-", "")}
        out = RigFit(estimates, flow_r2, 1.0, 1.0, DEFAULT_RIG)
        with_systematic(out)
        return out

    exact, loose = fit(1.0), fit(0.99)
    lag_s = 2.0 * 0.75 / 300.0
    assert valve_lag_s(loose) == pytest.approx(lag_s)
    before, after = exact.estimates["position_latency_s"].std, loose.estimates["position_latency_s"].std
    assert after ** 2 == pytest.approx(before ** 2 + (LATENCY_PER_VALVE_LAG_UNEXPLAINED * 0.1 * lag_s) ** 2)
    assert loose.estimates["mass_kg"].std == exact.estimates["mass_kg"].std


@pytest.mark.slow  # a whole commissioning: scripts/test.sh --quick leaves it out
def test_a_latency_the_valve_model_shifted_is_stated_with_the_valves_lag():
    """Foreign rig 231 (an underlapped 51 Hz spool damped 0.87), commissioned at 40 mm/s as its first attempt's
    refusal suggests: the flow balance took 0.63 ms of the valve's lag into the latency (2.62 +- 0.18 ms against a
    true 1.99) and was trusted 3.5 sigma off. With the valve's lag in the latency's uncertainty its truth lies
    within 3 sigma, trusted or not."""
    from foreign_rigs import draw_rig

    spec = draw_rig(VALVE_LAG_RIG)
    declared = fc.declared_rig(spec.lab_knows())
    ident = fc.commission(spec, declared, fc.DEFAULT_MAX_STROKE_M, RETRY_MAX_VELOCITY_M_PER_S)  # 40 mm/s
    assert ident.fit is not None, ident.problems
    values = fc.judged_values(ident, spec, declared)
    value, std, truth = values["position_latency_s"]
    assert abs(value - truth) > 4e-4, (value, truth)  # the shift is still there: this test is about its statement
    assert abs(value - truth) <= 3.0 * std, (value, std, truth)
    assert not ident.trusted or fc.wrong_values(values) == []
