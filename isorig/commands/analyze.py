"""`isorig analyze FILE.csv`: per-cycle isolator quantities (K_eff, EDC, xi_eff, Q_d, K_d) of any
force-displacement record with the columns time_s, displacement_m, force_n (other columns are ignored)."""

from __future__ import annotations

import json
import math

from isorig.cli import UsageError

JSON_KEYS = ("cycle", "d_max_m", "d_min_m", "f_max_n", "f_min_n", "k_eff_n_per_m", "edc_j", "xi_eff", "qd_n",
             "kd_n_per_m")

# (key, heading, scale to the displayed unit, format)
TABLE = (
    ("cycle", "cycle", 1, "{:>5d}"),
    ("d_max_m", "d+ mm", 1e3, "{:>8.3f}"),
    ("d_min_m", "d- mm", 1e3, "{:>8.3f}"),
    ("f_max_n", "F+ kN", 1e-3, "{:>9.3f}"),
    ("f_min_n", "F- kN", 1e-3, "{:>9.3f}"),
    ("k_eff_n_per_m", "K_eff kN/mm", 1e-6, "{:>11.4f}"),
    ("edc_j", "EDC J", 1, "{:>10.2f}"),
    ("xi_eff", "xi_eff %", 100, "{:>8.2f}"),
    ("qd_n", "Q_d kN", 1e-3, "{:>9.3f}"),
    ("kd_n_per_m", "K_d kN/mm", 1e-6, "{:>10.4f}"),
)


def register(sub) -> None:
    p = sub.add_parser("analyze", help="per-cycle K_eff, EDC, xi_eff, Q_d, K_d of a force-displacement CSV")
    p.add_argument("file", help="CSV with a header and the columns time_s, displacement_m, force_n")
    p.add_argument("--json", action="store_true", help="print {\"cycles\": [...]} as JSON instead of a table")
    p.add_argument("--frequency-hz", type=float, default=None,
                   help="split cycles by the command's phase: cycle k starts at the first time + k / f "
                        "(default: split at upward zero crossings with hysteresis)")
    p.set_defaults(func=run)


def _clean(value):
    return None if isinstance(value, float) and not math.isfinite(value) else value


def format_table(cycles: list[dict]) -> str:
    widths = [len(fmt.format(1 if key == "cycle" else 1.0)) for key, _h, _s, fmt in TABLE]
    head = " ".join(h.rjust(max(w, len(h))) for (_k, h, _s, _f), w in zip(TABLE, widths, strict=True))
    lines = [head]
    for c in cycles:
        cells = []
        for (key, heading, scale, fmt), w in zip(TABLE, widths, strict=True):
            value = c.get(key)
            text = "-" if value is None else fmt.format(value if key == "cycle" else value * scale)
            cells.append(text.strip().rjust(max(w, len(heading))))
        lines.append(" ".join(cells))
    return "\n".join(lines)


def run(args) -> int:
    import numpy as np

    from sim.metrics import cycle_metrics, read_csv_columns

    if args.frequency_hz is not None and not (math.isfinite(args.frequency_hz) and 0 < args.frequency_hz <= 100):
        raise UsageError(f"isorig analyze: --frequency-hz = {args.frequency_hz:g} must be in (0, 100] Hz")
    cols = read_csv_columns(args.file)
    t, d, f = cols["time_s"], cols["displacement_m"], cols["force_n"]
    starts = end = None
    if args.frequency_hz is not None:
        period = 1.0 / args.frequency_hz
        n = int(math.floor((t[-1] - t[0]) / period + 1e-9)) + 1
        starts = t[0] + period * np.arange(n)
        end = starts[-1] + period
    cycles = cycle_metrics(t, d, f, starts, end)
    try:
        _print(args, cycles, t, starts is not None)
    except BrokenPipeError:  # e.g. piped into `head`
        pass
    return 0


def _print(args, cycles, t, by_phase: bool) -> int:
    if args.json:
        print(json.dumps({"cycles": [{k: _clean(c[k]) for k in JSON_KEYS} for c in cycles]}, indent=1))
        return 0
    if not cycles:
        print(f"no complete cycle in {args.file} ({t.size} samples, {t[-1] - t[0]:g} s)")
        return 0
    print(f"{args.file}: {len(cycles)} complete cycles in {t.size} samples "
          f"({'by phase at ' + format(args.frequency_hz, 'g') + ' Hz' if by_phase else 'by zero crossings'})")
    print(format_table(cycles))
    return 0
