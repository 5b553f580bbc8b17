"""Commissioning through the UDP protocol, end to end (issue 20): the rig emulator in its own process plays
rigs drawn from docs/examples/unknown_rigs.toml; `isorig identify rig` commissions each, then `isorig simulate
--rig` runs the campaign's tests with the rig file it wrote, and the same tests without it. Prints a table:
rig time, how far and how fast the table went against its bounds, the fit's errors, the tracking verdicts.

    .venv/bin/python scripts/commissioning_emulator.py [--rigs 3] [--seed 20261127] [--watchdog-ms 18]

Real time: about 70 s a rig. The verdicts judge the reading against the target of the declared latency ago,
as the service does.
"""

from __future__ import annotations

import argparse
import json
import re
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
ISORIG = [sys.executable, "-m", "isorig"]
TESTS = ((0.02, 0.5, 10), (0.002, 1.0, 10))


def emulator(plant: dict, watchdog_ms: float, status: Path) -> tuple[subprocess.Popen, str]:
    flags = [f"--plant-set={k}={v!r}" for k, v in plant.items()]
    proc = subprocess.Popen([*ISORIG, "rig-emulator", "--port", "0", "--isolator", "IUT_a", "--watchdog-ms",
                             str(watchdog_ms), "--status-file", str(status), *flags], stderr=subprocess.PIPE,
                            stdout=subprocess.DEVNULL, text=True)
    line = proc.stderr.readline()
    match = re.search(r"udp://[\d.]+:\d+", line)
    if match is None:
        proc.kill()
        raise SystemExit(f"the emulator did not start: {line}")
    return proc, match.group(0)


def simulate(url: str, out: Path, amplitude_m: float, frequency_hz: float, cycles: int, rig_file: Path | None):
    args = [*ISORIG, "simulate", "--rig", url, "--out", str(out), "--isolator", "IUT_a", "--supply-bar", "100",
            "--amplitude-m", str(amplitude_m), "--frequency-hz", str(frequency_hz), "--cycles", str(cycles)]
    if rig_file is not None:
        args += ["--rig-file", str(rig_file)]
    subprocess.run(args, capture_output=True, text=True, timeout=300)
    summary = json.loads((out / "summary.json").read_text())
    v = summary.get("tracking_verdict", {})
    return summary.get("status"), v.get("rms_share"), v.get("verdict")


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--rigs", type=int, default=3)
    parser.add_argument("--seed", type=int, default=20261127)
    parser.add_argument("--watchdog-ms", type=float, default=18.0)
    args = parser.parse_args()
    sys.path.insert(0, str(ROOT))
    from sim.campaign import load_campaign
    from sim.rigfile import load_rig_file

    campaign = load_campaign(ROOT / "docs" / "examples" / "unknown_rigs.toml")
    campaign.runs, campaign.seed = args.rigs, args.seed
    print("| rig | oil column Hz | dead zone V | latency ms | rig time s | excursion / bound | velocity / bound | "
          "trusted | mass err % | beta / V_0 err % | DZ err mV | L err ms | " +
          " | ".join(f"{a * 1e3:g} mm {f:g} Hz with / without" for a, f, _ in TESTS) + " |")
    print("|" + "---|" * (12 + len(TESTS)))
    for i, (plant, _seed) in enumerate(campaign.draws()):
        rig = campaign.nominal_rig.with_changes(**plant)
        column_hz = (2 * rig.bulk_modulus_pa * rig.piston_area_m2 ** 2 / (rig.half_volume_m3 * rig.mass_kg)) ** 0.5 \
            / (2 * np.pi)
        with tempfile.TemporaryDirectory() as tmp:
            tmp = Path(tmp)
            proc, url = emulator(plant, args.watchdog_ms, tmp / "status.json")
            try:
                out = subprocess.run([*ISORIG, "identify", "rig", "--rig", url, "--supply-bar", "100", "--isolator",
                                      "IUT_a", "--out", str(tmp / "rig.json"), "--json"], capture_output=True,
                                     text=True, timeout=300)
                ident = json.loads(out.stdout.splitlines()[-2])  # the JSON, then "wrote ..." or "no rig file ..."
                rec = ident["record"]
                trusted = out.returncode == 0
                cells = [f"{i}", f"{column_hz:.0f}", f"{rig.dead_zone_v:.2f}", f"{rig.position_latency_s * 1e3:.2f}",
                         f"{rec['rig_time_s']:.1f}", f"{rec['peak_excursion_m'] / 0.002:.2f}",
                         f"{rec['peak_velocity_m_per_s'] / 0.02:.2f}", "yes" if trusted else "NO: "
                         + "; ".join(ident["problems"])[:80]]
                if trusted:
                    fitted = load_rig_file(tmp / "rig.json").parameters
                    stiffness = (fitted.bulk_modulus_pa / fitted.half_volume_m3) \
                        / (rig.bulk_modulus_pa / rig.half_volume_m3)
                    cells += [f"{100 * (fitted.mass_kg / rig.mass_kg - 1):+.1f}",
                              f"{100 * (stiffness - 1):+.1f}",  # beta / V_0: the fit keeps the declared V_0
                              f"{1e3 * (fitted.dead_zone_v - rig.dead_zone_v):+.1f}",
                              f"{1e3 * (fitted.position_latency_s - rig.position_latency_s):+.3f}"]
                else:
                    cells += ["-"] * 4
                for a, f, n in TESTS:
                    parts = [] if trusted else ["-"]
                    for rig_file in ([tmp / "rig.json"] if trusted else []) + [None]:
                        status, share, _verdict = simulate(url, tmp / f"t{a}{f}{rig_file is None}", a, f, n, rig_file)
                        parts.append(f"{100 * share:.3f} %" if status == "completed" and share is not None
                                     else f"{status}")
                    cells.append(" / ".join(parts))
                print("| " + " | ".join(cells) + " |", flush=True)
            finally:
                proc.terminate()
                proc.wait(10)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
