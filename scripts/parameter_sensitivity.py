"""How wrong may a commissioned value be? The servo controller's tracking when the rig it is told differs from
the plant in one value the controller relies on (issue 32 item 3: "what the controller relies on decides the
verdict"; sim.commission.identify's MAX_RELATIVE_STD / MAX_ABSOLUTE_STD).

For each value and each error e (relative: told = true x (1 + e); absolute, V or s: told = true + e) the plant is
the rig as it truly is and the controller is told the wrong value; the issue's three cases run to their end
without detectors (20 mm at 0.5 Hz, 2 mm at 1 Hz, 0.5 mm at 1 Hz, IUT_a at 100 bar, 12 cycles, taper 1). Printed:
the tracking figure (RMS |y - r| over the last two full cycles / amplitude, %) and "LC" where the last two cycles
do not repeat in 5-30 Hz (sim.robustness.case_figures: a limit cycle or a sustained oscillation), beside the
cases' targets (0.1 %, 0.5 %, 1 %).

Run: .venv/bin/python scripts/parameter_sensitivity.py [--processes 2] [--values flow_gain,mass]
     [--base-latency-s 0.001] [--rig mass_kg=4000 ...] [--json FILE]
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from sim.engine import run_batch  # noqa: E402
from sim.rig import DEFAULT_RIG  # noqa: E402
from sim.robustness import RobustnessPoint, case_figures  # noqa: E402

CASES = (("20mm_0.5Hz", 0.02, 0.5, 0.001), ("2mm_1Hz", 0.002, 1.0, 0.005), ("0.5mm_1Hz", 0.0005, 1.0, 0.01))
#: value -> (rig field, relative?, errors)
VALUES = {
    "flow_gain": ("flow_gain_m3_per_s_v_sqrt_pa", True, (-0.3, -0.2, -0.1, -0.05, 0.05, 0.1, 0.2, 0.3)),
    "driver_gain_negative": ("driver_gain_negative", True, (-0.3, -0.2, -0.1, -0.05, 0.05, 0.1, 0.2, 0.3)),
    "mass": ("mass_kg", True, (-0.5, -0.3, -0.2, 0.2, 0.3, 0.5)),
    "bulk_modulus": ("bulk_modulus_pa", True, (-0.5, -0.3, -0.2, 0.2, 0.3, 0.5, 1.0)),
    "valve_frequency": ("valve_natural_frequency_rad_s", True, (-0.5, -0.3, -0.2, 0.2, 0.3, 0.5)),
    "dead_zone": ("dead_zone_v", False, (-0.1, -0.05, -0.03, 0.03, 0.05, 0.1)),
    "driver_offset": ("driver_offset_v", False, (-0.1, -0.05, -0.03, 0.03, 0.05, 0.1)),
    "latency": ("position_latency_s", False, (-0.001, -5e-4, -3e-4, 3e-4, 5e-4, 1e-3)),
}


def points(values: list[str], base_latency_s: float, base_changes: dict | None = None
           ) -> list[tuple[str, float, str, RobustnessPoint]]:
    base = DEFAULT_RIG.with_changes(position_latency_s=base_latency_s, **(base_changes or {}))
    out = []
    for value in values:
        name, relative, errors = VALUES[value]
        true = getattr(base, name)
        for e in (0.0,) + errors:
            told = true * (1.0 + e) if relative else true + e
            if told < 0.0:
                continue
            for case, amp, freq, target in CASES:
                p = RobustnessPoint("servo", "IUT_a", 100.0, freq, amp, "told", case, None, group="sensitivity",
                                    target=target, base_rig=base, rig_changes={name: told}, plant={name: true},
                                    cycles=12)
                out.append((value, e, case, p))
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--processes", type=int, default=2)
    ap.add_argument("--values", default=",".join(VALUES), help="comma-separated, of: " + ", ".join(VALUES))
    ap.add_argument("--base-latency-s", type=float, default=1e-3, help="the plant's (and told) position latency, s")
    ap.add_argument("--rig", action="append", default=[], metavar="NAME=VALUE",
                    help="a rig value of the base rig (plant and told), SI, e.g. mass_kg=4000 bulk_modulus_pa=5e8")
    ap.add_argument("--json", type=Path)
    args = ap.parse_args(argv)
    values = [v.strip() for v in args.values.split(",") if v.strip()]
    unknown = [v for v in values if v not in VALUES]
    if unknown:
        ap.error(f"unknown --values {unknown}; allowed: {', '.join(VALUES)}")
    base_changes = {}
    for item in args.rig:
        name, _, value = item.partition("=")
        try:
            base_changes[name.strip()] = float(value)
        except ValueError:
            ap.error(f"--rig {item!r}: expected NAME=VALUE with a number in SI units")
    pts = points(values, args.base_latency_s, base_changes)
    t0 = time.perf_counter()
    results = run_batch([p.scenario() for _, _, _, p in pts], processes=args.processes)
    rows = []
    for (value, e, case, p), result in zip(pts, results, strict=True):
        f = case_figures(p, result)
        rows.append({"value": value, "error": e, "case": case, "figure_pct": 100 * f["figure"],
                     "target_pct": 100 * p.target, "limit_cycle": bool(f["limit_cycle"]), "met": bool(f["met"])})
    print(f"{len(rows)} runs in {time.perf_counter() - t0:.0f} s (servo, IUT_a 100 bar, plant latency "
          f"{1e3 * args.base_latency_s:g} ms{''.join(f', {k} {v:g}' for k, v in base_changes.items())})")
    for value in values:
        relative = VALUES[value][1]
        print(f"\n{value} ({'told/true - 1' if relative else 'told - true, ' + ('s' if value == 'latency' else 'V')})")
        print(f"{'error':>9} " + " ".join(f"{c[0]:>16}" for c in CASES))
        for e in sorted({r["error"] for r in rows if r["value"] == value}):
            cells = []
            for case, *_ in CASES:
                r = next(r for r in rows if r["value"] == value and r["error"] == e and r["case"] == case)
                mark = " LC" if r["limit_cycle"] else ("   " if r["met"] else "  x")
                cells.append(f"{r['figure_pct']:12.3f}{mark:>4}")
            label = f"{100 * e:+.0f} %" if relative else (f"{1e3 * e:+.1f} ms" if value == "latency"
                                                           else f"{1e3 * e:+.0f} mV")
            print(f"{label:>9} " + " ".join(cells))
    if args.json:
        args.json.write_text(json.dumps(rows, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
