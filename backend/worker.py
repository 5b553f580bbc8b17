"""The rig worker: runs one test in its own process, paced to the wall clock, and reports over a pipe.

The server starts ``main(job, out, commands)`` in a separate process (forkserver or spawn, never fork from
the threaded server). The worker arms the rig driver, closes the controller around it in chunks of
``CHUNK_S`` of wall time (20 ms: 20 control periods at speed 1, ``speed`` times more when a simulated test
runs accelerated), checks every ``CHECK_PERIODS`` periods against the safety limits and for an operator
command, sleeps until each
chunk's wall-clock deadline and then sends the chunk's samples. It never touches the database: the server
stores and streams what it sends, so a crash here loses nothing that was sent.

Messages to the server (tuples): ``("started", {...})``, ``("samples", rows)`` (engine COLUMNS layout),
``("cycle", {...})``, ``("event", {...})``, ``("finished", {"status", "reason", "pacing"})``.
Commands from the server: ``"stop"`` (ramp-out: the sine tapers to zero over ``taper_cycles``, at least
one cycle, then ``stopped``) and ``"abort"`` (at once: valve command zero, ``aborted``).
"""

from __future__ import annotations

import math
import os
import queue
import sys
import threading
import time

import numpy as np

from sim.engine import C_FORCE, C_Y, CONTROL_PERIOD_S, Scenario
from sim.isolator import isolator_from_dict
from sim.profiles import B_CYCLES, B_FREQUENCY, B_START, B_TAPER, SineProfile
from sim.tracking import cycle_windows

from .drivers import RigDriver, make_driver
from .safety import COMMAND_RAMP_S, SafetyLimits, Trip, check_block, command_ramp

try:  # per-cycle loop metrics (sim/metrics.py)
    from sim.metrics import loop_metrics
except ImportError:  # pragma: no cover - only while sim/metrics.py did not exist
    loop_metrics = None

CHUNK_S = 0.02  # wall time per chunk: samples reach clients at most this much after they are due
CHECK_PERIODS = 10  # safety detectors run every 10 control periods (10 ms of test time)
GIL_SWITCH_INTERVAL_S = 0.0005  # CPython's default is 5 ms, longer than the 2 ms lateness budget
SPIN_S = 0.001  # the pacer sleeps until this long before a chunk is due, then polls the clock (~5 % of one CPU)
LOOP_POINTS_MAX = 2000  # points of a cycle's loop sent and stored (decimated beyond this)


class ServerGone(Exception):
    """The pipe to the server broke: the server died; the worker makes the rig safe and exits."""


class Outbox:
    """Sends messages to the server from a thread, so a busy or stalled server never blocks the control loop.

    A pipe holds only ~64 KB: if the server stops reading, a direct ``send`` would block the loop within a
    second. Here the loop only queues (memory grows by ~0.1 MB per second of a stalled server) and the
    thread drains the queue into the pipe.
    """

    def __init__(self, conn):
        self.conn = conn
        self.queue: queue.SimpleQueue = queue.SimpleQueue()
        self.broken = False
        self.thread = threading.Thread(target=self._drain, daemon=True, name="isorig-worker-outbox")
        self.thread.start()

    def send(self, message) -> None:
        if self.broken:
            raise ServerGone()
        self.queue.put(message)

    def _drain(self) -> None:
        while True:
            message = self.queue.get()
            if message is None:
                return
            try:
                self.conn.send(message)
            except (BrokenPipeError, ConnectionResetError, EOFError, OSError):
                self.broken = True
                return

    def close(self, timeout_s: float = 30.0) -> None:
        """Send what is queued (up to ``timeout_s``), then stop the thread."""
        self.queue.put(None)
        self.thread.join(timeout_s)


