"""`isorig simulate`: one closed-loop test on the simulated rig -> timeseries.csv + summary.json."""

from __future__ import annotations

import json
import time
from pathlib import Path

from isorig.cli import Progress, UsageError, whole_number


def register(sub) -> None:
    from sim.controllers import CONTROLLER_NAMES, DEFAULT_CONTROLLER
    from sim.isolator import PRESETS

    p = sub.add_parser("simulate", help="run one closed-loop test on the simulated rig")
    p.add_argument("--isolator", default="IUT_a",
                   help=f"preset ({', '.join(PRESETS)}) or path to an isolator .json file")
    p.add_argument("--supply-bar", type=float, default=100.0, help="supply pressure in bar (default 100)")
    p.add_argument("--amplitude-m", type=float, default=0.02, help="sine amplitude in m (default 0.02)")
    p.add_argument("--frequency-hz", type=float, default=1.0, help="sine frequency in Hz (default 1)")
    p.add_argument("--cycles", type=whole_number, default=30, help="number of cycles (default 30)")
    p.add_argument("--taper-cycles", type=whole_number, default=1, help="ramp-in/out cycles (default 1)")
    p.add_argument("--offset-m", type=float, default=0.0, help="mean displacement in m (default 0)")
    p.add_argument("--controller", choices=CONTROLLER_NAMES, default=DEFAULT_CONTROLLER,
                   help=f"controller (default {DEFAULT_CONTROLLER})")
    p.add_argument("--controller-option", action="append", default=[], metavar="NAME=VALUE", type=option_pair,
                   help="override a controller default, e.g. dimensionless_as=true or gamma=5e4 (repeatable)")
    p.add_argument("--out", required=True, help="output directory for timeseries.csv and summary.json")
    p.set_defaults(func=run)


def option_pair(text: str) -> tuple[str, float | bool]:
    """NAME=VALUE with a number or true/false."""
    import argparse

    name, sep, raw = text.partition("=")
    if not sep or not name:
        raise argparse.ArgumentTypeError(f"{text!r} is not NAME=VALUE")
    if raw.lower() in ("true", "false"):
        return name, raw.lower() == "true"
    try:
        return name, float(raw)
    except ValueError:
        raise argparse.ArgumentTypeError(f"value of {name!r} must be a number or true/false, not {raw!r}") from None


def run(args) -> int:
    from sim.engine import Scenario, Simulation
    from sim.records import write_csv

    scenario = Scenario.sine(args.isolator, args.supply_bar, args.amplitude_m, args.frequency_hz, args.cycles,
                             controller=args.controller, taper_cycles=args.taper_cycles, offset_m=args.offset_m,
                             controller_options=dict(args.controller_option))
    scenario.validate()
    out = Path(args.out)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise UsageError(f"isorig simulate: cannot create --out {out}: {exc.strerror}") from None
    progress = Progress(f"simulating {scenario.duration_s:g} s")
    t0 = time.perf_counter()
    result = Simulation(scenario, validate=False).run(progress=progress)
    progress.close()
    elapsed = time.perf_counter() - t0
    write_csv(out / "timeseries.csv", result.samples)
    summary = result.summary()
    summary["wall_time_s"] = elapsed
    (out / "summary.json").write_text(json.dumps(summary, indent=2))
    last = summary.get("last_two_cycles", {})
    print(f"wrote {out / 'timeseries.csv'} ({len(result.samples)} samples) and {out / 'summary.json'}")
    print(f"RMS |y - r| over the run: {summary['rms_y_minus_r_m'] * 1e3:.3f} mm; "
          + (f"last two cycles: {last['rms_y_minus_r_m'] * 1e3:.3f} mm "
             f"({100 * last['rms_y_minus_r_over_amplitude']:.2f} % of amplitude); " if last else "")
          + f"saturated samples {100 * summary['saturated_share']:.2f} %")
    return 0 if not result.diverged else 1
