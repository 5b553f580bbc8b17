"""Tune the PID baseline once on IUT_a, 100 bar, 0.5 Hz, 20 mm (the only tuning it ever gets).

Grid over K_p and K_i; the cost is the RMS of y - r over the last two full cycles. A candidate is
accepted only with a gain margin of 2, as a servo engineer would tune: the same loop with both gains
doubled must not saturate the valve command (no limit cycle).
Prints the best gains; they are copied into sim/controllers/pid.py.
Run: .venv/bin/python scripts/tune_pid.py
"""

import itertools

from sim.engine import Scenario, run_batch


def main():
    grid = list(itertools.product([400, 700, 1000, 1400, 2000, 2800, 4000], [3000, 10000, 20000, 40000, 80000]))
    scenarios = [Scenario.sine("IUT_a", 100.0, 0.02, 0.5, 6, controller="pid",
                               controller_options={"kp_v_per_m": g * kp, "ki_v_per_m_s": g * ki})
                 for g in (1, 2) for kp, ki in grid]
    results = run_batch(scenarios)
    nominal, doubled = results[: len(grid)], results[len(grid):]
    rows = []
    for (kp, ki), res, res2 in zip(grid, nominal, doubled, strict=False):
        s, s2 = res.summary(), res2.summary()
        ok = s["saturated_share"] == 0 and s2["saturated_share"] == 0 and s["all_finite"] and s2["all_finite"]
        cost = s["last_two_cycles"]["rms_y_minus_r_m"] if ok else 1.0
        rows.append((cost, kp, ki))
    rows.sort()
    for cost, kp, ki in rows[:8]:
        print(f"kp {kp:6.0f} V/m  ki {ki:7.0f} V/(m s)  RMS(y - r) last two cycles {cost * 1e3:.3f} mm")


if __name__ == "__main__":
    main()