def scenario_from_job(job: dict) -> Scenario:
    spec = job["scenario"]
    blocks = [SineProfile(b["amplitude_m"], b["frequency_hz"], int(b["cycles"]), int(b["taper_cycles"]),
                          b.get("offset_m", 0.0)) for b in spec["profile"]]
    return Scenario(isolator_from_dict(spec["isolator"]), spec["supply_pa"], blocks, spec["controller"],
                    dict(spec.get("controller_options") or {}))


def ramp_out_profile(blocks: np.ndarray, t_now_s: float, dt_s: float = CONTROL_PERIOD_S):
    """The packed profile with the running sine block ending smoothly from now, and the new end period.

    The block's cycle count is cut to the first whole cycle at least one taper (>= 1 cycle) after now (or
    kept, if the block is already tapering out), and later blocks are dropped; the raised-cosine taper-out
    of sim.profiles does the rest, so the target and its rate stay continuous. Returns ``(blocks, total_periods)``.
    """
    for i in range(blocks.shape[0]):
        f = blocks[i, B_FREQUENCY]
        end = blocks[i, B_START] + blocks[i, B_CYCLES] / f
        if t_now_s < end:
            tau = (t_now_s - blocks[i, B_START]) * f
            taper = blocks[i, B_TAPER]
            if taper < 1.0 and tau >= 1.0:
                taper = 1.0  # an untapered block still ramps out over one cycle
            cycles = math.ceil(tau + max(taper, 1.0) - 1e-9)
            if cycles >= blocks[i, B_CYCLES]:  # already inside this block's own taper-out: finish it
                cycles, taper = blocks[i, B_CYCLES], blocks[i, B_TAPER]
            new = blocks[: i + 1].copy()
            new[i, B_CYCLES] = cycles
            new[i, B_TAPER] = taper
            return new, int(round((blocks[i, B_START] + cycles / f) / dt_s))
    total = int(round((blocks[-1, B_START] + blocks[-1, B_CYCLES] / blocks[-1, B_FREQUENCY]) / dt_s))
    return blocks, total


class Pacer:
    """Waits until each chunk is due on the wall clock; records how late every release was.

    It sleeps until ``spin_s`` before the deadline and polls the clock from there: the OS's wake-up delay
    (usually tenths of a millisecond, a few milliseconds at times on a shared machine or VM) then falls
    before the deadline instead of after it, unless it exceeds ``spin_s``.
    """

    def __init__(self, speed: float, spin_s: float = SPIN_S):
        self.speed = speed
        self.spin_s = spin_s
        self.t0 = time.perf_counter()
        self.wall_t0 = time.time()
        self.lateness_s: list[float] = []

    def wait_until(self, test_time_s: float) -> None:
        due = self.t0 + test_time_s / self.speed
        now = time.perf_counter()
        if due - now > self.spin_s:
            time.sleep(due - now - self.spin_s)
        while now < due:
            now = time.perf_counter()
        self.lateness_s.append(max(0.0, now - due))

    def stats(self) -> dict:
        late = np.array(self.lateness_s) * 1e3
        if late.size == 0:
            return {"chunks": 0, "speed": self.speed}
        return {"chunks": int(late.size), "speed": self.speed, "chunk_s": CHUNK_S,
                "lateness_p50_ms": float(np.percentile(late, 50)), "lateness_p99_ms": float(np.percentile(late, 99)),
                "lateness_max_ms": float(late.max()), "late_over_2ms": int(np.sum(late > 2.0))}


