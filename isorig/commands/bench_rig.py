"""`isorig bench-rig`: the real-rig targets, measured against `isorig rig-emulator` in its own process.

1. ``stream``: the service drives the emulator over loopback (``isorig serve --rig udp://...``) for
   ``--duration-s`` (default 600 s) at 1 kHz while ``--clients`` websocket clients (default 10) watch. The
   lateness of the control period is measured where it matters, at the rig: from the moment it sends a
   period's measurement to the moment the host's command for that period arrives (p50, p99, max); a period
   is missed when no command arrived before the rig's next period began. Targets: p99 < 1 ms, fewer than
   0.1 % of periods missed.
2. ``tracking``: the paper's scenarios (IUT_a 100 bar 20 mm, IUT_b 70 bar 30 mm, at 0.5 and 1 Hz, the
   default controller) through the emulator (``isorig simulate --rig``) and on the in-process simulated rig;
   the last two cycles' RMS |y - r| / amplitude of both. Target: within 0.1 % of the amplitude.
3. ``link-drop``: the emulator cuts its link 3 s into a test run by the service: how long after the last
   command the emulator's watchdog closed the valve (target <= 20 ms), and how long after the link timeout
   the test was marked failed in the store (target <= 100 ms); ``--drops`` repetitions.
"""

from __future__ import annotations

import json
import math
import os
import signal
import subprocess
import sys
import tempfile
import time
from datetime import datetime
from functools import partial
from pathlib import Path

from backend.children import end_with_parent

PARTS = ("stream", "tracking", "link-drop", "watchdog")
DEFAULT_PARTS = ("stream", "tracking", "link-drop")  # "watchdog" takes --tests x --test-s: asked for by name
TRACKING_CASES = (("IUT_a", 100.0, 0.02, 0.5), ("IUT_a", 100.0, 0.02, 1.0), ("IUT_b", 70.0, 0.03, 0.5),
                  ("IUT_b", 70.0, 0.03, 1.0))


def register(sub) -> None:
    p = sub.add_parser("bench-rig", help="measure the real-rig targets against `isorig rig-emulator`")
    p.add_argument("--parts", nargs="+", choices=PARTS, default=list(DEFAULT_PARTS),
                   help="what to measure (default: stream tracking link-drop)")
    p.add_argument("--duration-s", type=float, default=600.0, help="length of the streamed test (default 600)")
    p.add_argument("--clients", type=int, default=10, help="websocket clients watching it (default 10)")
    p.add_argument("--cycles", type=int, default=12, help="cycles of each tracking case (default 12)")
    p.add_argument("--drops", type=int, default=3, help="link-drop repetitions (default 3)")
    p.add_argument("--tests", type=int, default=10, help="watchdog: tests run one after another (default 10)")
    p.add_argument("--test-s", type=float, default=60.0, help="watchdog: length of each test in s (default 60)")
    p.add_argument("--cpu-hogs", type=int, default=0,
                   help="CPU-bound processes at normal priority running beside every part (default 0; the "
                        "watchdog target is measured with 2)")
    p.add_argument("--host-priority", choices=("granted", "none"), default="granted",
                   help="watchdog: the host's loop at the real-time priority it is granted (default), or none: run "
                        "without CAP_SYS_NICE, as in a container (SCHED_OTHER, nice 0); the emulator keeps its own")
    p.add_argument("--json", action="store_true", help="print the figures as JSON")
    p.set_defaults(func=run)


class EmulatorProcess:
    """`isorig rig-emulator` on a free port with a status file."""

    def __init__(self, folder: Path, *flags: str, isolator: str = "IUT_a"):
        import re

        self.status_file = folder / f"emulator-{time.monotonic_ns()}.json"
        self.process = subprocess.Popen([sys.executable, "-m", "isorig", "rig-emulator", "--port", "0",
                                         "--isolator", isolator, "--status-file", str(self.status_file), *flags],
                                        stderr=subprocess.PIPE, stdout=subprocess.DEVNULL, text=True)
        match = re.search(r"udp://[\d.]+:(\d+)", self.process.stderr.readline())
        if match is None:
            self.process.kill()
            raise RuntimeError("isorig rig-emulator did not start")
        self.url = f"udp://127.0.0.1:{match.group(1)}"

    def status(self) -> dict:
        time.sleep(0.6)  # rewritten twice a second
        return json.loads(self.status_file.read_text())

    def stop(self) -> dict:
        self.process.terminate()
        self.process.wait(10)
        return json.loads(self.status_file.read_text())


