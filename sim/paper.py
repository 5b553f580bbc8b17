"""The paper's four simulation scenarios (section V) with its MRAC settings."""

from __future__ import annotations

from .engine import Scenario

DURATION_S = 30.0


def paper_scenarios(controller: str = "mrac", duration_s: float = DURATION_S) -> list[Scenario]:
    """IUT_a 100 bar 20 mm and IUT_b 70 bar 30 mm, each at 0.5 and 1 Hz; no taper (the paper starts at rest)."""
    cases = [("IUT_a", 100.0, 0.02), ("IUT_b", 70.0, 0.03)]
    out = []
    for iso, bar, amp in cases:
        for f in (0.5, 1.0):
            s = Scenario.sine(iso, bar, amp, f, int(round(duration_s * f)), controller=controller, taper_cycles=0)
            s.label = f"{iso} {bar:g} bar {amp * 1e3:g} mm {f:g} Hz"
            out.append(s)
    return out


def convergence_check(summary: dict) -> dict:
    """The paper-results criterion: RMS(y - y_m) per cycle falls; last two cycles under half of cycle 2's."""
    rms = [c["rms_y_minus_ym_m"] for c in summary["cycles"]]
    last_two = max(rms[-2:])
    return {"cycle2_rms_m": rms[1], "last_two_max_rms_m": last_two, "ratio": last_two / rms[1],
            "passes": summary["all_finite"] and last_two < 0.5 * rms[1]}
