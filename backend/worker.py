"""The rig worker: runs one test in its own process, in real time, and reports over a pipe.

The server starts ``main(job, out, commands)`` in a separate process (forkserver or spawn, never fork from
the threaded server). The worker builds the test's closed loop (sim.loop) and the rig driver
(backend.drivers), arms the rig and runs the loop in chunks of ``CHUNK_S`` of wall time (20 control periods
at speed 1; ``speed`` times more when a simulated test runs accelerated). Every ``CHECK_PERIODS`` periods it
checks the safety detectors and polls for an operator command. A driver that paces itself (real hardware)
sets the rhythm by blocking until its next period; a simulated rig is paced here to the wall clock. It
never touches the database: the server stores and streams what it sends, so a crash here loses nothing
that was sent.

After ARM and before the test's clock starts, the worker answers every measurement with 0 V until the
measured supply pressure reaches ``SUPPLY_SETTLE_FRACTION`` of the asked one (a real pump needs time to reach
a new set point; the simulated rig is there at once), at most ``SUPPLY_SETTLE_TIMEOUT_S``
(``Run.settle_supply``); only then does period 0 of the loop run, and the supply-loss detector judge.

Every way a test ends closes the valve and says why: completed; ``stop`` (the operator: the target ramps
out, then ``stopped``); a limit trip (the command ramps to zero open loop, ``aborted``); ``abort`` (0 V at
once, ``aborted``); a rig fault, a lost link or a supply that did not come up after ARM (``failed``: the rig's
own watchdog closes the valve when the link is gone); an error in the worker (``failed``). The driver is
disarmed on every path.

Messages to the server (tuples): ``("started", {...})``, ``("samples", rows)`` (an (n, len(SAMPLE_FIELDS))
array, sim.samples), ``("hybrid", {...})`` (a hybrid test, just before each chunk's samples: ``monitor``, the
stability monitor at the chunk's end, sim.hybrid_metrics.EnergyMonitor.to_dict(); ``columns`` and ``rows``,
the structure's channels for the chunk's periods, sim.structure.channel_names; ``time_s``),
``("cycle", {...})`` (the loop of a completed cycle; the service adds its metrics),
``("event", {...})``, ``("link", stats)``, ``("finished", {"status", "reason", "pacing", "link", "lost_periods"})``.
Commands from the server: ``"stop"`` and ``"abort"``.
"""

from __future__ import annotations

import dataclasses
import math
import queue
import signal
import sys
import threading
import time
from collections import deque
from contextlib import nullcontext
from functools import partial

import numpy as np

from sim.controllers import make_controller
from sim.detectors import follow_monitor, guard_trip
from sim.engine import Scenario
from sim.follow import commissioning_facts
from sim.isolator import isolator_from_dict
from sim.loop import CONTROL_PERIOD_S, ClosedLoop
from sim.measurement import RIG_FAULT_BITS, Measurement, describe_status, measured_rows
from sim.profiles import B_CYCLES, B_TAPER, blocks_from_dicts
from sim.realtime import PeriodTrace, RealtimeSection, raise_priority, realtime_priority
from sim.rig import DEFAULT_RIG
from sim.samples import Samples
from sim.tracking import cycle_phase, cycle_windows

from .drivers import SIMULATED, ArmConditions, RigDriver, RigFault, SimulatedRig
from .drivers.udp import START_TOLERANCE_M
from .safety import FOLLOW_KEY, SafetyLimits, SafetyMonitor, Trip, follow_trip

CHUNK_S = 0.02  # wall time per chunk: samples reach clients at most this much after they are due
WORKER_RR_PRIORITY = 10  # below the rig emulator's 20 when both run on one machine
CHECK_PERIODS = 10  # safety detectors run every 10 control periods (10 ms of test time)
GIL_SWITCH_INTERVAL_S = 0.0005  # CPython's default is 5 ms, longer than the 2 ms lateness budget
SPIN_S = 0.001  # the pacer sleeps until this long before a chunk is due, then polls the clock (~5 % of one CPU)
LINK_REPORT_S = 0.25  # test time between link-health messages of a driver with a link
#: after ARM the test's clock starts once the measured supply pressure is this share of the asked one ...
SUPPLY_SETTLE_FRACTION = 0.9
#: ... or the run ends before any motion when it is not within this long of ARM (the job's
#: ``supply_settle_timeout_s`` overrides it). A real pump reaches its set point within a second or two.
SUPPLY_SETTLE_TIMEOUT_S = 5.0


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
    """The test's scenario; a manual motion (spec["motion"]: start_m, end_m, speed_m_per_s) runs as a time
    history (sim.motion); an earthquake profile (spec["earthquake"]: the API's history or hybrid form, as
    asked) is rebuilt from its spec (sim.earthquake, deterministic) and checked against the fingerprint taken
    when the test was created (spec["earthquake_fingerprint"])."""
    spec = job["scenario"]
    history = spec.get("history_target")
    motion = spec.get("motion")
    if motion is not None:
        from sim.motion import move_target

        history = move_target(motion["start_m"], motion["end_m"], motion["speed_m_per_s"])
    isolator = isolator_from_dict(spec["isolator"])
    if spec.get("earthquake") is not None:
        history = earthquake_from_job(job, isolator).target
    rig = DEFAULT_RIG.with_changes(**spec["rig_changes"]) if spec.get("rig_changes") else DEFAULT_RIG
    return Scenario(isolator, spec["supply_pa"], blocks_from_dicts(spec["profile"]),
                    spec["controller"],
                    dict(spec.get("controller_options") or {}), rig=rig, vertical_load_n=spec.get("vertical_load_n"),
                    history=history, plant_changes=dict(spec.get("plant_changes") or {}),
                    rig_commissioning=commissioning_facts(spec.get("rig_commissioning")))