def _stream(folder: Path, duration_s: float, clients: int) -> dict:
    import asyncio

    import httpx

    from .bench_stream import Service, _paced_run

    emulator = EmulatorProcess(folder)
    svc = Service(str(folder), None, rig=emulator.url)
    try:
        with httpx.Client(timeout=30) as http:
            svc.wait_up(http)
            print(f"[stream] {duration_s:g} s at 1 kHz on {emulator.url}, {clients} websocket clients ...",
                  file=sys.stderr)
            result = asyncio.run(_paced_run(svc, http, duration_s, clients))
    finally:
        svc.stop()
        status = emulator.stop()
    counters = status["counters"]
    periods = counters["measurements_sent"] + counters["measurements_dropped"]
    result["rig"] = {"command_latency": status["command_latency"], "periods": periods,
                     "periods_missed": counters["periods_missed"],
                     "missed_share": counters["periods_missed"] / max(periods, 1),
                     "commands_late": counters["commands_late"], "rejected": status["rejected"],
                     "tick_lateness": status["tick_lateness"], "watchdog_trips": status["watchdog_trips"],
                     "overruns": counters.get("overruns", 0)}
    return result


def _tracking(folder: Path, cycles: int) -> list[dict]:
    rows = []
    for isolator, supply_bar, amplitude_m, frequency_hz in TRACKING_CASES:
        args = ["--isolator", isolator, "--supply-bar", str(supply_bar), "--amplitude-m", str(amplitude_m),
                "--frequency-hz", str(frequency_hz), "--cycles", str(cycles)]
        out = {}
        emulator = EmulatorProcess(folder, isolator=isolator)
        print(f"[tracking] {isolator} {supply_bar:g} bar {1e3 * amplitude_m:g} mm {frequency_hz:g} Hz, "
              f"{cycles / frequency_hz:g} s through {emulator.url} ...", file=sys.stderr)
        try:
            for rig in ("simulated", emulator.url):
                target = folder / f"{isolator}-{frequency_hz:g}-{'sim' if rig == 'simulated' else 'udp'}"
                proc = subprocess.run([sys.executable, "-m", "isorig", "simulate", "--rig", rig, "--out", str(target),
                                       *args], capture_output=True, text=True)
                summary = json.loads((target / "summary.json").read_text())
                last = summary.get("last_two_cycles")  # absent when the run ended before its last cycles
                out[rig] = {"exit": proc.returncode, "status": summary.get("status", "completed"),
                            "reason": summary.get("reason"),
                            "rms_last2": last["rms_y_minus_r_over_amplitude"] if last else None,
                            "lost_periods": summary.get("lost_periods", 0)}
        finally:
            emulator.stop()
        sim, udp = out["simulated"], out[emulator.url]
        both = None not in (udp["rms_last2"], sim["rms_last2"])
        rows.append({"isolator": isolator, "supply_bar": supply_bar, "amplitude_m": amplitude_m,
                     "frequency_hz": frequency_hz, "cycles": cycles, "simulated_rms_last2": sim["rms_last2"],
                     "emulator_rms_last2": udp["rms_last2"],
                     "difference": udp["rms_last2"] - sim["rms_last2"] if both else None,
                     "emulator_status": udp["status"], "emulator_reason": udp["reason"],
                     "emulator_lost_periods": udp["lost_periods"]})
    return rows


