"""The rig service in the server process: starts the worker process, records and streams what it sends.

One service per rig, one test at a time per rig: the service starts only the tests of its rig
(``settings.rig_name``); other services may run their rigs' tests on the same database at the same time.
``start`` spawns the worker (forkserver or spawn context), a reader thread
that streams what the worker sends to the hub at once, and a writer thread that stores it: samples in
chunks committed at least every ``commit_interval_s`` (so a killed server loses at most about a second),
cycles, events and the final status as they come. If the worker dies without a final message the
test ends ``aborted`` with the exit code as its reason and every sample received so far kept.
"""

from __future__ import annotations

import contextlib
import logging
import multiprocessing as mp
import queue
import signal
import threading
import time
from datetime import UTC, datetime

import numpy as np
from sqlalchemy.orm import Session, sessionmaker

from sim.engine import Scenario, said_indicate
from sim.follow import advice_for, tracking_verdict
from sim.loop import CONTROL_PERIOD_S
from sim.metrics import headline_figures
from sim.safety import FOLLOW_KEY, SafetyLimits
from sim.samples import CSV_FIELDS, SAMPLE_FIELDS, Samples
from sim.tracking import tracking_summary

from . import store
from .settings import Settings
from .stream import Hub, sample_labels
from .worker import scenario_from_job

log = logging.getLogger("isorig.service")

STATUS_INTERVAL_S = 0.25  # wall time between status messages while a test runs
MAX_CHUNK_ROWS = 1000  # one stored chunk holds at most ~1 s of samples
SHUTDOWN_GRACE_S = 20.0  # a shutdown waits this long for the controlled stop and the return home (<= 30 mm: ~5 s)


CLOSED_VALVE = "no test runs: the valve is closed (0 V)"  # the command between tests (GET /api/rig/state)
LOOP_POINTS_MAX = 2000  # points of a cycle's loop streamed and stored (decimated beyond this)