def earthquake_from_job(job: dict, isolator=None):
    """The earthquake profile of a job's scenario (sim.earthquake.EarthquakeProfile), rebuilt from the spec the
    test was created with; a target that differs from the one checked then (another numerical library?) is
    refused: nothing moves on a target that was not checked."""
    from sim.earthquake import earthquake_from_spec

    spec = job["scenario"]
    isolator = isolator or isolator_from_dict(spec["isolator"])
    profile = earthquake_from_spec(spec["earthquake"], isolator, spec.get("vertical_load_n"))
    expected = spec.get("earthquake_fingerprint")
    if expected and profile.fingerprint != expected:
        raise ValueError("the earthquake target rebuilt from the test's request differs from the one checked "
                         "against the envelope when the test was created; create the test again")
    return profile


def make_driver(rig: str, scenario: Scenario, link: dict | None = None, table_position_m: float = 0.0) -> RigDriver:
    """The driver of a rig named ``simulated`` or ``udp://HOST:PORT`` (with the link settings ``link``).

    The simulated rig is built with the test's isolator mounted, as a real rig has its specimen mounted, and
    its table where the last test left it (``table_position_m``); no driver receives the isolator through
    the protocol. It is the scenario's plant: the rig the controller is told of, with the plant's changes (a
    simulated lab rig that differs from its rig file, ``plant_changes``).
    """
    if rig == SIMULATED:
        return SimulatedRig(scenario.plant_isolator, scenario.plant_rig, scenario.noise_seed, table_position_m)
    from .drivers.udp import UdpRig

    return UdpRig.from_url(rig, **(link or {}))