class Run:
    """One test on one driver; ``execute`` returns the final (status, reason)."""

    def __init__(self, job: dict, out, commands, driver: RigDriver | None = None):
        self.job = job
        self.out = out
        self.commands = commands
        self.scenario = scenario_from_job(job)
        self.limits = SafetyLimits(**job["limits"])
        self.speed = float(job.get("speed", 1.0))
        self.driver = driver or make_driver(job.get("driver", "simulated"))
        if self.speed != 1.0 and not self.driver.can_accelerate:
            raise ValueError(f"the {self.driver.name} rig runs in real time only (speed = {self.speed:g})")
        self.windows = cycle_windows(self.scenario)
        self.next_window = 0
        self.pending = np.empty((0, 0))
        self.pending_start = 0
        self.pacer: Pacer | None = None
        self.stopping = False
        self.priority = "normal"

    # --- messages ------------------------------------------------------------------------------------
    def send(self, kind: str, payload) -> None:
        self.out.send((kind, payload))

    def event(self, kind: str, message: str, values: dict | None = None) -> None:
        self.send("event", {"kind": kind, "message": message, "values": values or {},
                            "time_s": self.driver.time_s})

    def poll_command(self) -> str | None:
        try:
            if self.commands.poll():
                return self.commands.recv()
        except (EOFError, OSError) as exc:
            raise ServerGone() from exc
        return None

    # --- cycles --------------------------------------------------------------------------------------
    def collect_cycles(self, rows: np.ndarray) -> None:
        self.pending = rows if self.pending.size == 0 else np.concatenate([self.pending, rows])
        while self.next_window < len(self.windows):
            block, i0, i1, _f = self.windows[self.next_window]
            if i1 > self.driver.period:
                break
            seg = self.pending[i0 - self.pending_start: i1 - self.pending_start]
            self.next_window += 1
            if seg.shape[0] >= 2:
                self.send_cycle(self.next_window, block, seg)
            drop = i1 - self.pending_start
            self.pending = self.pending[drop:]
            self.pending_start = i1

    def send_cycle(self, number: int, block: int, seg: np.ndarray) -> None:
        d, f = seg[:, C_Y], seg[:, C_FORCE]
        metrics = {}
        if loop_metrics is not None:
            try:
                metrics = loop_metrics(d, f)
            except ValueError as exc:  # non-finite samples: no metrics for this cycle
                metrics = {"error": str(exc)}
        step = max(1, math.ceil(len(d) / LOOP_POINTS_MAX))
        self.send("cycle", {"cycle": number, "block": block, "t_start_s": float(seg[0, 0]),
                            "t_end_s": float(seg[-1, 0] + CONTROL_PERIOD_S), "metrics": metrics,
                            "displacement_m": d[::step].copy(), "force_n": f[::step].copy()})

    # --- the loop ------------------------------------------------------------------------------------
    def execute(self) -> tuple[str, str | None]:
        driver = self.driver
        driver.arm(self.scenario)
        chunk = max(1, round(CHUNK_S * self.speed / CONTROL_PERIOD_S))
        self.pacer = Pacer(self.speed)
        self.send("started", {"wall_t0": self.pacer.wall_t0, "chunk_periods": chunk,
                              "total_periods": driver.total_periods, "priority": self.priority})
        try:
            command = None
            while not driver.done:
                if command == "abort":
                    driver.write_valve_command(0.0)
                    self.event("operator", f"abort at t = {driver.time_s:.3f} s: valve command set to zero at once",
                               {"action": "abort"})
                    return "aborted", f"operator abort at t = {driver.time_s:.3f} s"
                if command == "stop" and not self.stopping:
                    self.stopping = True
                    blocks, total = ramp_out_profile(driver.blocks, driver.time_s)
                    driver.set_profile(blocks, min(total, driver.total_periods))
                    self.windows = [w for w in self.windows if w[2] <= driver.total_periods]
                    self.event("operator", f"stop at t = {driver.time_s:.3f} s: ramping out, ends at "
                               f"t = {driver.total_periods * CONTROL_PERIOD_S:.3f} s",
                               {"action": "stop", "ends_at_s": driver.total_periods * CONTROL_PERIOD_S})
                rows, trip, command = self.closed_loop_chunk(chunk)
                self.release(rows)
                if trip is not None:
                    return self.controlled_stop(trip)
            if self.stopping:
                return "stopped", f"operator stop; ramped out to t = {driver.time_s:.3f} s"
            return "completed", None
        finally:
            driver.disarm()

    def closed_loop_chunk(self, n: int) -> tuple[np.ndarray, Trip | None, str | None]:
        """Up to n periods in blocks of CHECK_PERIODS; stops early at a trip or an operator command."""
        driver = self.driver
        parts = []
        trip = command = None
        done = 0
        while done < n and not driver.done:
            m = min(CHECK_PERIODS, n - done)
            block = driver.run_closed_loop(m)
            parts.append(block)
            done += block.shape[0]
            trip = check_block(block, self.limits)
            fault = driver.fault()
            if trip is None and fault is not None:
                trip = Trip("non_finite", block.shape[0] - 1, driver.time_s, f"{fault} at t = {driver.time_s:.3f} s",
                            {"time_s": driver.time_s})
            if trip is not None or block.shape[0] < m:
                break
            command = self.poll_command()
            if command is not None:
                break
        rows = np.concatenate(parts) if parts else np.empty((0, 0))
        return rows, trip, command

    def release(self, rows: np.ndarray) -> None:
        if rows.size == 0:
            return
        self.pacer.wait_until(self.driver.time_s)
        self.send("samples", rows)
        self.collect_cycles(rows)

    def controlled_stop(self, trip: Trip) -> tuple[str, str]:
        """A limit trip: record it, ramp the valve command to zero (open loop), end ``aborted``."""
        driver = self.driver
        self.event("limit_trip", trip.message, {"detector": trip.detector, **trip.values})
        ramp = command_ramp(driver.last_command_v, COMMAND_RAMP_S, CONTROL_PERIOD_S)
        chunk = max(1, round(CHUNK_S * self.speed / CONTROL_PERIOD_S))
        for i0 in range(0, len(ramp), chunk):
            parts = []
            for u in ramp[i0: i0 + chunk]:
                driver.write_valve_command(float(u))
                parts.append(driver.step(1))
            rows = np.concatenate(parts)
            self.pacer.wait_until(driver.time_s)
            self.send("samples", rows)
        return "aborted", trip.message


