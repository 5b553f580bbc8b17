"""The controlled stop across the envelope (issue 21): trips at many phases and frequencies, the peak after each.

Each case runs a whole test through the service's worker (backend.worker.run_here) on the simulated rig with
the default controller: a sine beyond the operator's displacement limit, whose action is ``controlled_stop``
(the displacement guard brakes the target to rest within the limit), or a force limit with ``controlled_stop``
that trips mid-stroke (the braking stop from wherever the table is). For each it prints the trip time and
phase, the peak |y| after the trip, the limit, the tracking error |y - r| at the trip, and whether the peak
stayed within the tripped displacement limit plus that error (and within the displacement limit on a force
trip). Exit 1 if any case did not.

    .venv/bin/python scripts/stop_envelope.py [--quick]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from backend.safety import default_limits  # noqa: E402
from backend.worker import run_here  # noqa: E402
from sim.isolator import PRESETS  # noqa: E402
from sim.profiles import SineProfile  # noqa: E402
from sim.rig import DEFAULT_RIG  # noqa: E402


def job(isolator: str, supply_bar: float, amplitude_m: float, frequency_hz: float, cycles: int, limits: dict) -> dict:
    base = default_limits(DEFAULT_RIG).to_dict()
    return {"test_id": 1, "rig": "simulated", "speed": 1e6, "realtime": False,
            "scenario": {"isolator": PRESETS[isolator].to_dict(), "supply_pa": supply_bar * 1e5, "controller": "servo",
                         "profile": [SineProfile(amplitude_m, frequency_hz, cycles, 1).to_dict()]},
            "limits": {**base, **limits}}


def case(isolator, supply_bar, amplitude_m, frequency_hz, limits, cycles=3):
    run, out, status, reason = run_here(job(isolator, supply_bar, amplitude_m, frequency_hz, cycles, limits))
    s = out.samples()
    trips = [e for e in out.of_kind("event") if e["kind"] == "limit_trip"]
    if not trips:
        return {"status": status, "reason": reason, "tripped": False}
    t_trip = trips[0]["values"]["time_s"]
    k = int(round(t_trip / 1e-3))
    y = s["displacement_m"]  # the table's true position: what must not pass the limit
    after = np.abs(y[k:])
    e_trip = abs(float(s["measured_displacement_m"][k] - s["target_m"][k]))
    return {"status": status, "reason": reason, "tripped": True, "detector": trips[0]["values"].get("detector",
                                                                                                      trips[0]["message"]),
            "t_trip_s": t_trip, "phase_deg": (360.0 * frequency_hz * t_trip) % 360.0,
            "peak_after_m": float(after.max()), "e_trip_m": e_trip, "at_rest_m_per_s": float(np.abs(np.diff(
                s["displacement_m"][-100:])).max() / 1e-3), "end_s": float(s["time_s"][-1])}


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--quick", action="store_true", help="a smaller grid (12 cases)")
    args = p.parse_args()
    shares = (0.35, 0.6, 0.85) if args.quick else (0.25, 0.4, 0.55, 0.7, 0.85, 0.95)
    sines = ((0.03, 0.5), (0.02, 1.0)) if args.quick else ((0.03, 0.5), (0.03, 1.0), (0.02, 1.0), (0.02, 2.0),
                                                               (0.01, 2.0), (0.005, 4.0), (0.04, 0.25))
    rows, bad = [], 0
    print(f"{'case':<34} {'trip t s':>8} {'phase':>6} {'limit mm':>9} {'peak mm':>9} {'|e| mm':>8} "
          f"{'margin mm':>10}  ok")
    for amplitude_m, f in sines:
        for share in shares:
            limit = share * amplitude_m
            r = case("IUT_b", 70.0, amplitude_m, f, {"displacement_m": limit,
                                                     "actions": {"displacement_m": "controlled_stop"}})
            rows.append(("displacement", amplitude_m, f, limit, r))
    for amplitude_m, f in sines[: 2 if args.quick else 4]:
        for force_share in ((0.6,) if args.quick else (0.4, 0.7, 0.9)):
            # a force limit below the loop's peak force: the trip comes mid-stroke, the displacement limit
            # (just beyond the amplitude) must still hold
            limit_f = force_share * 1e3 * amplitude_m * 1e3 * 0.9  # about share x k_eff A (IUT_b ~0.9 kN/mm)
            r = case("IUT_b", 70.0, amplitude_m, f, {"force_n": limit_f, "displacement_m": 1.02 * amplitude_m,
                                                     "actions": {"force_n": "controlled_stop",
                                                                 "displacement_m": "controlled_stop"}})
            rows.append(("force", amplitude_m, f, 1.02 * amplitude_m, r))
    n_trips = 0
    for kind, amplitude_m, f, limit, r in rows:
        name = f"{kind} {amplitude_m * 1e3:g} mm {f:g} Hz"
        if not r["tripped"]:
            print(f"{name:<34} no trip ({r['status']}: {r['reason']})")
            bad += kind == "displacement"
            continue
        n_trips += 1
        bound = limit + r["e_trip_m"]
        ok = r["peak_after_m"] <= bound and r["status"] == "aborted"
        bad += not ok
        label = f"{name} lim {limit * 1e3:.3g}"
        print(f"{label:<34} {r['t_trip_s']:>8.3f} {r['phase_deg']:>6.0f} {limit * 1e3:>9.3f} "
              f"{r['peak_after_m'] * 1e3:>9.3f} {r['e_trip_m'] * 1e3:>8.4f} {(bound - r['peak_after_m']) * 1e3:>10.4f}"
              f"  {'yes' if ok else 'NO'}")
    print(f"{n_trips} trips; {n_trips - bad} kept the limit plus the tracking error at the trip; {bad} did not")
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