def _link_drop(folder: Path, drops: int) -> list[dict]:
    import httpx

    from .bench_stream import Service, _create

    rows = []
    for i in range(drops):
        emulator = EmulatorProcess(folder, "--drop-link-after-s", "3")
        svc = Service(str(folder / f"drop-{i}"), None, rig=emulator.url)
        (folder / f"drop-{i}").mkdir(exist_ok=True)
        try:
            with httpx.Client(timeout=30) as http:
                svc.wait_up(http)
                test_id = _create(http, svc, 10, 1.0)
                http.post(f"{svc.base}/api/tests/{test_id}/start",
                          headers={"Authorization": f"Bearer {svc.token}"}).raise_for_status()
                while (record := http.get(f"{svc.base}/api/tests/{test_id}").json())["status"] in ("ready",
                                                                                                  "running"):
                    time.sleep(0.2)
                timeout_s = http.get(f"{svc.base}/api/rig").json()["rig"]["link_timeout_s"]
        finally:
            svc.stop()
        status = emulator.stop()
        fault = next(e for e in record["events"] if e["kind"] == "rig_fault")
        last_wall = fault["values"]["link"]["last_received_wall_s"]
        ended = datetime.fromisoformat(record["ended_at"]).timestamp()
        trips = status["watchdog_trips"]
        rows.append({"test_id": test_id, "status": record["status"], "reason": record["reason"],
                     "valve_zero_after_last_command_ms": trips[0]["after_last_command_ms"] if trips else None,
                     "marked_failed_after_timeout_ms": (ended - last_wall - timeout_s) * 1e3,
                     "samples_kept": record["samples_stored"], "link_timeout_s": timeout_s})
        print(f"[link-drop] {i + 1}/{drops}: {rows[-1]['status']}", file=sys.stderr)
    return rows


def _watchdog(folder: Path, tests: int, test_s: float, host_priority: str = "granted") -> list[dict]:
    """``tests`` tests of ``test_s`` through ``isorig simulate --rig`` on an emulator with the rig's 18 ms
    watchdog: how each ended, the watchdog's trips, the lateness of the host's answers as the rig saw them
    (measurement sent -> command arrived), the periods the rig missed and the host lost, the longest stall
    of the host's answers and, from the loop's period trace (sim.realtime.PeriodTrace), the stalls by cause
    and what ran before the longest. ``host_priority`` "none": the host runs without CAP_SYS_NICE."""
    from sim.realtime import steal_ms_since, steal_s

    rows = []
    frequency_hz = 0.5
    cycles = max(2, int(round(test_s * frequency_hz)))
    for i in range(tests):
        emulator = EmulatorProcess(folder, "--watchdog-ms", "18")
        target = folder / f"watchdog-{i}"
        steal_start = steal_s()
        try:
            proc = subprocess.run([sys.executable, "-m", "isorig", "simulate", "--rig", emulator.url, "--out",
                                   str(target), "--isolator", "IUT_a", "--supply-bar", "100", "--amplitude-m", "0.02",
                                   "--frequency-hz", str(frequency_hz), "--cycles", str(cycles)],
                                  capture_output=True, text=True,
                                  preexec_fn=_without_sys_nice if host_priority == "none" else None)
        finally:
            status = emulator.stop()
        steal_ms = steal_ms_since(steal_start)
        summary_file = target / "summary.json"
        summary = json.loads(summary_file.read_text()) if summary_file.exists() else {}
        counters = status["counters"]
        link = summary.get("link") or {}
        trace = (summary.get("pacing") or {}).get("period_trace") or {}
        longest = (trace.get("longest_stalls") or [None])[0]
        latency = status["command_latency"]  # {"n": 0} when no command arrived (a test that failed at once)
        rows.append({"test": i + 1, "exit": proc.returncode, "status": summary.get("status"),
                     "reason": summary.get("reason"), "watchdog_trips": len(status["watchdog_trips"]),
                     "lateness_p99_ms": latency.get("p99_ms", math.nan),
                     "lateness_max_ms": latency.get("max_ms", math.nan),
                     "load_average": os.getloadavg()[0], "stalls_off_cpu": trace.get("stalls_off_cpu"),
                     "cpu_per_period_p99_ms": (trace.get("ms") or {}).get("cpu", {}).get("p99"),
                     "cpu_per_period_mean_ms": (trace.get("ms") or {}).get("cpu", {}).get("mean"),
                     "periods_missed": counters["periods_missed"], "host_lost_periods": summary.get("lost_periods"),
                     "host_stall_max_ms": link.get("host_stall_max_ms"), "stall_at_fault": link.get("stall_at_fault"),
                     "stalls": trace.get("stalls"),
                     "stall_causes": trace.get("stall_causes"), "longest_stall": longest,
                     "trips_at_s": [trip.get("test_time_s") for trip in status["watchdog_trips"]],
                     "rig_overruns": counters.get("overruns", 0), "rig_ticks_slipped": counters.get("ticks_slipped", 0),
                     "rig_tick_lateness_max_ms":
                         status["tick_lateness"].get("max_ms"),
                     "priority": (summary.get("pacing") or {}).get("priority"),
                     "steal_ms": steal_ms})
        r = rows[-1]
        print(f"[watchdog] {i + 1}/{tests}: {r['status']}, {r['watchdog_trips']} trip(s), p99 "
              f"{r['lateness_p99_ms']:.3f} ms, longest stall {_ms(r['host_stall_max_ms'])} ms "
              f"({_cause(longest)}), {r['host_lost_periods']} period(s) lost; load average "
              f"{r['load_average']:.1f}", file=sys.stderr)
    return rows