def raise_priority() -> str:
    """Ask the OS to schedule the control loop ahead of ordinary processes, as far as it allows.

    Round-robin real-time priority if permitted (root or CAP_SYS_NICE), else a lower nice value, else
    nothing. The loop sleeps between chunks, so a real-time priority cannot starve the machine.
    """
    try:
        os.sched_setscheduler(0, os.SCHED_RR, os.sched_param(10))
        return "SCHED_RR 10"
    except (AttributeError, OSError):
        pass
    try:
        os.nice(-10)
        return "nice -10"
    except OSError:
        return "normal"


def main(job: dict, out, commands) -> None:
    """Process entry point: run the job, always end with a ``finished`` message if the server is there."""
    run = None
    # Priority first: threads inherit it, so the outbox thread cannot hold the GIL at a lower priority while
    # the real-time control thread waits for it (a priority inversion). A short GIL switch interval lets
    # the control thread take the GIL back within 0.5 ms when it wakes.
    priority = raise_priority() if job.get("realtime", True) else "normal"
    sys.setswitchinterval(GIL_SWITCH_INTERVAL_S)
    outbox = Outbox(out)
    try:
        run = Run(job, outbox, commands)
        run.priority = priority
        status, reason = run.execute()
        run.send("finished", {"status": status, "reason": reason,
                              "pacing": {**run.pacer.stats(), "priority": run.priority}})
    except ServerGone:
        return
    except Exception as exc:  # report any failure to the server instead of dying silently
        pacing = run.pacer.stats() if run is not None and run.pacer is not None else {}
        try:
            outbox.send(("finished", {"status": "failed", "reason": f"worker error: {type(exc).__name__}: {exc}",
                                      "pacing": pacing}))
        except ServerGone:
            pass
    finally:
        outbox.close()
        try:
            out.close()
        except OSError:
            pass