def hybrid_from_job(job: dict, scenario: Scenario):
    """The numerical substructure of a hybrid test, or None: from the job's earthquake profile of kind hybrid
    (a service test: building, ground motion and stability monitor rebuilt from the spec) or from job["hybrid"]
    (the command line: the building as a dict and the ground acceleration at every control period)."""
    eq_spec = job["scenario"].get("earthquake")
    if isinstance(eq_spec, dict) and eq_spec.get("kind") == "hybrid":
        return earthquake_from_job(job, scenario.isolator).substructure(scenario.isolator)
    spec = job.get("hybrid")
    if not spec:
        return None
    from sim.hybrid import HybridSubstructure
    from sim.structure import ShearBuilding

    return HybridSubstructure(ShearBuilding.from_dict(spec["building"]), scenario.isolator,
                              spec["ground_acc_m_per_s2"])


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
        self.speed = float(job.get("speed", 1.0))
        self.driver = driver or make_driver(job.get("rig", SIMULATED), self.scenario, job.get("link"),
                                            job.get("table_position_m") or 0.0)
        self.motion = job["scenario"].get("motion") is not None  # a manual move: a stop holds where it is
        self.move_guard = self.new_move_guard() if self.motion else None  # a table that runs away from it stops
        self.rig = self.driver.describe()
        if abs(self.rig.control_period_s - CONTROL_PERIOD_S) > 1e-9:
            raise ValueError(f"the rig {self.rig.name!r} runs at a control period of {self.rig.control_period_s:g} s; "
                             f"isorig's loop runs at {CONTROL_PERIOD_S:g} s")
        if self.speed != 1.0 and self.rig.realtime:
            raise ValueError(f"the rig {self.rig.name!r} runs in real time only (speed = {self.speed:g})")
        scenario = self.scenario
        options = scenario.effective_controller_options()
        controller = make_controller(scenario.controller, rig=scenario.rig, **options)
        limit = min(scenario.rig.command_limit_v, self.rig.command_limit_v)
        self.hybrid = hybrid_from_job(job, scenario)
        if self.hybrid is not None:  # its compiled kernels load on a first call: before the rig is armed
            self.hybrid.warm_up()
        table = self.hybrid.target_table() if self.hybrid is not None else scenario.target_table()
        self.loop = ClosedLoop(scenario.profile, controller, limit, table=table)
        if self.rig.realtime:  # load the compiled period before the rig is armed: its watchdog will not wait
            warm = ClosedLoop(scenario.profile, make_controller(scenario.controller, rig=scenario.rig, **options),
                              limit, table=scenario.target_table())
            warm.guard_displacement(scenario.rig.stroke_m)
            for k in (0, 2):  # period 1 lost: the held period's code too
                warm.step(Measurement(k, k * CONTROL_PERIOD_S, 0.0, 0.0, 0.0, scenario.supply_pa))
            warm.brake()
        limits = SafetyLimits.from_dict(job["limits"])
        self.monitor = SafetyMonitor(limits, self.scenario.supply_pa, sensor_range_m=scenario.rig.stroke_m)
        # a braking stop comes to rest within the displacement limit, whatever its action (but indicate)
        self.displacement_bound_m = (math.inf if limits.action("displacement_m") == "indicate"
                                     else limits.displacement_m)
        self.guard_m = None  # a controlled-stop displacement limit: the target never carries the table past it
        if limits.action("displacement_m") == "controlled_stop" and not self.motion:
            self.guard_m = limits.displacement_m
            self.brake_m_per_s2 = self.loop.guard_displacement(limits.displacement_m)
        # judged against the test's planned target: a hybrid test's table is written as it runs (zeros now), its
        # prediction is the reference's motion (an amplitude of 0 made the oscillation bound its 40 um floor)
        self.follow = follow_monitor(scenario, scenario.target_table())
        self.follow_action = limits.action(FOLLOW_KEY)  # controlled_stop, or indicate: an event, the test goes on
        self.start_target_m = self.loop.start_target_m  # now, not in the first period (its first call compiles)
        self.realtime_section = "not entered"
        # a hybrid test computes each target from the last measurement: one period at a time on every rig
        self.compiled = getattr(self.driver, "run_compiled", None) if self.hybrid is None else None
        self.windows = cycle_windows(self.scenario)
        self.next_window = 0
        self.cycles_in_block: dict[int, int] = {}
        self.pending = Samples.empty()
        self.pending_start = 0
        self.produced: list[Samples] = []  # rows run on the rig and not yet released
        # a rig in real time: the worker's own work waits for the answer of a period, one piece per period
        # (``after_answer``), so that no measurement waits for more than one piece
        self.after_answer_work: deque[tuple[str, object]] = deque()
        self.answered = False  # a command was written for the rig's current period: wait for the next one
        # the rig's period of the loop's period 0: the periods the host waited for the supply (settle_supply)
        self.period_base = 0
        self.supply_settle: dict | None = None  # the wait for the supply, when there was one (in ``pacing``)
        self.pacer: Pacer | None = None
        self.trip: Trip | None = None
        self.lost_periods = 0
        self.next_link_report_s = 0.0
        self.priority = "normal"
        # a rig in real time: where each period went, and what ran before each stall (sim.realtime.PeriodTrace)
        self.trace = PeriodTrace(CONTROL_PERIOD_S) if self.rig.realtime else None

    # --- messages ------------------------------------------------------------------------------------
    def send(self, kind: str, payload) -> None:
        self.out.send((kind, payload))

    def event(self, kind: str, message: str, values: dict | None = None, time_s: float | None = None) -> None:
        self.send("event", {"kind": kind, "message": message, "values": values or {},
                            "time_s": self.loop.time_s if time_s is None else time_s})

    def poll_command(self) -> str | None:
        if SIGNALS.pending:  # SIGTERM reached this process (its process group was told to stop)
            SIGNALS.pending = False
            return "shutdown"
        try:
            if self.commands.poll():
                return self.commands.recv()
        except (EOFError, OSError) as exc:
            raise ServerGone() from exc
        return None

    # --- cycles --------------------------------------------------------------------------------------
    def collect_cycles(self, rows: Samples) -> None:
        self.pending = Samples.concatenate([self.pending, rows])
        while self.next_window < len(self.windows):
            block, i0, i1, _f = self.windows[self.next_window]
            if i1 > self.loop.period:
                break
            seg = self.pending[i0 - self.pending_start: i1 - self.pending_start]
            self.next_window += 1
            index_in_block = self.cycles_in_block.get(block, 0)
            self.cycles_in_block[block] = index_in_block + 1
            if len(seg) >= 2:
                self.send_cycle(self.next_window, block, index_in_block, seg)
            self.pending = self.pending[i1 - self.pending_start:]
            self.pending_start = i1

    def send_cycle(self, number: int, block: int, index_in_block: int, seg: Samples) -> None:
        """The cycle's loop at full resolution, its measured periods only, and its phase (after a stop, the
        loop's blocks are cut: its last cycles are the ramp-out); the service computes its metrics
        (service.cycle_with_metrics)."""
        packed = self.loop.blocks[block]
        phase = cycle_phase(index_in_block, int(packed[B_CYCLES]), int(packed[B_TAPER]),
                            self.scenario.profile[block].cycles)
        measured = measured_rows(seg["flags"])  # a lost period's row holds an older reading: not in the loop
        self.send("cycle", {"cycle": number, "block": block, "phase": phase, "t_start_s": float(seg["time_s"][0]),
                            "t_end_s": float(seg["time_s"][-1] + CONTROL_PERIOD_S),
                            "displacement_m": seg["displacement_m"][measured], "force_n": seg["force_n"][measured]})

    # --- the loop ------------------------------------------------------------------------------------
    def execute(self) -> tuple[str, str | None]:
        """Arm, run to the end (or to a stop, trip, abort or fault), disarm; the final (status, reason)."""
        driver, loop = self.driver, self.loop
        status = "failed"
        section = RealtimeSection(lock=self.rig.realtime)
        try:
            section.__enter__()  # no collector pause in the period; memory locked where permitted (sim.realtime)
            self.realtime_section = section.granted
            driver.arm(ArmConditions(self.scenario.supply_pa, self.scenario.effective_vertical_load_n,
                                     self.job.get("test_id")))
            ended = self.settle_supply()
            if ended is not None:  # the operator ended it while the supply rose: nothing moved
                status, reason = ended
                return status, reason
            if self.motion:
                self.start_move_where_read()
            status, reason = self._run()
            return status, reason
        except RigFault as exc:
            status = "failed"
            self.run_after_answer(("release",))
            self.release(self.take_produced(), pace=False)  # every sample received before the fault is kept
            reason = f"rig fault at t = {loop.time_s:.3f} s: {exc}"
            self.event("rig_fault", reason, {"link": driver.link_stats()})
            return status, reason
        except ServerGone:
            raise
        except BaseException:  # a bug, an error, SIGTERM (Terminated): keep what was measured, then report it (main)
            self.run_after_answer(("release",))
            self.release(self.take_produced(), pace=False)
            raise
        finally:
            driver.disarm(success=status in ("completed", "stopped"))
            section.__exit__(None, None, None)

    def _run(self) -> tuple[str, str | None]:
        driver, loop = self.driver, self.loop
        chunk = max(1, round(CHUNK_S * self.speed / CONTROL_PERIOD_S))
        self.pacer = Pacer(self.speed)
        self.send("started", {"wall_t0": self.pacer.wall_t0, "chunk_periods": chunk,
                              "total_periods": loop.total_periods, "priority": self.priority,
                              "rig": self.rig.to_dict()})
        command = None
        shutdown = None
        while not loop.done:
            if command == "shutdown" and shutdown is None and not loop.ramping:
                shutdown = self.shut_down()
            if command == "abort":  # disarm(success=False) in execute closes the valve at once
                self.run_after_answer(("release",))
                self.event("operator", f"abort at t = {loop.time_s:.3f} s: valve command set to zero at once",
                           {"action": "abort"})
                return "aborted", f"operator abort at t = {loop.time_s:.3f} s"
            if command == "stop" and self.motion and not loop.ramping:  # the table stops where it is
                loop.begin_command_ramp()
                loop.stopping = True
                self.event("operator", f"stop at t = {loop.time_s:.3f} s: the move stops where it is (valve "
                           "command to 0 V in 0.1 s)", {"action": "stop"})
            elif command == "stop" and not loop.stopping and self.trip is None:
                end_s = self.ramp_out()
                self.event("operator", f"stop at t = {loop.time_s:.3f} s: ramping out, ends at t = {end_s:.3f} s",
                           {"action": "stop", "ends_at_s": end_s})
            if self.trace is not None:
                self.trace.lap("chunk")  # the chunk's rows released (queued) and the operator's command handled
            rows, command = self.chunk(chunk)
            self.after_answer("release", partial(self.release, rows))
            if len(rows) == 0:  # the rig cannot run on (a simulated rig diverged)
                if self.trip is None:
                    self.trip_now(Trip("rig_fault", 0, loop.time_s, f"{driver.fault() or 'the rig stopped'} at "
                                       f"t = {loop.time_s:.3f} s", {"time_s": loop.time_s}))
                break
        self.run_after_answer()  # the last block's checks can still trip: before the verdict
        if shutdown is not None:
            return "interrupted", shutdown + (f"; before it, {self.trip.message}" if self.trip is not None else "")
        if self.trip is not None:
            return "aborted", self.trip.message
        if loop.stopping:
            return "stopped", f"operator stop; ramped out to t = {loop.time_s:.3f} s"
        return "completed", None

    def new_move_guard(self):
        """A manual move's velocity guard (sim.motion.MoveGuard), at the move's speed."""
        from sim.motion import MoveGuard

        speed = self.job["scenario"]["motion"]["speed_m_per_s"]
        return MoveGuard(speed, commissioned=self.scenario.rig_commissioning is not None)

    def move_guard_trip(self, block: Samples, trip: Trip | None) -> Trip | None:
        """The first of the limits' ``trip`` and the move guard's in this block (the guard judges every block of a
        move until a trip, so its velocity spans the blocks)."""
        if self.trip is not None:
            return trip
        guard = self.move_guard.check(block)
        if guard is not None and (trip is None or guard.index <= trip.index):
            return guard
        return trip

    def start_move_where_read(self) -> None:
        """A manual move begins where the table reads now, armed, not where it read when the move was asked (a table
        that settled since, or a reading taken before it came to rest): the move is planned again from this reading,
        at the same speed to the same end, so it starts at rest with no error to close. The reading must be within
        the start tolerance of the planned start (``check_start``), else nothing is sent. A rig in real time is
        answered 0 V (the valve held closed) while the move is planned again, and the loop's period 0 is its next
        measurement (a long move's target takes longer to plan than its watchdog waits)."""
        from sim.motion import MotionError, move_target

        driver = self.driver
        m = driver.read()
        self.check_start(m)
        motion = self.job["scenario"]["motion"]
        planned_m, here_m = float(motion["start_m"]), float(m.position_m)
        if here_m == planned_m:
            return
        if self.rig.realtime:
            driver.write(0.0)
        try:
            self.scenario.history = move_target(here_m, motion["end_m"], motion["speed_m_per_s"])
        except MotionError as exc:
            raise RigFault(f"the table reads {here_m * 1e3:.3f} mm at arming; the move from there: {exc}; "
                           "nothing but 0 V was sent") from None
        loop = self.loop
        self.loop = ClosedLoop(loop.profile, loop.controller, loop.command_limit_v,
                               table=self.scenario.target_table())
        self.follow = follow_monitor(self.scenario, self.scenario.target_table())
        self.start_target_m = self.loop.start_target_m
        if self.rig.realtime:
            driver.wait_next_period()
            self.period_base = driver.read().period  # as after a wait for the supply (settle_supply)
            self.compiled = None
        self.event("status", f"the move starts where the table reads at arming, {here_m * 1e3:.3f} mm "
                   f"({(here_m - planned_m) * 1e3:+.3f} mm from the {planned_m * 1e3:.3f} mm read when it was "
                   f"asked), and lasts {self.loop.total_periods * CONTROL_PERIOD_S:.2f} s",
                   {"planned_start_m": planned_m, "start_m": here_m}, time_s=0.0)

    def ramp_out(self) -> float:
        """The operator's stop: the target ramps out under control (the profile tapers out); the end time in s."""
        end_s = self.loop.ramp_out()
        self.windows = [w for w in self.windows if w[2] <= self.loop.total_periods]
        return end_s

    def shut_down(self) -> str:
        """The service is told to stop (SIGTERM, SIGINT, docker stop): the target brakes to rest and goes back
        to where the test began (a manual move stops where it is), under control; the reason to record."""
        loop, t = self.loop, self.loop.time_s
        if self.motion:
            if not loop.ramping:
                loop.begin_command_ramp()
                loop.stopping = True
            what = "the move stopped where it was (valve command to 0 V in 0.1 s)"
        else:
            end_s = loop.brake(within_m=self.displacement_bound_m, home_m=self.start_target_m)
            self.windows = [w for w in self.windows if w[2] <= loop.end_period]
            what = (f"the table braked to rest and went back to {self.start_target_m * 1e3:.4g} mm under control, "
                    f"by t = {end_s:.3f} s")
        reason = f"the service was told to stop at t = {t:.3f} s: {what}, then the valve closed"
        self.event("operator", reason, {"action": "shutdown"}, time_s=t)
        return reason

    def brake(self) -> float:
        """A controlled stop after a limit trip: the target brakes to rest from where it is, within every
        displacement limit, and holds there under control (sim.loop.ClosedLoop.brake); the end time in s."""
        end_s = self.loop.brake(within_m=self.displacement_bound_m)
        self.windows = [w for w in self.windows if w[2] <= self.loop.end_period]
        return end_s

    def guard_trip(self, block: Samples) -> Trip | None:
        """The displacement guard began a braking stop in this block (FLAG_GUARD): the trip that says so
        (sim.detectors.guard_trip); the loop brakes from now on."""
        if self.guard_m is None:
            return None
        trip = guard_trip(block, self.guard_m, self.loop.brake_rest_m, self.brake_m_per_s2)
        if trip is None:
            return None
        self.loop.stopping = True
        self.windows = [w for w in self.windows if w[2] <= self.loop.end_period]
        return trip

    def trip_now(self, trip: Trip) -> None:
        """A limit trip: record it and act: ``controlled_stop`` ramps the target out under control, anything
        else ramps the valve command to zero, open loop (a later valve_close trip during a controlled stop
        still closes the valve: ``escalate``)."""
        self.trip = trip
        self.event("limit_trip", trip.message, {"detector": trip.detector, "action": trip.action, **trip.values})
        if trip.action == "controlled_stop" and not self.motion:  # also during an operator's ramp-out
            self.brake()
        else:  # a manual move stops where it is, as on the operator's stop
            self.loop.begin_command_ramp(at_once=trip.close_at_once)

    def escalate(self, trip: Trip) -> None:
        """A valve_close trip during a controlled stop: the valve closes now."""
        self.event("limit_trip", f"{trip.message}; during the controlled stop: the valve closes",
                   {"detector": trip.detector, "action": trip.action, "escalation": True, **trip.values})
        self.loop.begin_command_ramp(at_once=trip.close_at_once)

    def periods(self, n: int) -> Samples:
        """Up to n periods of the loop on the rig: one compiled call, or wait/read/step/write per period.

        The wait comes first, so the worker's own work (detectors, sending samples) runs after a command is
        written, while the rig's next period goes on, never between a measurement and its answer. Each
        period's rows join ``produced`` as soon as they exist: a fault raised by a wait loses none of them."""
        loop, driver = self.loop, self.driver
        first = len(self.produced)
        if self.compiled is not None:
            self.produced.append(self.compiled(loop, n))
        else:
            end = min(loop.period + n, loop.end_period)
            trace = self.trace
            while loop.period < end:
                wait_from = time.perf_counter()
                if self.answered:
                    driver.wait_next_period()
                got = time.perf_counter()
                m = driver.read()
                if self.period_base:  # the test's clock started after the host waited for the supply
                    m = dataclasses.replace(m, period=m.period - self.period_base,
                                            time_s=(m.period - self.period_base) * CONTROL_PERIOD_S)
                if not self.answered:
                    self.check_start(m)
                if self.hybrid is not None:
                    self.hybrid.on_measurement(m, loop)
                u, rows = loop.step(m)
                self.produced.append(rows)
                driver.write(u)
                if trace is not None:
                    trace.answered(wait_from, got, time.perf_counter(), getattr(driver, "first_sent_ns", None),
                                   getattr(driver, "sent_ns", None))
                self.answered = True
                if self.after_answer_work:  # one piece of the worker's own work, while the rig's period goes on
                    kind, work = self.after_answer_work.popleft()
                    work()
                    if trace is not None:
                        trace.lap(kind)
        return Samples.concatenate(self.produced[first:])

    def after_answer(self, kind: str, work) -> None:
        """Run ``work`` (``kind``: "check" or "release") after the answer of a coming period, one piece per
        period in the order given, on a rig in real time; at once on a simulated rig. The limit detectors never
        wait: they run as each block ends (``chunk``). Measured on the rig emulator with two CPU hogs beside
        (host at SCHED_RR): the limit detectors took 0.67 ms and the follow detector 0.42 ms of a 1 ms period, so
        run back to back they made every tenth measurement wait."""
        if self.rig.realtime:
            self.after_answer_work.append((kind, work))
        else:
            work()

    def run_after_answer(self, kinds: tuple[str, ...] = ("check", "release")) -> None:
        """Run the pieces of work still waiting for an answer, in order (those of other kinds are dropped): at
        the end of a run every kind, after a fault or an abort the releases alone (no sample is lost; a detector
        has nothing left to stop)."""
        while self.after_answer_work:
            kind, work = self.after_answer_work.popleft()
            if kind in kinds:
                work()

    def check_start(self, m: Measurement) -> None:
        """The first reading after arming: the table must rest where the target begins (the service and the
        command line ask the rig before; this is the check that cannot be raced), else no command is sent (but
        the 0 V of a wait for the supply, ``settle_supply``, which checks it before it waits)."""
        start_m = self.start_target_m
        tolerance_m = self.job.get("start_tolerance_m", START_TOLERANCE_M)
        if not abs(m.position_m - start_m) <= tolerance_m:
            sent = "no command was sent" if self.supply_settle is None else "no command but 0 V was sent"
            raise RigFault(f"the table reads {m.position_m * 1e3:.2f} mm at arming and the run starts at "
                           f"{start_m * 1e3:.2f} mm (within +-{tolerance_m * 1e3:g} mm): {sent}")

    def settle_supply(self) -> tuple[str, str] | None:
        """After ARM, before the test's clock starts: wait until the measured supply pressure is
        ``SUPPLY_SETTLE_FRACTION`` of the asked one, answering every measurement with 0 V (the rig's watchdog
        needs a command every period), at most ``supply_settle_timeout_s`` (wall time from ARM on a rig in real
        time, the rig's own clock on a simulated one). A supply there at once (the simulated rig) costs one
        read and nothing is written. Not there in time: ``RigFault`` with the figures, nothing but 0 V sent (the
        run ends ``failed``, the rig disarmed). The loop's period 0 is then the measurement that reached it
        (``period_base``), so the supply-loss detector judges only from there. A fault the rig reports meanwhile
        ends it at once; the operator's stop, abort or the service's shutdown end it with nothing moved: the
        final (status, reason), else None."""
        driver = self.driver
        asked_pa = self.scenario.supply_pa
        need_pa = SUPPLY_SETTLE_FRACTION * asked_pa
        m = driver.read()
        if not m.supply_pressure_pa < need_pa:  # there (or not finite: the loop's detectors judge that at once)
            return None
        self.check_start(m)  # a table not where the run begins: nothing is sent, not even the 0 V of the wait
        timeout_s = float(self.job.get("supply_settle_timeout_s", SUPPLY_SETTLE_TIMEOUT_S))
        wall0 = time.perf_counter()
        self.supply_settle = {"asked_pa": asked_pa, "fraction": SUPPLY_SETTLE_FRACTION, "timeout_s": timeout_s,
                              "supply_at_arm_pa": m.supply_pressure_pa, "reached": False}
        n = 0
        while m.supply_pressure_pa < need_pa:
            waited_s = time.perf_counter() - wall0 if self.rig.realtime else m.time_s
            self.supply_settle.update(waited_s=waited_s, supply_pa=m.supply_pressure_pa)
            if m.status & RIG_FAULT_BITS:
                raise RigFault(f"the rig reports a fault ({describe_status(m.status & RIG_FAULT_BITS)}) "
                               f"{waited_s:.2f} s after ARM, while its supply rose ({m.supply_pressure_pa / 1e5:.3g} "
                               f"of {asked_pa / 1e5:.3g} bar): nothing but 0 V was sent")
            if waited_s >= timeout_s:
                raise RigFault(f"the supply reached only {m.supply_pressure_pa / 1e5:.3g} bar of "
                               f"{asked_pa / 1e5:.3g} bar within {timeout_s:g} s after ARM (a run starts at "
                               f"{SUPPLY_SETTLE_FRACTION:.0%} of it): check the pump, its set point and the supply "
                               "line; nothing but 0 V was sent")
            driver.write(0.0)
            n += 1
            if n % CHECK_PERIODS == 0:
                ended = self.settle_ended(self.poll_command(), m.supply_pressure_pa, waited_s)
                if ended is not None:
                    return ended
            driver.wait_next_period()
            m = driver.read()
        waited_s = time.perf_counter() - wall0 if self.rig.realtime else m.time_s
        self.supply_settle.update(waited_s=waited_s, supply_pa=m.supply_pressure_pa, reached=True,
                                  rig_periods=m.period)
        self.period_base = m.period  # the loop answers this measurement: its period 0
        if self.compiled is not None:  # a compiled path runs on the rig's own periods: per period from here
            self.compiled = None
        self.event("status", f"the supply reached {m.supply_pressure_pa / 1e5:.3g} bar of {asked_pa / 1e5:.3g} bar "
                   f"{waited_s:.2f} s after ARM (the valve held at 0 V meanwhile); the test's clock starts now",
                   dict(self.supply_settle), time_s=0.0)
        return None

    def settle_ended(self, command: str | None, supply_pa: float, waited_s: float) -> tuple[str, str] | None:
        """An operator's command (or the service's shutdown) while the host waits for the supply: the run ends
        with nothing moved (the driver is disarmed on the way out)."""
        if command is None:
            return None
        status = {"abort": "aborted", "stop": "stopped", "shutdown": "interrupted"}.get(command)
        if status is None:
            return None
        what = {"abort": "operator abort", "stop": "operator stop",
                "shutdown": "the service was told to stop"}[command]
        reason = (f"{what} {waited_s:.2f} s after ARM, while the host waited for the supply "
                  f"({supply_pa / 1e5:.3g} of {self.scenario.supply_pa / 1e5:.3g} bar): nothing moved, the valve "
                  "was held at 0 V and closed")
        self.event("operator", reason, {"action": command}, time_s=0.0)
        return status, reason

    def take_produced(self) -> Samples:
        rows, self.produced = Samples.concatenate(self.produced), []
        return rows

    def chunk(self, n: int) -> tuple[Samples, str | None]:
        """Up to n periods in blocks of CHECK_PERIODS, checking the detectors after each block and polling for
        an operator command; stops early at a trip that closes the valve or a command."""
        loop = self.loop
        command = None
        done = 0
        while done < n and not loop.done:
            m = min(CHECK_PERIODS, n - done)
            block = self.periods(m)
            done += len(block)
            trip = self.monitor.check(block, valve_close_only=self.trip is not None)
            if self.move_guard is not None:
                trip = self.move_guard_trip(block, trip)
            if self.trip is None and (trip is None or trip.action == "controlled_stop"):
                guard = self.guard_trip(block)  # the target began braking before the limit: that comes first
                trip = guard or trip
            for indication in self.monitor.take_indications():
                self.event("limit_indicate", indication.message, {"detector": indication.detector,
                                                                  **indication.values}, time_s=indication.time_s)
            if trip is not None:
                if self.act_on(trip):
                    break
            elif not self.rig.realtime:
                if self.judge_following(block):
                    break
            else:  # after the next period's answer: these checks judge learning and faults, not limits
                self.after_answer("check", partial(self.judge_following, block))
            if len(block) < m:
                break
            command = self.poll_command()
            if self.trace is not None:
                self.trace.lap("block")  # the block's detectors, its rows gathered, the operator's command polled
            if command is not None:
                break
        return self.take_produced(), command

    def judge_following(self, block: Samples) -> bool:
        """The checks of a block that did not trip a limit (``chunk``): a rig the controller does not follow, a
        hybrid simulation gone unstable, a fault the driver reports; the first trip acts (True: the valve
        closes, ``act_on``)."""
        loop = self.loop
        trip = None
        if self.follow is not None and self.trip is None and not loop.stopping:
            lost = self.follow.check(block)
            if lost is not None:
                trip = follow_trip(lost, self.follow_action)
            if trip is not None and trip.action == "indicate":  # an event; the monitor goes on
                self.monitor.indicate_follow(trip)
                for indication in self.monitor.take_indications():
                    self.event("limit_indicate", indication.message, {"detector": indication.detector,
                                                                      **indication.values}, time_s=indication.time_s)
                self.follow.resume()
                trip = None
        if trip is None and self.hybrid is not None and self.hybrid.tripped:
            trip = Trip("rths_stability", len(block) - 1, loop.time_s,
                        f"hybrid simulation unstable at t = {loop.time_s:.3f} s: {self.hybrid.monitor.reason}",
                        {"time_s": loop.time_s, **self.hybrid.monitor.to_dict()})
        fault = self.driver.fault()
        if trip is None and fault is not None:
            trip = Trip("rig_fault", len(block) - 1, loop.time_s, f"{fault} at t = {loop.time_s:.3f} s",
                        {"time_s": loop.time_s})
        return trip is not None and self.act_on(trip)

    def act_on(self, trip: Trip) -> bool:
        """The first trip of a test acts (``trip_now``); a valve close during a controlled stop overrules it
        (``escalate``). True: the chunk ends here (the valve closes)."""
        if self.trip is None:
            self.trip_now(trip)
            return trip.action != "controlled_stop"
        if trip.action == "valve_close" and not self.loop.ramping:
            self.escalate(trip)  # a controlled stop is running: only a valve close overrules it
        return False

    def release(self, rows: Samples, pace: bool = True) -> None:
        if len(rows) == 0:
            return
        if pace and not self.rig.realtime:  # a real rig paced the chunk itself
            self.pacer.wait_until(self.loop.time_s)
        self.lost_periods += int(np.count_nonzero(~measured_rows(rows["flags"])))
        if self.hybrid is not None:  # the stability monitor and the structure's response, just before the samples
            k0 = int(round(float(rows["time_s"][0]) / CONTROL_PERIOD_S))
            structure = np.full((len(rows), len(self.hybrid.names)), np.nan)
            part = self.hybrid.channels[k0: k0 + len(rows)]
            structure[: len(part)] = part
            self.send("hybrid", {"time_s": float(rows["time_s"][-1]), "monitor": self.hybrid.monitor.to_dict(),
                                 "columns": self.hybrid.names, "rows": structure})
        self.send("samples", rows.array)
        self.collect_cycles(rows)
        if self.loop.time_s >= self.next_link_report_s:
            self.next_link_report_s = self.loop.time_s + LINK_REPORT_S
            link = self.driver.link_stats()
            if link:
                self.send("link", {**link, "lost_periods": self.lost_periods})

    def pacing(self) -> dict:
        stats = self.pacer.stats() if self.pacer is not None else {}
        if self.rig.realtime:
            stats = {"chunks": stats.get("chunks", 0), "realtime_rig": True}
        if self.supply_settle is not None:  # the host waited for the supply after ARM
            stats = {**stats, "supply_settle": dict(self.supply_settle)}
        if self.trace is not None and self.trace.periods:
            stats = {**stats, "period_trace": self.trace.summary()}
        return {**stats, "priority": self.priority, "realtime_section": self.realtime_section}


