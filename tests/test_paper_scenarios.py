from sim.engine import run_batch
from sim.paper import convergence_check, paper_scenarios


def test_paper_scenarios_converge_with_mrac():
    """Issue 2's criterion on the paper's four scenarios: finite, and the last two cycles' RMS(y - y_m)
    under half of cycle 2's."""
    for res in run_batch(paper_scenarios()):
        summary = res.summary()
        check = convergence_check(summary)
        assert summary["all_finite"], res.scenario.label
        assert check["passes"], (res.scenario.label, check)
        rms = [c["rms_y_minus_ym_m"] for c in summary["cycles"]]
        assert rms[-1] < rms[2] < rms[0]  # falling from cycle to cycle
