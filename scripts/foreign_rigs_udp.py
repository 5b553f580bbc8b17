"""Foreign rigs through the UDP protocol, end to end: the rig emulator in its own process plays foreign rig SEED
(``--foreign-rig``), ``isorig identify rig`` commissions it in real time from what its lab knows (the start rig
file of ``sim.commission.foreign_campaign.declared_rig``), then ``isorig simulate --rig`` runs 2 mm at 1 Hz with
the rig file it wrote (or, refused, with the start file: what the lab would have). One line a rig.

    .venv/bin/python scripts/foreign_rigs_udp.py --seeds 173 3 [--watchdog-ms 18]
"""

from __future__ import annotations

import argparse
import json
import re
import subprocess
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from foreign_rigs import draw_rig  # noqa: E402
from sim.commission.foreign_campaign import start_rig_file_data  # noqa: E402

ISORIG = [sys.executable, "-m", "isorig"]


def run_rig(seed: int, watchdog_ms: float, folder: Path) -> dict:
    start = folder / f"start-{seed}.json"
    start.write_text(json.dumps(start_rig_file_data(draw_rig(seed).lab_knows())))
    proc = subprocess.Popen([*ISORIG, "rig-emulator", "--port", "0", "--foreign-rig", str(seed), "--rig-protocol",
                             "1", "--watchdog-ms", str(watchdog_ms)], stderr=subprocess.PIPE,
                            stdout=subprocess.DEVNULL, text=True)
    line = proc.stderr.readline()
    url = re.search(r"udp://[\d.]+:\d+", line)
    if url is None:
        proc.kill()
        raise SystemExit(f"the emulator did not start: {line}")
    try:
        out = folder / f"rig-{seed}.json"
        load = f"{draw_rig(seed).drawn['table.vertical_load_n']:.6g}"  # the jack's setting, as in the campaign
        ident = subprocess.run([*ISORIG, "identify", "rig", "--rig", url.group(0), "--rig-protocol", "1",
                                "--supply-bar", "100", "--vertical-load-n", load, "--rig-file", str(start),
                                "--out", str(out), "--json"], capture_output=True, text=True, timeout=300)
        row = {"seed": seed, "name": draw_rig(seed).name, "identify_exit": ident.returncode,
               "trusted": ident.returncode == 0}
        try:
            report = json.loads(ident.stdout[ident.stdout.index("{"): ident.stdout.rindex("}") + 1])
            row["problems"] = report.get("problems", [])
            row["record"] = report.get("record")
        except ValueError:
            row["problems"] = [ident.stdout[-300:] + ident.stderr[-300:]]
        rig_file = str(out if row["trusted"] else start)
        moved = subprocess.run([*ISORIG, "move", "--rig", url.group(0), "--rig-protocol", "1", "--position-m", "0",
                                "--rig-file", rig_file], capture_output=True, text=True, timeout=120)
        row["zeroed"] = moved.returncode == 0
        row["move_said"] = (moved.stdout + moved.stderr).strip().splitlines()[-1:]
        test = folder / f"test-{seed}"
        sim = subprocess.run([*ISORIG, "simulate", "--rig", url.group(0), "--rig-protocol", "1", "--out", str(test),
                              "--isolator", "IUT_a", "--supply-bar", "100", "--amplitude-m", "0.002",
                              "--frequency-hz", "1", "--cycles", "12", "--rig-file", rig_file],
                             capture_output=True, text=True, timeout=120)
        summary = json.loads((test / "summary.json").read_text()) if (test / "summary.json").exists() else {}
        verdict = summary.get("tracking_verdict", {})
        row.update(test_exit=sim.returncode, test_said=(sim.stdout + sim.stderr).strip().splitlines()[-1:],
                   status=summary.get("status"), reason=summary.get("reason"),
                   verdict=verdict.get("verdict"), share_pct=None if verdict.get("rms_share") is None
                   else 100 * verdict["rms_share"])
        return row
    finally:
        proc.terminate()
        proc.wait(10)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seeds", type=int, nargs="+", required=True)
    parser.add_argument("--watchdog-ms", type=float, default=18.0)
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        for seed in args.seeds:
            print(json.dumps(run_rig(seed, args.watchdog_ms, Path(tmp))), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