class Collector:
    """An outbox that keeps what a run sends (for a run in this process, without the service)."""

    def __init__(self):
        self.messages: list[tuple[str, object]] = []

    def send(self, message) -> None:
        self.messages.append(message)

    def samples(self) -> Samples:
        return Samples.concatenate([Samples(rows) for kind, rows in self.messages if kind == "samples"])

    def of_kind(self, kind: str) -> list:
        return [payload for k, payload in self.messages if k == kind]


class AbortSwitch:
    """Operator commands for a run in this process: ``abort()`` (e.g. from Ctrl-C) is seen at the next check."""

    def __init__(self):
        self.pending: list[str] = []

    def abort(self, *_args) -> None:
        self.pending.append("abort")

    def poll(self, *_args) -> bool:
        return bool(self.pending)

    def recv(self) -> str:
        return self.pending.pop(0)


def run_here(job: dict, commands: AbortSwitch | None = None) -> tuple[Run, Collector, str, str | None]:
    """Run a job in this process (``isorig simulate --rig ...``): the same loop, detectors and stop paths as
    the service's worker. Returns the run, what it sent, the final status and its reason."""
    out = Collector()
    run = Run(job, out, commands or AbortSwitch())
    # a real-time rig only, and only for the run: this process goes on afterwards (a script, a test suite)
    realtime = job.get("realtime", True) and run.rig.realtime
    with realtime_priority(WORKER_RR_PRIORITY) if realtime else nullcontext("normal") as granted:
        run.priority = granted
        status, reason = run.execute()
    return run, out, status, reason