def _floor(seconds: float, host_priority: str) -> dict:
    """The machine's floor under the watchdog's tests: a loop that does nothing but wake every 1 ms period
    (sim.realtime.bare_loop), in its own process at the priority the host's loop gets (``host_priority``), beside
    the same CPU hogs, for ``seconds``. What it loses, no change to the control loop's own work can win back."""
    from backend.worker import WORKER_RR_PRIORITY

    code = ("import json, sys\nfrom sim.realtime import bare_loop, raise_priority\n"
            f"granted = raise_priority({WORKER_RR_PRIORITY})\n"
            f"print(json.dumps({{**bare_loop(1e-3, {seconds!r}), 'priority': granted}}))")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=seconds + 60,
                          preexec_fn=_without_sys_nice if host_priority == "none" else _normal_priority)
    if proc.returncode != 0:
        raise RuntimeError(f"the bare loop failed: {proc.stderr.strip()[-400:]}")
    return json.loads(proc.stdout)


def _ms(value) -> str:
    return "-" if value is None else f"{value:.2f}"


def _cause(stall: dict | None) -> str:
    """The longest stall's cause and what ran before it, in a few words."""
    if not stall:
        return "no stall"
    pieces = ", ".join(f"{k} {v:.2f}" for k, v in sorted(stall["pieces_ms"].items(), key=lambda kv: -kv[1])[:2])
    cpu = (f"; the loop's CPU {stall['cpu_ms']:.2f} ms, off its CPU {stall['off_cpu_ms']:.2f} ms"
           if "cpu_ms" in stall else "")
    return f"{stall['cause']}; busy {stall['busy_ms']:.2f} ms ({pieces}), waited {stall['wait_ms']:.2f} ms{cpu}"


def _without_sys_nice() -> None:
    """In the child before exec: CAP_SYS_NICE dropped from the bounding set (so neither SCHED_RR nor a negative
    nice is granted, as in a container without it) and SCHED_OTHER, nice 0."""
    import ctypes

    pr_capbset_drop, cap_sys_nice = 24, 23  # <linux/prctl.h>, <linux/capability.h>
    ctypes.CDLL(None, use_errno=True).prctl(pr_capbset_drop, cap_sys_nice, 0, 0, 0)
    _normal_priority()
    try:
        os.setpriority(os.PRIO_PROCESS, 0, 0)
    except OSError:  # a nice above 0 stays where it is
        pass


class CpuHogs:
    """``n`` CPU-bound processes at normal priority, for as long as the ``with`` lasts."""

    def __init__(self, n: int):
        self.n = n
        self.processes: list[subprocess.Popen] = []

    def __enter__(self) -> CpuHogs:
        code = "import os\nos.setpriority(os.PRIO_PROCESS, 0, 0)\nwhile True: pass"
        self.processes = [subprocess.Popen([sys.executable, "-c", code], start_new_session=True,
                                           preexec_fn=partial(_hog_preexec, os.getpid())) for _ in range(self.n)]
        return self

    def __exit__(self, *_exc) -> None:
        for p in self.processes:
            p.kill()
            p.wait(5)


def _hog_preexec(bench_pid: int) -> None:
    """A hog starts at normal priority and is killed when the bench ends, however it ends (PR_SET_PDEATHSIG,
    backend.children.end_with_parent: a bench killed by a signal left its hogs spinning in their own sessions,
    loading every later measurement)."""
    end_with_parent(bench_pid, signal.SIGKILL)
    _normal_priority()


def _normal_priority() -> None:
    """A child starts at SCHED_OTHER, nice 0, whatever this process was granted."""
    try:
        os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))
    except (AttributeError, OSError):
        pass


