"""What the servo's valve compensation is worth on foreign rigs: each rig commissioned as `isorig compare
--foreign-rigs` does it (a second attempt where the first suggests one), then 2 mm and 0.5 mm at 1 Hz with the
commissioned rig file, and again with the servo told no play (or no underlap): the same plant, the same fit.

    .venv/bin/python scripts/valve_compensation.py --seeds 24 66 79 --without underlap_v
    .venv/bin/python scripts/valve_compensation.py --seeds 64 87 56 --without valve_play_v

One line a rig: the fitted play and underlap, then each case's tracking figure (% of the amplitude) and its stop.
"""

from __future__ import annotations

import argparse
import sys
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

CASES = ("2mm_1Hz", "0.5mm_1Hz")


def rig_row(seed: int, without: str) -> dict | None:
    """One rig: commissioned, then each case with the commissioned rig and with ``without`` set to 0."""
    import numpy as np

    from sim.commission import foreign_campaign as fc

    np.seterr(all="ignore")
    lab = fc.commission_as_a_lab(fc.ForeignRun(seed))
    spec, ident = lab.spec, lab.last
    if not ident.trusted:
        return None
    section = fc.commissioning_section(ident, lab.max_velocity_m_per_s)
    row = {"seed": seed, "valve_play_v": ident.rig.valve_play_v, "underlap_v": ident.rig.underlap_v}
    for label, amplitude_m, frequency_hz, _target in fc.CASES:
        if label not in CASES:
            continue
        for tag, rig in (("with", ident.rig), ("without", ident.rig.with_changes(**{without: 0.0}))):
            result = fc.tested(spec, rig, amplitude_m, frequency_hz, section)
            row[f"{label} {tag}"] = (result["share"], result["stop_kind"])
    return row


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, nargs="+", required=True, help="foreign rigs (foreign_rigs.draw_rig)")
    parser.add_argument("--without", choices=("valve_play_v", "underlap_v"), default="valve_play_v",
                        help="the compensation left out in the second run of each case")
    parser.add_argument("--workers", type=int, default=2)
    args = parser.parse_args(argv)
    with ProcessPoolExecutor(args.workers) as pool:
        rows = list(pool.map(rig_row, args.seeds, [args.without] * len(args.seeds)))
    for seed, row in zip(args.seeds, rows, strict=True):
        if row is None:
            print(f"rig {seed}: not commissioned")
            continue
        cases = "  ".join(f"{key} refused before start" if row[key][0] is None else
                          f"{key} {100 * row[key][0]:.3f} %{' (' + row[key][1] + ' stop)' if row[key][1] else ''}"
                          for key in (f"{label} {tag}" for label in CASES for tag in ("with", "without")))
        print(f"rig {seed}: play {row['valve_play_v']:.3f} V, underlap {row['underlap_v']:.3f} V  {cases}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