def cycle_with_metrics(payload: dict) -> dict:
    """A cycle as the worker sends it (full-resolution displacement and force) with its loop metrics
    (sim.metrics), the loop decimated to at most ``LOOP_POINTS_MAX`` points for the stream and the store.

    Done here, not in the worker: the real-time process runs the loop and nothing else (a cycle's metrics
    took 1 ms, a whole period, in the control thread)."""
    from sim.metrics import loop_metrics

    d, f = payload["displacement_m"], payload["force_n"]
    try:
        metrics = loop_metrics(d, f)
    except ValueError as exc:  # non-finite samples: no metrics for this cycle
        metrics = {"error": str(exc)}
    step = max(1, -(-len(d) // LOOP_POINTS_MAX))
    return {**payload, "metrics": metrics, "displacement_m": d[::step].copy(), "force_n": f[::step].copy()}


def start_position_m(job_scenario: dict) -> float:
    """Where a job's target begins, m: a manual move's start, a commissioning's resting position, else the
    first sine block's ``start_m`` (0 for every other test)."""
    motion = job_scenario.get("motion")
    if motion:
        return float(motion["start_m"])
    if job_scenario.get("commissioning"):
        return float(job_scenario["commissioning"]["start_m"])
    profile = job_scenario.get("profile") or []
    return float(profile[0].get("start_m", 0.0)) if profile else 0.0


def worker_scenario(job_scenario: dict, plant_changes: dict) -> dict:
    """The job's scenario as the worker gets it: the stored one (JSON), with a commissioning's excitation target
    (sim.commission.identify.excitation_target, rebuilt from its conditions: the table held where it rested)
    and the simulated plant's changes of ``isorig serve --plant-set`` (the run's own come last)."""
    out = dict(job_scenario)
    c = job_scenario.get("commissioning")
    if c:
        from sim.commission.identify import excitation_target

        out["history_target"] = excitation_target(c["start_m"], job_scenario.get("controller_options") or {})
    if plant_changes:
        out["plant_changes"] = {**plant_changes, **(job_scenario.get("plant_changes") or {})}
    return out


def lost_periods(samples: Samples) -> int:
    """Periods whose measurement never arrived (flagged by the loop, sim.measurement.FLAG_LOST)."""
    from sim.measurement import measured_rows

    return int(np.count_nonzero(~measured_rows(samples["flags"])))


class Conflict(Exception):
    """The request is valid but the rig or the test is not in a state that allows it (HTTP 409)."""


class ActiveRun:
    """The bookkeeping of the test the worker is running now."""

    def __init__(self, test_id: int, process, out, commands, job: dict):
        self.test_id = test_id
        self.process = process
        self.out = out
        self.commands = commands
        self.job = job
        self.thread: threading.Thread | None = None
        self.wall_t0: float | None = None
        self.time_s = 0.0
        self.finished = threading.Event()
        self.stop_requested = False
        self.shutdown = False
        self.cycles_done = 0
        self.arrival_ms: list[float] = []
        self.link: dict = {}  # the latest link health a real rig's driver reported
        self.last_row: np.ndarray | None = None  # the newest sample (SAMPLE_FIELDS layout)
        self.stopping: str | None = None  # why the test is ending early (a stop, an abort, a limit trip)
        self.ends_at_s: float | None = None  # a stop's ramp-out: the test time it ends at (the worker says)
        self.vertical_load_n = job["scenario"].get("vertical_load_n")
        self.stability: dict | None = None  # a hybrid test: the stability monitor as the worker last sent it
        self.structure: dict | None = None  # ... and the structure's channels for the samples that follow


def _what(test) -> str:
    """What a record is, in its events' words: "manual move" (a move of the table), "commissioning" (the rig's
    commissioning excitation) or "test"."""
    kind = ((test.request or {}).get("profile") or {}).get("kind")
    return {"move": "manual move", "commissioning": "commissioning"}.get(kind, "test")


def _source_word(test) -> str:
    """How a position source names the record the table's last position comes from: "end of move N" after a
    manual move, "end of test N" after anything else (the console reads both: frontend/static/js/state.js)."""
    return "move" if _what(test) == "manual move" else "test"


class RigService:
    """Runs tests on one rig through a worker process; records them in the store and streams them."""

    def __init__(self, settings: Settings, sessions: sessionmaker[Session], hub: Hub, driver: str | None = None):
        self.settings = settings
        self.sessions = sessions
        self.hub = hub
        self.driver = driver or settings.rig  # "simulated" or "udp://HOST:PORT"
        self.rig_name = settings.rig_name  # the rig this service drives; its records carry the name
        self.active: ActiveRun | None = None
        self.last_link: dict = {}  # the link figures of the last test that ran on a UDP rig
        self.last_end: dict | None = None  # where the table was when the last test ended (rig_state)
        self._lock = threading.Lock()
        self._context = None
        self._seq: dict[int, int] = {}
        #: called as hook(session, test, status, reason) in the transaction that ends a run, after its summary;
        #: a hook may change the record and return a callable, called once the end is committed and streamed
        self.end_hooks: list = []
        self.rig_lock = None  # backend.rig_lock: while it is not held (its database connection lost) no test starts

    # --- state ---------------------------------------------------------------------------------------
    def context(self):
        if self._context is None:
            method = self.settings.worker_start_method
            if method not in mp.get_all_start_methods() or method == "fork":
                method = "spawn"
            ctx = mp.get_context(method)
            if method == "forkserver":
                ctx.set_forkserver_preload(["backend.preload"])
            self._context = ctx
        return self._context

    def prepare(self) -> None:
        """Start the worker forkserver now (it imports and loads the engine once), not at the first test."""
        ctx = self.context()
        if ctx.get_start_method() == "forkserver":
            from multiprocessing import forkserver, resource_tracker

            # Ctrl-C reaches the whole process group: the forkserver is the service's to stop (it ends with the
            # service). Blocked here, SIGINT stays blocked in the forkserver (the mask outlives exec) until
            # backend.preload has set it ignored: a Ctrl-C during its imports printed a KeyboardInterrupt
            # traceback (issue 34). The resource tracker, which forkserver starts first, protects itself the
            # same way but unblocks SIGINT after: started first here, it leaves the mask below alone.
            resource_tracker.ensure_running()
            old = signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})
            try:
                forkserver.ensure_running()
            finally:
                signal.pthread_sigmask(signal.SIG_SETMASK, old)

    def running_test_id(self) -> int | None:
        run = self.active
        return run.test_id if run is not None and not run.finished.is_set() else None

    def state(self) -> dict:
        run = self.active
        if run is None or run.finished.is_set():
            return {"status": "idle", "test_id": None, "driver": self.driver, "rig_name": self.rig_name}
        return {"status": "running", "test_id": run.test_id, "driver": self.driver, "rig_name": self.rig_name,
                "time_s": run.time_s,
                "worker_pid": run.process.pid, "link": run.link}

    def rig_info(self) -> dict:
        """Which rig this service drives and with which link settings (what the dashboard shows)."""
        from .drivers import SIMULATED

        tolerance = {"start_tolerance_m": self.settings.rig_start_tolerance_m}  # the table within this of the start
        if self.driver == SIMULATED:
            plant = self.settings.plant_changes()
            out = {"kind": "simulated", "name": "simulated rig", "url": SIMULATED, **tolerance,
                   "detail": "the fifth-order rig model runs in the worker, faster than real time if asked",
                   "plant_changes": plant}
            if plant:
                out["detail"] += ("; it plays a rig unlike the rig file in force (isorig serve --plant-set: "
                                  + ", ".join(f"{k}={v:g}" for k, v in plant.items()) + "), for demos and tests")
            return out
        from .drivers.udp import parse_udp_url

        host, port = parse_udp_url(self.driver)
        link = self.settings.link_settings()
        security = self.settings.rig_security(self.driver)
        return {"kind": "udp", "name": self.driver, "url": self.driver, "host": host, "port": port, **tolerance,
                "control_period_s": link["period_s"], "link_timeout_s": link["timeout_s"],
                "arm_timeout_s": link["arm_timeout_s"], **security.describe(),
                "protocol": f"isorig rig protocol v{security.protocol_version} (docs/rig-protocol.md), "
                + ("authenticated" if security.authenticated else f"NOT AUTHENTICATED: {security.why}")}

    def link_health(self) -> dict:
        """The link to the rig: the running test's figures (latency, lost packets, last sequence), else one
        HELLO to the rig (is it there, how long it took)."""
        from .drivers import SIMULATED

        if self.driver == SIMULATED:
            return {"kind": "simulated", "connected": True}
        run = self.active
        if run is not None and not run.finished.is_set():
            return {"kind": "udp", "connected": True, "armed": True, "test_id": run.test_id, **run.link}
        from .drivers.udp import probe

        out = {"kind": "udp", **probe(self.driver, timeout_s=0.2, **self.settings.rig_security_options())}
        if self.last_link:
            out["last_test"] = self.last_link
        return out

    @staticmethod
    def _row_state(row: np.ndarray | None) -> dict:
        if row is None:
            return {"table_position_m": None, "force_n": None, "supply_pressure_pa": None, "command_v": None}
        named = dict(zip(SAMPLE_FIELDS, (float(v) for v in row), strict=False))
        return {key: named[field] if np.isfinite(named[field]) else None for key, field in (
            ("table_position_m", "measured_displacement_m"), ("force_n", "force_n"),
            ("supply_pressure_pa", "supply_pressure_pa"), ("command_v", "voltage_v"))}

    def rig_state(self) -> dict:
        """What the status strip and the console's readouts show: the rig's status (running, stopping, idle,
        not_connected, faulted), the running test, where the table is and where that figure comes from (live, the
        end of the last test, the rig's answer to a probe), the force and the valve command now with where each
        comes from (``force_source``, ``command_source``; a null figure's source says why there is none), supply
        pressure, vertical load, the limits in force, the last event."""
        from .drivers import SIMULATED

        run = self.active
        out: dict = {"at": time.time(), "driver": self.driver, "rig_name": self.rig_name}
        if run is not None and not run.finished.is_set():
            out.update(status="stopping" if run.stopping else "running", test_id=run.test_id, armed=True,
                       time_s=run.time_s, stopping_reason=run.stopping, **self._row_state(run.last_row),
                       position_source="live", force_source="live", command_source="live",
                       vertical_load_n=run.vertical_load_n, limits=run.job["limits"])
            return out
        # no test runs: this service drives no valve, so the valve is closed (0 V) unless a rig says it is armed
        out.update(status="idle", test_id=None, armed=False, vertical_load_n=None, limits=None,
                   table_position_m=None, force_n=None, supply_pressure_pa=None, position_source="unknown",
                   force_source="no reading: no test has run on this rig", command_v=0.0,
                   command_source=CLOSED_VALVE)
        if self._last_end() is not None:
            ended = f"end of {self.last_end.get('what', 'test')} {self.last_end['test_id']} ({self.last_end['status']})"
            out.update(table_position_m=self.last_end["table_position_m"], force_n=self.last_end["force_n"],
                       position_source=ended, force_source=ended)
        if self.driver != SIMULATED:
            from .drivers.udp import probe

            answer = probe(self.driver, timeout_s=0.2, **self.settings.rig_security_options())
            if not answer["connected"]:
                # the last known position stays (the strip says where from); a force or command of before is
                # not the rig's now
                out.update(status="not_connected", detail=answer["detail"], force_n=None, command_v=None,
                           force_source=f"no reading: the rig does not answer ({answer['detail']})",
                           command_source="no reading: the rig does not answer (its watchdog closes the valve "
                           "when commands stop)")
            else:
                out.update(status="faulted" if answer.get("fault") else "idle", armed=answer["armed"],
                           rig_status=answer["status"], table_position_m=answer.get("position_m"),
                           force_n=answer.get("force_n"), supply_pressure_pa=answer.get("supply_pressure_pa"),
                           position_source="the rig (probe)", force_source="the rig (probe)")
                if answer["armed"]:  # armed, yet by no test of this service: its command is not known here
                    out.update(command_v=None, command_source="no reading: the rig says it is armed, but no test "
                               "of this service runs; the rig does not report its valve command")
        return out

    # --- operator actions ----------------------------------------------------------------------------
    def start(self, test_id: int, actor: str = "operator") -> None:
        from .drivers import SIMULATED

        with self._lock:
            running = self.running_test_id()
            if running is not None:
                raise Conflict(f"test {running} is running; the rig runs one test at a time")
            if self.rig_lock is not None and not self.rig_lock.held:
                raise Conflict(f"this service has lost the lock of the rig {self.rig_name!r} with its database "
                               "connection (another service may drive it): no test starts until it is held again")
            with self.sessions() as session:
                test = store.get_test(session, test_id)
                if test is None:
                    raise KeyError(test_id)
                self._check_own_rig(test, "start")
                if test.status != "ready":
                    raise Conflict(f"test {test_id} is {test.status}; only a test with status 'ready' can start "
                                   "(create a new test to run it again)")
                self._check_start_position(start_position_m(test.request["job_scenario"]), test_id)
                plant = self.settings.plant_changes() if test.driver == SIMULATED else {}
                if plant:  # the record says what the simulated plant was: not the rig it was told of
                    test.request = {**test.request, "plant_changes": plant}
                    test.scenario = {**test.scenario, "plant_changes": {**plant,
                                                                        **(test.scenario.get("plant_changes") or {})}}
                job = {"test_id": test_id, "rig": test.driver, "link": self.settings.link_settings(),
                       "speed": test.speed, "scenario": worker_scenario(test.request["job_scenario"], plant),
                       "limits": test.limits,
                       "realtime": self.settings.worker_realtime,
                       "start_tolerance_m": self.settings.rig_start_tolerance_m,
                       "table_position_m": self.resting_position_m() or 0.0}
                ctx = self.context()
                out_r, out_w = ctx.Pipe(duplex=False)
                cmd_r, cmd_w = ctx.Pipe(duplex=False)
                from .worker import main as worker_main

                process = ctx.Process(target=worker_main, args=(job, out_w, cmd_r), daemon=True,
                                      name=f"isorig-worker-test-{test_id}")
                process.start()
                out_w.close()
                cmd_r.close()
                store.set_status(session, test, "running")
                started = f"{_what(test)} {test_id} started by {actor}"
                start_values = {"action": "start", **({"move": True} if _what(test) == "manual move" else {}),
                                **({"commissioning": True} if _what(test) == "commissioning" else {})}
                store.add_event(session, test_id, "operator", started, {**start_values, "worker_pid": process.pid},
                                actor=actor, time_s=0.0)
                session.commit()
                record = store.test_record(session, test, with_events=False)
            run = ActiveRun(test_id, process, out_r, cmd_w, job)
            self.active = run
            run.thread = threading.Thread(target=self._record, args=(run, record), daemon=True,
                                          name=f"isorig-reader-{test_id}")
            run.thread.start()
        self._publish_event(test_id, 0.0, "operator", started, start_values)

    def _check_own_rig(self, test, action: str) -> None:
        """Conflict unless ``test`` is of this service's rig: another rig's test is its own service's to run."""
        if test.rig_name != self.rig_name:
            raise Conflict(f"test {test.id} belongs to the rig {test.rig_name!r}; this service drives the rig "
                           f"{self.rig_name!r}: {action} it from the service of {test.rig_name!r}")

    def _check_start_position(self, start_m: float, test_id: int) -> None:
        """The table must rest where the target begins (``start_position_m``: 0 for most tests, a sine's
        ``start_m``, the start of a manual move), within ``rig_start_tolerance_m``: else the controller would
        drive it there at full flow. A UDP rig is asked (one probe); the simulated rig's table is where the
        last test or move left it."""
        from .drivers import SIMULATED
        from .drivers.udp import move_first, start_position_problem

        tolerance = self.settings.rig_start_tolerance_m
        if self.driver != SIMULATED:
            problem = start_position_problem(self.driver, tolerance, expected_m=start_m,
                                             **self.settings.rig_security_options())
        else:
            y = self.resting_position_m() or 0.0
            problem = None if abs(y - start_m) <= tolerance else (
                f"the table is at {y * 1e3:.2f} mm and test {test_id} starts at {start_m * 1e3:.2f} mm (within "
                f"+-{tolerance * 1e3:g} mm): {move_first(start_m)}; nothing moved")
        if problem is not None:
            raise Conflict(problem)

    def resting_position_m(self) -> float | None:
        """Where the table rests now (m), as far as the service knows: a UDP rig is asked; the simulated rig's
        table is where the last test or move left it (None: never moved, or not known)."""
        from .drivers import SIMULATED

        if self.driver != SIMULATED:
            from .drivers.udp import probe

            answer = probe(self.driver, timeout_s=0.2, **self.settings.rig_security_options())
            return answer.get("position_m") if answer["connected"] else None
        end = self._last_end()
        return end["table_position_m"] if end is not None else None

    def _last_end(self) -> dict | None:
        if self.last_end is None:  # after a restart: the end of the newest test on record
            with self.sessions() as session:
                found = store.last_sample(session, self.rig_name)
                if found is not None:
                    test, row = found
                    self.last_end = {"test_id": test.id, "status": test.status, "what": _source_word(test),
                                     **self._row_state(row.array[0])}
        return self.last_end

    def command(self, test_id: int, action: str, actor: str = "operator") -> None:
        """``stop`` (ramp-out) or ``abort`` (at once) the running test."""
        run = self.active
        if run is None or run.finished.is_set() or run.test_id != test_id:
            with self.sessions() as session:
                test = store.get_test(session, test_id)
                if test is None:
                    raise KeyError(test_id)
                if test.status == "running":
                    self._check_own_rig(test, action)
                raise Conflict(f"test {test_id} is {test.status}, not running; nothing to {action}")
        at_s = run.time_s  # one instant for the record and the stream (the run moves on while the write commits)
        with self.sessions() as session:
            store.add_event(session, test_id, "operator", f"{action} requested by {actor}", {"action": action},
                            actor=actor, time_s=at_s)
            session.commit()
        run.stopping = run.stopping or f"{action} requested by {actor}"
        self._publish_event(test_id, at_s, "operator", f"{action} requested by {actor}", {"action": action})
        with self._lock:  # one writer at a time on the command pipe
            try:
                run.commands.send(action)
            except (BrokenPipeError, OSError):
                pass
        if action == "abort":
            run.stop_requested = True
            # the worker stops at its next chunk (<= 20 ms); if it does not answer, end it
            threading.Thread(target=self._ensure_ended, args=(run, 2.0), daemon=True).start()

    def wait_ended(self, test_id: int, timeout_s: float) -> bool:
        """Wait (at most ``timeout_s``) until the run of ``test_id`` has ended: its final status committed and
        streamed, the rig free for the next test. True if it has (or is not the run in progress)."""
        run = self.active
        if run is None or run.test_id != test_id:
            return True
        return run.finished.wait(timeout_s)

    def _ensure_ended(self, run: ActiveRun, timeout_s: float) -> None:
        if not run.finished.wait(timeout_s) and run.process.is_alive():
            log.warning("worker of test %s did not answer an abort; terminating it", run.test_id)
            run.process.terminate()

    def shutdown(self, timeout_s: float = SHUTDOWN_GRACE_S) -> None:
        """Service shutdown (SIGTERM, SIGINT, docker stop): the running test is stopped under control, its table
        brought back to where the test began (``backend.worker.Run.shut_down``); it ends ``interrupted`` with
        that reason, and this returns once its records are stored. A worker that has not ended within
        ``timeout_s`` is aborted (valve closed at once), then terminated."""
        run = self.active
        if run is None or run.finished.is_set():
            return
        log.warning("the service is stopping: test %s is stopped under control, its table brought back, before "
                    "the service exits (up to %.0f s)", run.test_id, timeout_s)
        run.stop_requested = True
        run.shutdown = True
        run.stopping = run.stopping or "the service is stopping"
        with self._lock, contextlib.suppress(BrokenPipeError, OSError):
            run.commands.send("shutdown")
        if run.finished.wait(timeout_s):
            return
        log.warning("test %s did not end within %.0f s of the shutdown: aborting it", run.test_id, timeout_s)
        with self._lock, contextlib.suppress(BrokenPipeError, OSError):
            run.commands.send("abort")
        if not run.finished.wait(2.0) and run.process.is_alive():
            run.process.terminate()
            run.finished.wait(5.0)

    # --- reader and writer threads ------------------------------------------------------------------
    # The reader streams what the worker sends to the hub at once and hands it to the writer, which stores
    # it. Disk stalls (commits, WAL checkpoints, a slow PostgreSQL) therefore never delay the live stream,
    # and a slow stream never delays the store.

    def _status_message(self, run: ActiveRun, record: dict, status: str, reason: str | None = None) -> dict:
        cycles_total, duration_s = record["cycles_total"], record["duration_s"]
        cycle = run.cycles_done if status != "running" else min(run.cycles_done + 1, cycles_total)
        end_s = run.ends_at_s if run.ends_at_s is not None else duration_s  # a stop's ramp-out ends it sooner
        msg = {"type": "status", "test_id": run.test_id, "status": status, "time_s": run.time_s,
               "progress": min(1.0, run.time_s / duration_s) if duration_s else 0.0, "cycle": cycle,
               "cycles_total": cycles_total,
               "time_left_s": max(0.0, end_s - run.time_s) / record["speed"] if status == "running" else 0.0}
        if reason:
            msg["reason"] = reason
        if run.link:
            msg["link"] = run.link
        if run.stability is not None:
            msg["stability"] = live_stability(run.stability)
        return msg

    def _record(self, run: ActiveRun, record: dict) -> None:
        """Reader thread: pipe -> hub (at once) and -> writer queue."""
        test_id = run.test_id
        speed = record["speed"]
        writes: queue.SimpleQueue = queue.SimpleQueue()
        writer = threading.Thread(target=self._write, args=(run, record, writes), daemon=True,
                                  name=f"isorig-writer-{test_id}")
        writer.start()
        last_status = 0.0
        labels = sample_labels(record.get("controller"))  # what the columns hold for this test's controller
        self.hub.publish_threadsafe(self._status_message(run, record, "running"))
        try:
            while True:
                try:
                    if not run.out.poll(0.1):
                        if not run.process.is_alive() and not run.out.poll(0):
                            break
                        continue
                    kind, payload = run.out.recv()
                except (EOFError, OSError):
                    break
                if kind == "samples":
                    rows = payload
                    if run.wall_t0 is not None:  # how late the newest sample reaches the server (diagnostics)
                        due = run.wall_t0 + (float(rows[-1, 0]) + CONTROL_PERIOD_S) / speed
                        run.arrival_ms.append((time.time() - due) * 1e3)
                    run.time_s = float(rows[-1, 0])
                    run.last_row = rows[-1].copy()
                    frame = {"type": "samples", "test_id": test_id, "seq": self.hub_seq(test_id),
                             "columns": list(CSV_FIELDS), "labels": labels,
                             "rows": rows[:, : len(CSV_FIELDS)].tolist()}
                    if run.stability is not None:  # the worker sent it just before these samples
                        frame["stability"] = live_stability(run.stability)
                    if run.structure is not None and len(run.structure["rows"]) == len(rows):
                        frame["structure"] = {"columns": run.structure["columns"],
                                              "rows": run.structure["rows"].tolist()}
                    run.structure = None
                    self.hub.publish_threadsafe(frame)
                    now = time.monotonic()
                    if now - last_status >= STATUS_INTERVAL_S:
                        last_status = now
                        self.hub.publish_threadsafe(self._status_message(run, record, "running"))
                elif kind == "started":
                    run.wall_t0 = payload["wall_t0"]
                elif kind == "link":
                    run.link = store.clean_json(payload)
                    continue  # shown live, not stored (the final figures go into the summary)
                elif kind == "hybrid":  # streamed with the next samples (and the monitor in the status), not
                    run.stability = store.clean_json({**payload["monitor"], "time_s": payload["time_s"]})  # stored:
                    run.structure = payload  # the last monitor goes into the summary; the structure is replayed
                    # from the record (sim.hybrid.replay)
                    continue
                elif kind == "cycle":
                    payload = cycle_with_metrics(payload)
                    run.cycles_done = payload["cycle"]
                    self.hub.publish_threadsafe({
                        "type": "cycle", "test_id": test_id, "cycle": payload["cycle"], "phase": payload.get("phase"),
                        "metrics": store.clean_json(payload["metrics"]),
                        "loop": {"displacement_m": payload["displacement_m"].tolist(),
                                 "force_n": payload["force_n"].tolist()}})
                elif kind == "event":
                    if payload["kind"] == "limit_trip" and run.stopping is None:
                        run.stopping = payload["message"]
                    if (payload["values"] or {}).get("ends_at_s") is not None:
                        run.ends_at_s = float(payload["values"]["ends_at_s"])
                    self._publish_event(test_id, payload["time_s"], payload["kind"], payload["message"],
                                        payload["values"])
                writes.put((kind, payload))
                if kind == "finished":
                    return
        except Exception as exc:  # the reader must never die silently: end the test as failed
            log.exception("stream reader of test %s failed", test_id)
            writes.put(("finished", {"status": "failed", "reason": f"stream error: {type(exc).__name__}: {exc}",
                                     "pacing": {}}))
            with contextlib.suppress(OSError):
                run.commands.send("abort")
            return
        finally:
            writes.put(("end", None))
        return

    def _write(self, run: ActiveRun, record: dict, writes: queue.SimpleQueue) -> None:
        """Writer thread: stores samples in chunks (committed at least every ``commit_interval_s``), cycles,
        events, and at the end the summary and the final status."""
        test_id = run.test_id
        interval = self.settings.commit_interval_s
        session = self.sessions()
        pending: list[np.ndarray] = []
        pending_rows = 0
        last_commit = time.monotonic()
        final = None
        indications: dict = {}

        def flush() -> None:
            nonlocal pending, pending_rows, last_commit
            if pending:
                rows = np.concatenate(pending)
                test = store.get_test(session, test_id)
                for i in range(0, rows.shape[0], MAX_CHUNK_ROWS):
                    store.append_samples(session, test, rows[i: i + MAX_CHUNK_ROWS])
                pending, pending_rows = [], 0
            session.commit()
            last_commit = time.monotonic()

        try:
            while True:
                try:
                    kind, payload = writes.get(timeout=max(0.01, interval - (time.monotonic() - last_commit)))
                except queue.Empty:
                    if pending:
                        flush()
                    else:
                        last_commit = time.monotonic()
                    continue
                if kind == "samples":
                    pending.append(payload)
                    pending_rows += payload.shape[0]
                    if pending_rows >= MAX_CHUNK_ROWS or time.monotonic() - last_commit >= interval:
                        flush()
                elif kind == "started":
                    test = store.get_test(session, test_id)
                    test.started_at = datetime.fromtimestamp(payload["wall_t0"], UTC)
                    session.commit()
                elif kind == "cycle":
                    flush()
                    store.add_cycle(session, test_id, payload["cycle"], payload["block"], payload["t_start_s"],
                                    payload["t_end_s"], payload["metrics"], payload["displacement_m"],
                                    payload["force_n"], payload.get("phase"))
                    session.commit()
                elif kind == "event":
                    flush()
                    store.add_event(session, test_id, payload["kind"], payload["message"], payload["values"],
                                    time_s=payload["time_s"])
                    session.commit()
                elif kind == "finished":
                    final = payload
                elif kind == "end":
                    break
        except Exception as exc:
            log.exception("writer of test %s failed", test_id)
            session.rollback()
            final = {"status": "failed", "reason": f"storage error: {type(exc).__name__}: {exc}", "pacing": {}}
            with contextlib.suppress(OSError):
                run.commands.send("abort")
        try:
            flush()
            run.process.join(timeout=5.0)
            if final is None:
                code = run.process.exitcode
                if run.shutdown:
                    status, reason = "interrupted", "the service shut down while the test was running"
                else:
                    status, reason = "aborted", (f"the worker process ended unexpectedly (exit code {code}) at "
                                                 f"t = {run.time_s:.3f} s; samples up to then are kept")
                pacing = {}
            else:
                status, reason, pacing = final["status"], final["reason"], final.get("pacing", {})
                indications = final.get("limit_indications") or {}
                if final.get("link"):
                    run.link = store.clean_json({**final["link"], "lost_periods": final.get("lost_periods", 0)})
                    self.last_link = {"test_id": test_id, **run.link}
                if run.shutdown and status == "aborted":
                    status, reason = "interrupted", f"the service shut down while the test was running: {reason}"
            test = store.get_test(session, test_id)
            if run.arrival_ms:
                pacing = {**pacing, "server_arrival_p50_ms": float(np.percentile(run.arrival_ms, 50)),
                          "server_arrival_p95_ms": float(np.percentile(run.arrival_ms, 95)),
                          "server_arrival_max_ms": float(np.max(run.arrival_ms))}
            test.summary = self._summary(session, test, run.job, pacing, run.link, indications, run.stability)
            self.last_end = {"test_id": test_id, "status": status, "what": _source_word(test),
                             **self._row_state(run.last_row)}
            store.set_status(session, test, status, reason)
            verdict = protocol_verdict(session, test)  # once the status is final (an early end: INCOMPLETE)
            if verdict is not None:
                test.summary = {**test.summary, "acceptance": verdict}
            message = f"{_what(test)} {test_id} {status}" + (f": {reason}" if reason else "")
            store.add_event(session, test_id, "status", message, {"status": status, "time_s": run.time_s},
                            time_s=run.time_s)
            after = []
            for hook in self.end_hooks:
                try:
                    then = hook(session, test, status, reason)
                except Exception:  # never lose the end of a run over what follows it
                    log.exception("end hook of test %s", test_id)
                    then = None
                if then is not None:
                    after.append(then)
            session.commit()
            self._publish_event(test_id, run.time_s, "status", message, {"status": status})
            self.hub.publish_threadsafe(self._status_message(run, record, status, reason))
            for then in after:
                then()
        except Exception:
            log.exception("could not record the end of test %s", test_id)
        finally:
            session.close()
            if run.process.is_alive():  # never leave a worker running once its test is closed
                run.process.terminate()
                run.process.join(2.0)
                if run.process.is_alive():  # SIGTERM is handled in Python: a worker stuck below it is killed
                    run.process.kill()
                    run.process.join(2.0)
            for conn in (run.out, run.commands):
                with contextlib.suppress(OSError):
                    conn.close()
            run.finished.set()

    def hub_seq(self, test_id: int) -> int:
        self._seq[test_id] = self._seq.get(test_id, 0) + 1
        return self._seq[test_id]

    def publish_event(self, test_id: int, time_s: float | None, kind: str, message: str, values: dict) -> None:
        """Stream an event of a test to every console (the caller stores it)."""
        self._publish_event(test_id, time_s, kind, message, values)

    def _publish_event(self, test_id: int, time_s: float | None, kind: str, message: str, values: dict) -> None:
        self.hub.publish_threadsafe({"type": "event", "test_id": test_id, "time_s": time_s, "kind": kind,
                                     "message": message, "values": store.clean_json(values)})

    def _summary(self, session: Session, test, job: dict, pacing: dict, link: dict,
                 indications: dict | None = None, stability: dict | None = None) -> dict:
        """Tracking figures (sim.tracking) and the tracking verdict (sim.follow), loop-metric means over the steady
        cycles (sim.metrics), pacing, the periods lost on the link and its health, how often each indicating
        limit was exceeded; for a history or hybrid test the J criteria with their targets, and for a hybrid test
        the structure against its reference and the stability monitor (sim.earthquake.record_figures)."""
        samples = store.load_samples(session, test.id)
        scenario: Scenario = scenario_from_job(job)
        closed = samples[np.isfinite(samples["target_m"])]
        summary: dict = {"samples": len(samples), "pacing": pacing,
                         "storage_bytes": store.storage_bytes(session, test.id),
                         "lost_periods": lost_periods(samples)}
        if link:
            summary["link"] = link
        if indications:
            summary["limit_indications"] = indications
        if len(closed):
            tracking = tracking_summary(closed, scenario)
            tracking.pop("samples", None)
            tracking.pop("lost_periods", None)  # the summary's own lost_periods counts the whole record
            summary["tracking"] = tracking
        cycles = store.load_cycles(session, test.id, arrays=False)
        headline = headline_figures(cycles)
        summary["cycles_done"] = len(cycles)
        summary["steady_cycles"] = headline["steady_cycles"]
        summary["excluded_cycles"] = headline["excluded_cycles"]
        summary["loop_metrics_mean"] = headline["means"]  # over the steady cycles only (sim.metrics)
        if job["scenario"].get("earthquake") is not None:
            summary.update(self._earthquake_summary(session, test, job, samples, stability))
        verdict = tracking_verdict(samples, scenario.profile, summary.get("criteria") if not scenario.profile
                                   else None, advice=advice_for(scenario.controller),
                                   latency_s=scenario.rig.position_latency_s,
                                   commissioning=scenario.rig_commissioning)
        # the CLI's words (sim.engine.said_indicate): set to indicate, the detector stopped nothing
        follow_action = SafetyLimits.from_dict(job["limits"]).action(FOLLOW_KEY) if job.get("limits") else None
        summary["tracking_verdict"] = said_indicate(verdict, follow_action,
                                                    (indications or {}).get(FOLLOW_KEY, 0))
        return store.clean_json(summary)

    @staticmethod
    def _earthquake_summary(session: Session, test, job: dict, samples: Samples, stability: dict | None) -> dict:
        """``criteria`` (J1-J3, J1-J5 for a hybrid test), ``stability`` (hybrid: the live monitor's last state)
        and ``earthquake`` (verdicts with their targets, what was judged, peaks; hybrid: the structure's peaks
        beside the reference's, the replay): sim.earthquake.record_figures on the stored samples."""
        from sim.earthquake import early_end_time_s, record_figures

        from .worker import earthquake_from_job

        try:
            profile = earthquake_from_job(job)
            figures = record_figures(profile, scenario_isolator(job), samples,
                                     end_time_s=early_end_time_s(store.load_events(session, test.id)),
                                     stability=stability)
        except Exception as exc:  # never lose the end of a test over its figures
            log.exception("earthquake figures of test %s", test.id)
            return {"earthquake": {"error": f"{type(exc).__name__}: {exc}"}}
        out = {"criteria": figures.pop("criteria")}
        if "stability" in figures:
            out["stability"] = figures.pop("stability")
        out["earthquake"] = figures
        return out


