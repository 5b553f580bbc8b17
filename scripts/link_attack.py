"""The rig-link attack target of issue 21, measured over several runs: under every attack of
tests/backend/test_rig_link_auth.py (a process without the key, sniffing the link, forging from the rig's and the
host's addresses, replaying, flooding), the test completes with tracking within 0.1 % of the amplitude of a run
nobody attacked, and every forged packet is counted.

Each run: an emulator (``isorig rig-emulator --rig-key-file ... --tap-port ...``) and ``isorig simulate --rig ...``
as processes of their own; a run nobody attacks, then one under attack (IUT_a, 100 bar, 10 mm at 2 Hz, 8 cycles).
Prints per run the RMS tracking of both, their difference in % of the amplitude, the largest command the rig applied
against the largest the host sent, and the commands the rig missed (a loaded machine's timing, not the attack's).
Exit code 0 if every run meets the target.

With ``--flood`` it measures issue 33 item 2 instead: a keyless HELLO flood from another process (1 000 and 10 000
a second; 10 000 from 200 sockets, more than the rig's table of sources holds, so every datagram's tag is checked)
while 10 starts are made and a short test runs (tests/backend/test_hello_flood.py). Prints per flood the starts that
succeeded, the probe's round trip under the flood, the tracking against a run without it, the rig emulator's share of
a CPU idle without and with the flood, and what the rig dropped. ``--protocol 1``: the same without a key.

Run: .venv/bin/python scripts/link_attack.py [--runs 5]
     .venv/bin/python scripts/link_attack.py --flood [--runs 1] [--protocol 1]
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT), str(ROOT / "tests" / "backend")]

from test_hello_flood import flood_figures  # noqa: E402
from test_rig_link_auth import attack_figures  # noqa: E402

TARGET_PCT = 0.1
FLOODS = ((1000, 1), (10_000, 1), (10_000, 200))  # (HELLOs a second, sockets)


def floods(runs: int, protocol: int) -> int:
    """The flood figures (``--flood``); exit code 0 if every start succeeded and every test tracked as without."""
    print(f"load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} CPUs; rig protocol {protocol}; a keyless HELLO "
          "flood from another process; 10 starts and a 2-cycle test (10 mm, 2 Hz) under it")
    print(f"{'flood /s':>8} {'socks':>5} {'sent /s':>7} {'starts':>6} {'probe ms med/max':>16} {'rms base um':>11} "
          f"{'rms flood um':>12} {'diff %':>6} {'rig CPU % idle/flood':>20}  rig dropped")
    good = True
    for _ in range(runs):
        for rate, sockets in FLOODS:
            with tempfile.TemporaryDirectory(prefix="isorig-flood-") as tmp:
                f = flood_figures(Path(tmp), rate, sockets, protocol, cpu_window_s=2.0)
            rtt, cpu = f["probe_round_trip_ms"], f["rig_cpu"]
            diff = f["difference_pct_of_amplitude"]
            good &= f["starts_ok"] == f["starts"] and diff is not None and diff <= 0.5
            print(f"{rate:>8} {sockets:>5} {f['flood_rate_per_s']:>7.0f} {f['starts_ok']:>3}/{f['starts']:<2} "
                  f"{rtt['median'] or 0:>8.2f}/{rtt['max'] or 0:<7.2f} {f['rms_base_m'] * 1e6:>11.2f} "
                  f"{(f['rms_flooded_m'] or 0) * 1e6:>12.2f} {diff if diff is not None else float('nan'):>6.3f} "
                  f"{cpu['idle_pct']:>9.1f}/{cpu['flooded_pct']:<10.1f}  {f['rig_rejected']}", flush=True)
            for failure in f["failures"][:3]:
                print(f"    start failed: {failure}")
    return 0 if good else 1


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--runs", type=int, help="pairs of runs (unattacked, attacked), default 5; with --flood: "
                        "rounds of the floods, default 1")
    parser.add_argument("--flood", action="store_true", help="measure the HELLO floods of issue 33 instead")
    parser.add_argument("--protocol", type=int, choices=(1, 2), default=2, help="with --flood: the rig protocol")
    args = parser.parse_args()
    if args.runs is None:
        args.runs = 1 if args.flood else 5
    if args.runs < 1:
        parser.error(f"--runs {args.runs}: at least 1")
    if args.flood:
        return floods(args.runs, args.protocol)
    print(f"load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} CPUs; target: within {TARGET_PCT} % "
          "of the amplitude (10 mm)")
    print(f"{'run':>3} {'rms unattacked um':>18} {'rms attacked um':>16} {'diff % ampl':>11} "
          f"{'rig max V':>9} {'host max V':>10} {'missed (base, attacked)':>24}")
    differences = []
    for run in range(1, args.runs + 1):
        with tempfile.TemporaryDirectory(prefix="isorig-attack-") as tmp:
            f = attack_figures(Path(tmp))
        differences.append(f["difference_pct_of_amplitude"])
        print(f"{run:>3} {f['rms_unattacked_m'] * 1e6:>18.2f} {f['rms_attacked_m'] * 1e6:>16.2f} "
              f"{f['difference_pct_of_amplitude']:>11.3f} {f['rig_applied_max_abs_v']:>9.3f} "
              f"{f['host_sent_max_abs_v']:>10.3f} {str(f['rig_commands_missed']):>24}", flush=True)
    met = sum(d <= TARGET_PCT for d in differences)
    print(f"within {TARGET_PCT} %: {met} of {len(differences)} runs; largest difference {max(differences):.3f} %")
    return 0 if met == len(differences) else 1


if __name__ == "__main__":
    sys.exit(main())