class Terminated(BaseException):
    """SIGTERM reached the worker process: the run ends where it is (the driver is disarmed on the way out)."""


class Signals:
    """SIGTERM to the worker: the first asks for the controlled shutdown (``Run.shut_down``, seen at the next
    block of ten periods); a second one, or one before the run has begun, ends the run at once (valve closed)."""

    def __init__(self):
        self.pending = False
        self.count = 0
        self.running = False

    def on_term(self, signum, _frame):
        self.count += 1
        if self.running and self.count == 1:
            self.pending = True
            return
        raise Terminated(f"the worker process was told to end ({signal.Signals(signum).name})")


SIGNALS = Signals()


def main(job: dict, out, commands) -> None:
    """Process entry point: run the job, always end with a ``finished`` message if the server is there.

    Ctrl-C in the service's terminal reaches the whole process group: the worker ignores SIGINT, the service
    shuts down and aborts the test (``interrupted``). SIGTERM ends the run at once with its reason recorded."""
    run = None
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, SIGNALS.on_term)
    # Priority first: threads inherit it, so the outbox thread cannot hold the GIL at a lower priority while
    # the real-time control thread waits for it (a priority inversion). A short GIL switch interval lets
    # the control thread take the GIL back within 0.5 ms when it wakes.
    priority = raise_priority(WORKER_RR_PRIORITY) if job.get("realtime", True) else "normal"
    sys.setswitchinterval(GIL_SWITCH_INTERVAL_S)
    outbox = Outbox(out)
    try:
        run = Run(job, outbox, commands)
        run.priority = priority
        SIGNALS.running = True
        status, reason = run.execute()
        run.send("finished", {"status": status, "reason": reason, "pacing": run.pacing(),
                              "link": run.driver.link_stats(), "lost_periods": run.lost_periods,
                              "limit_indications": dict(run.monitor.indication_counts)})
    except ServerGone:
        return
    except (Exception, Terminated) as exc:  # report any failure to the server instead of dying silently
        pacing = run.pacing() if run is not None else {}
        if isinstance(exc, Terminated):
            at = f" at t = {run.loop.time_s:.3f} s" if run is not None else ""
            status, reason = "aborted", f"{exc}{at}; the valve command was set to zero"
        else:
            status, reason = "failed", f"worker error: {type(exc).__name__}: {exc}"
        try:
            outbox.send(("finished", {"status": status, "reason": reason, "pacing": pacing}))
        except ServerGone:
            pass
    finally:
        outbox.close()
        try:
            out.close()
        except OSError:
            pass