def protocol_verdict(session: Session, test) -> dict | None:
    """A protocol test's verdict for its summary (the word, how many checks, how many failed), from its stored
    cycles (backend.reports.content.protocol_acceptance); None for another test or without reports."""
    if ((test.request or {}).get("profile") or {}).get("kind") != "protocol":
        return None
    try:
        from .reports.content import protocol_acceptance

        out = protocol_acceptance(store.test_record(session, test, with_events=False),
                                  store.load_cycles(session, test.id, arrays=False))
    except ImportError:
        return None
    except Exception:  # never lose the end of a test over its verdict
        log.exception("acceptance of test %s", test.id)
        return None
    if out is None:
        return None
    return store.clean_json({"verdict": out["verdict"], **{k: out["summary"][k] for k in ("verdicts", "failed")}})


def scenario_isolator(job: dict):
    from sim.isolator import isolator_from_dict

    return isolator_from_dict(job["scenario"]["isolator"])


LIVE_STABILITY_KEYS = ("time_s", "indicator", "ratio", "added_energy_j", "limit_j", "reference_energy_j", "tripped")


def live_stability(monitor: dict) -> dict:
    """What the live stream carries of the stability monitor (sim.hybrid_metrics.EnergyMonitor): ``indicator``
    (E_err / limit: the monitor trips at 1), ``ratio`` (E_err / the reference energy), E_err, the limit and the
    reference energy in J, ``tripped`` and the test time it is for."""
    return {k: monitor.get(k) for k in LIVE_STABILITY_KEYS}