def run(args) -> int:
    from isorig.cli import UsageError

    if args.duration_s < 2 or args.clients < 0 or args.cycles < 4 or args.drops < 1:
        raise UsageError("isorig bench-rig: --duration-s >= 2, --clients >= 0, --cycles >= 4, --drops >= 1")
    if args.tests < 1 or args.test_s < 4 or args.cpu_hogs < 0:
        raise UsageError("isorig bench-rig: --tests >= 1, --test-s >= 4, --cpu-hogs >= 0")
    results: dict = {"load_average_start": os.getloadavg(), "cpus": os.cpu_count(), "cpu_hogs": args.cpu_hogs}
    with tempfile.TemporaryDirectory(prefix="isorig-bench-rig-") as tmp, CpuHogs(args.cpu_hogs):
        folder = Path(tmp)
        if "tracking" in args.parts:
            results["tracking"] = _tracking(folder, args.cycles)
        if "link-drop" in args.parts:
            results["link_drop"] = _link_drop(folder, args.drops)
        if "stream" in args.parts:
            results["stream"] = _stream(folder, args.duration_s, args.clients)
        if "watchdog" in args.parts:
            print(f"[floor] a loop that does nothing, {args.test_s:g} s ...", file=sys.stderr)
            results["floor"] = _floor(args.test_s, args.host_priority)
            results["watchdog"] = _watchdog(folder, args.tests, args.test_s, args.host_priority)
            results["host_priority"] = args.host_priority
    results["load_average_end"] = os.getloadavg()
    if args.json:
        print(json.dumps(results, indent=2))
        return 0
    _print(results)
    return 0


