"""The servo's loop margin on a foreign rig (written from the physics, not isorig's model; issue 32 item 4).

Foreign rig 204 (a 4750 kg table on a 13 Hz oil column, an overlapped 72 Hz valve, the position read 1.7 ms late)
is commissioned at the first attempt (on most machines: see the test). At the servo's K_p of 30 /s its linearised
loop keeps a gain margin of 1.2, and 20 mm at 0.5 Hz and 2 mm at 1 Hz were stopped by 10-12 Hz oscillations (so was
2 mm through UDP). The loop design (sim.controllers.servo.loop_design) lowers K_p to keep a margin of 2: both run to
their end with the table within the labs' targets (measured 0.086 % and 0.31 %).
"""

import pytest

from sim.commission import foreign_campaign as fc

RIG = 204


@pytest.mark.slow  # a whole commissioning and four runs: scripts/test.sh --quick leaves it out
def test_a_soft_heavy_foreign_rig_runs_without_oscillating_at_the_designed_loop_gain():
    spec, _declared, ident = fc.first_attempt(RIG)
    # the fit's verdict on rig 204 turns with the last bits of the machine's libm (trusted here; with glibc's
    # non-FMA exp and log its valve frequency is uncertain by +-24 % against +-20 %): the loop design is what is
    # tested, so the fitted rig runs as a lab that accepted it would, and a refusal for anything but a value's
    # uncertainty fails the test
    assert all("is uncertain by" in problem for problem in ident.problems), ident.problems
    section = {**fc.commissioning_section(ident, fc.DEFAULT_MAX_VELOCITY_M_PER_S), "trusted": True}
    for label, amplitude_m, frequency_hz, target in fc.CASES[:2]:  # 20 mm at 0.5 Hz, 2 mm at 1 Hz
        before = fc.tested(spec, ident.rig, amplitude_m, frequency_hz, section, {"min_gain_margin": 0.0})
        assert before["stop_kind"] == "oscillation", (label, before)  # K_p = 30 /s, as it ran before the design
        designed = fc.tested(spec, ident.rig, amplitude_m, frequency_hz, section)
        assert designed["stopped_s"] is None, (label, designed)
        # the table follows within the lab's target, and the verdict says no better than the table did
        assert designed["table_share"] <= target, (label, designed)
        assert designed["share"] >= designed["table_share"], (label, designed)
        if label == "2mm_1Hz":  # at 20 mm the verdict is the latency's uncertainty (+-3 x 0.15 ms: 0.1 % at 0.5
            # Hz, sim.follow.judged_latencies_s), so 0.10-0.11 % with the last bits of the machine's libm
            assert designed["share"] <= target, (label, designed)