def _print(results: dict) -> None:
    if "watchdog" in results:
        rows = results["watchdog"]
        print(f"[watchdog] {len(rows)} tests on an 18 ms rig watchdog, {results['cpu_hogs']} CPU hog(s) beside "
              "[target: 0 trips, p99 lateness < 1 ms]")
        print("  test  status      trips  p99 ms  max ms  rig missed  host lost  stalls  longest stall ms  load  "
              "steal ms  priority")
        for r in rows:
            print(f"  {r['test']:>4}  {str(r['status']):10s}  {r['watchdog_trips']:>5}  {r['lateness_p99_ms']:>6.3f}"
                  f"  {r['lateness_max_ms']:>6.2f}  {r['periods_missed']:>10}  {str(r['host_lost_periods']):>9}"
                  f"  {str(r.get('stalls')):>6}  {_ms(r['host_stall_max_ms']):>16}  {r.get('load_average', 0):4.1f}"
                  f"  {_ms(r.get('steal_ms')):>8}  {r['priority']}")
        for r in rows:
            print(f"  test {r['test']}: longest stall {_ms(r['host_stall_max_ms'])} ms: "
                  f"{_cause(r.get('longest_stall'))}"
                  f"; stalls by cause {r.get('stall_causes') or {}}, {r.get('stalls_off_cpu')} with the loop off its "
                  f"CPU longer than it computed; its CPU per period mean {r.get('cpu_per_period_mean_ms')} ms, p99 "
                  f"{r.get('cpu_per_period_p99_ms')} ms; the rig's "
                  f"own overruns {r.get('rig_overruns')}, ticks slipped {r.get('rig_ticks_slipped')} "
                  f"(its longest tick lateness {_ms(r.get('rig_tick_lateness_max_ms'))} ms)")
            if r["watchdog_trips"] or r["status"] != "completed":
                print(f"  test {r['test']}: {r['status']} ({r['reason']}); the rig's watchdog tripped at t = "
                      f"{', '.join(f'{t:.3f}' for t in r.get('trips_at_s') or [])} s")
                fatal = r.get("stall_at_fault")
                if fatal:  # the stall that ended it: no later command measured it
                    print(f"  test {r['test']}: the stall that ended it: {fatal['after_last_command_ms']:.2f} ms after "
                          f"the last command; the loop's work before it waited {fatal['busy_ms']:.2f} ms (CPU "
                          f"{fatal['cpu_ms']:.2f} ms, off its CPU {fatal['busy_off_cpu_ms']:.2f} ms)")
        trips = sum(r["watchdog_trips"] for r in rows)
        worst = max((r["lateness_p99_ms"] for r in rows if not math.isnan(r["lateness_p99_ms"])), default=math.nan)
        stalls = [r["host_stall_max_ms"] for r in rows if r["host_stall_max_ms"] is not None]
        lost = sum(r["host_lost_periods"] or 0 for r in rows)
        missed = sum(r["periods_missed"] for r in rows)
        print(f"  total: {trips} watchdog trip(s); worst p99 lateness {worst:.3f} ms; longest stall "
              f"{_ms(max(stalls) if stalls else None)} ms [target: no period lost]: {lost} period(s) lost by the host, "
              f"{missed} missed by the rig; host priority {results.get('host_priority', 'granted')}")
    if "floor" in results:
        f = results["floor"]
        print(f"[floor] a loop that does nothing but wake every 1 ms, at the host's priority ({f['priority']}) beside "
              f"the same hogs, {f['seconds']:g} s: wake lateness p99 {f['lateness_p99_ms']:.3f} ms, max "
              f"{f['lateness_max_ms']:.2f} ms; {f['stalls']} stall(s), longest {f['stall_max_ms']:.2f} ms, "
              f"{f['lost_periods']} period(s) lost; the machine's steal time {_ms(f['steal_ms'])} ms (what the control "
              "loop cannot do better than)")
    if "tracking" in results:
        print("[tracking] last two cycles' RMS |y - r| / amplitude, default controller  [target: within 0.1 %]")
        print("  case                          simulated   emulator   difference  status")
        for r in results["tracking"]:
            case = f"{r['isolator']} {r['supply_bar']:g} bar {1e3 * r['amplitude_m']:g} mm {r['frequency_hz']:g} Hz"
            if r["difference"] is None:
                print(f"  {case:28s}  no figure: the emulator run ended {r['emulator_status']} "
                      f"({r['emulator_reason']})")
                continue
            print(f"  {case:28s}  {100 * r['simulated_rms_last2']:8.3f} %  {100 * r['emulator_rms_last2']:8.3f} %"
                  f"  {100 * r['difference']:+9.3f} %  {r['emulator_status']}, "
                  f"{r['emulator_lost_periods']} lost")
    for r in results.get("link_drop", []):
        print(f"[link-drop] test {r['test_id']} {r['status']} ({r['samples_kept']} samples kept): valve 0 V at the "
              f"emulator {r['valve_zero_after_last_command_ms']:.1f} ms after the last command [target <= 20 ms]; "
              f"marked failed {r['marked_failed_after_timeout_ms']:.0f} ms after the {1e3 * r['link_timeout_s']:g} ms "
              "timeout [target <= 100 ms]")
    if "stream" in results:
        s = results["stream"]
        rig = s["rig"]
        lat = rig["command_latency"]
        print(f"[stream] test {s['test_id']} {s['status']}, {s['test_time_s']:.1f} s at 1 kHz, {s['clients']} "
              "websocket clients watching" + (f"; reason: {s['reason']}" if s.get("reason") else ""))
        for message in s.get("events", []):
            print(f"  event: {message}")
        tick = s["rig"]["tick_lateness"]
        print(f"  the rig's own ticks: lateness p99 {tick.get('p99_ms', float('nan')):.2f} ms, max "
              f"{tick.get('max_ms', float('nan')):.2f} ms; overruns {s['rig'].get('overruns', 0)}")
        trips = s["rig"].get("watchdog_trips") or []
        for trip in trips:
            print(f"  the rig's watchdog tripped at t = {trip['test_time_s']:.3f} s, "
                  f"{trip['after_last_command_ms']:.1f} ms after the last command")
        print(f"  lateness of the control period at the rig (measurement sent -> command arrived): p50 "
              f"{lat['p50_ms']:.2f} ms, p99 {lat['p99_ms']:.2f} ms, max {lat['max_ms']:.2f} ms over {lat['n']} "
              "periods  [target p99 < 1 ms]")
        print(f"  periods missed (no command before the rig's next period): {rig['periods_missed']} of "
              f"{rig['periods']} ({100 * rig['missed_share']:.3f} %)  [target < 0.1 %]; late commands applied "
              f"{rig['commands_late']}; rejected {rig['rejected'] or 0}")
        link = s["pacing"]
        lat_c = s["latency"]
        if lat_c.get("n"):
            print(f"  sample-to-client latency p95 {lat_c['p95_ms']:.1f} ms; samples per client "
                  f"{min(s['samples_per_client'])}-{max(s['samples_per_client'])} of {s['samples_stored']}; "
                  f"worker {link.get('priority', '?')}")
    print(f"machine: {results['cpus']} CPUs, load average {results['load_average_start'][0]:.1f} at start, "
          f"{results['load_average_end'][0]:.1f} at end")
