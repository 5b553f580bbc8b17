"""A small pool of processes for the heavy work anyone may ask for without the token.

``POST /api/tests/check`` with a history or hybrid profile builds the whole profile (the isolator's demand under a
ground motion, a hybrid test's reference: seconds of CPU for a long record, hundreds of MB for a 200 000-sample
one), and ``POST /api/ground-motions/read-at2`` parses a file of up to ``MAX_AT2_CHARS``. Done in the service's own
process, four such requests at once held a GIL the event loop needs and left the process at 760 MB. Here:

* at most ``check_workers`` jobs run at once, each in a worker process forked from the service's forkserver (the
  engine preloaded; the API modules a job needs are imported once per worker, when the pool is made: the first
  heavy check after a start waits for that, a few seconds; a pool that replaces a retired one is made at once);
* at most ``check_queue`` more wait for one; beyond that the answer is **503** with ``Retry-After`` and a message
  saying how many such requests run at a time;
* a body larger than ``BIG_BODY_BYTES`` on these routes (an inline record: parsing and validating 6 MB of JSON
  takes the event loop a few hundred ms) is admitted before it is read, ``check_workers + check_queue`` at a time
  (``HeavyBodyGate``); beyond, the same 503 at once, the body never read;
* after every job the worker collects its garbage and hands freed heap back to the system (``malloc_trim``); a
  worker still larger than ``check_worker_max_rss_bytes`` is retired (its memory goes when it exits) and a fresh,
  warmed pool takes its place. The service's own process never holds a job's arrays.

The API modules are not preloaded into the forkserver itself: the rig worker is forked from it too, and with them
loaded a worker on a UDP rig missed the rig's 18 ms watchdog right after ARM (tests/backend/test_udp_rig.py).

Exceptions raised in a worker (an input refused with its field) come back as they were raised and meet the
service's exception handlers like any other.
"""

from __future__ import annotations

import ctypes
import gc
import json
import logging
import os
import threading
from concurrent.futures import ProcessPoolExecutor
from concurrent.futures.process import BrokenProcessPool

from sim.errors import rebuilt_exception

from .errors import ApiError

log = logging.getLogger("isorig")

RETRY_AFTER_S = 2
BIG_BODY_BYTES = 1024 * 1024  # a body this large on a heavy route is an inline record: admitted before it is read
HEAVY_ROUTES = frozenset({"/api/tests/check", "/api/ground-motions/read-at2"})


# what the jobs run; imported by each worker
JOB_MODULES = ("backend.api.tests", "backend.api.ground_motions", "backend.earthquake_view")


def _warm(modules: tuple[str, ...], service_pid: int | None = None) -> None:
    """A worker's initializer: end with the service (backend.children: kill -9 of the service left the workers
    behind, waiting on their queue), then import what the jobs need once (seconds), before the first job."""
    import importlib

    if service_pid is not None:
        from .children import exit_with

        exit_with(service_pid)
    for name in modules:
        importlib.import_module(name)


def _noop() -> None:
    return None


def _rss_bytes() -> int:
    try:
        with open("/proc/self/statm") as fh:
            return int(fh.read().split()[1]) * os.sysconf("SC_PAGE_SIZE")
    except (OSError, ValueError, IndexError):
        return 0


def _trim() -> None:
    """Collect garbage and give freed heap back to the system (glibc's malloc_trim; elsewhere nothing)."""
    gc.collect()
    try:
        ctypes.CDLL("libc.so.6").malloc_trim(0)
    except (OSError, AttributeError):
        pass


def _call(fn, args, trim=True):
    """In the worker: fn(*args), or what it raised in a form that survives pickling (an exception whose
    ``__init__`` takes other arguments than its message does not, unless it says how, as sim.errors.FieldError
    does); then the worker's size once its garbage is returned (``trim`` False: a small job, whose answer should
    not wait the 0.2-0.5 s of a full collection; the size still retires a worker grown too large)."""
    try:
        result = "ok", fn(*args)
    except Exception as exc:  # noqa: BLE001 - handed to the service as raised
        result = "raised", (type(exc), exc.args, dict(exc.__dict__), str(exc))
    if trim:
        _trim()
    return (*result, _rss_bytes())


def _rebuild(kind: type, args: tuple, state: dict, text: str) -> BaseException:
    try:
        return rebuilt_exception(kind, args, state)
    except Exception:  # noqa: BLE001 - a class that cannot be rebuilt: its message at least
        return RuntimeError(f"{kind.__name__}: {text}")


class CheckPool:
    """Bounded: ``workers`` processes, ``queue`` waiting requests, refusals (503) beyond; a worker larger than
    ``max_rss_bytes`` after a job is retired."""

    def __init__(self, context, workers: int, queue: int, max_rss_bytes: int = 512 * 1024**2,
                 modules: tuple[str, ...] = JOB_MODULES):
        self.context = context  # a callable giving the multiprocessing context (the service's, forkserver)
        self.workers = workers
        self.capacity = workers + queue
        self.max_rss_bytes = max_rss_bytes
        self.modules = modules
        self.in_flight = 0
        self.admitted = 0  # big bodies admitted by HeavyBodyGate, being read or checked
        self.retired = 0  # pools retired for their size (diagnostics, tests)
        self._lock = threading.Lock()
        self._executor: ProcessPoolExecutor | None = None

    def _pool(self) -> ProcessPoolExecutor:
        """The executor (made and warmed if there is none). Called with the lock held."""
        if self._executor is None:
            self._executor = ProcessPoolExecutor(max_workers=self.workers, mp_context=self.context(),
                                                 initializer=_warm, initargs=(self.modules, os.getpid()))
            for _ in range(self.workers):  # start the workers and their imports now, not at the next request
                self._executor.submit(_noop)
        return self._executor

    def _retire(self, pool: ProcessPoolExecutor, fresh: bool) -> None:
        with self._lock:
            if self._executor is pool:
                self._executor = None
                if fresh:
                    self._pool()
        pool.shutdown(wait=False, cancel_futures=not fresh)

    def run(self, what: str, fn, *args, small: bool = False):
        """fn(*args) in a worker process; ApiError 503 if ``capacity`` such jobs are running or waiting.
        ``small``: a job of a few small arrays (a test's first cycle): no collection after it."""
        with self._lock:
            if self.in_flight >= self.capacity:
                raise ApiError(503, f"the service is busy with {self.in_flight} other requests that {what} (at most "
                                    f"{self.workers} at a time, {self.capacity - self.workers} waiting: "
                                    "check_workers, check_queue); try again in a few seconds",
                               headers={"Retry-After": str(RETRY_AFTER_S)})
            self.in_flight += 1
            pool = self._pool()
        try:
            status, value, rss = pool.submit(_call, fn, args, not small).result()
        except BrokenProcessPool:
            log.warning("a check worker process died; starting a new pool")
            self._retire(pool, fresh=False)
            raise ApiError(503, f"the worker that was to {what} ended unexpectedly (out of memory?); try again",
                           headers={"Retry-After": str(RETRY_AFTER_S)}) from None
        finally:
            with self._lock:
                self.in_flight -= 1
        if rss > self.max_rss_bytes:  # what the job left behind goes with the process
            log.info("a check worker is %.0f MB after a job (more than %.0f MB): retired", rss / 1e6,
                     self.max_rss_bytes / 1e6)
            self.retired += 1
            self._retire(pool, fresh=True)
        if status == "raised":
            raise _rebuild(*value)
        return value

    def admit(self) -> bool:
        """A big body may be read (HeavyBodyGate): True and counted, or False if ``capacity`` are already."""
        with self._lock:
            if self.admitted >= self.capacity:
                return False
            self.admitted += 1
            return True

    def release(self) -> None:
        with self._lock:
            self.admitted -= 1

    def shutdown(self) -> None:
        with self._lock:
            pool, self._executor = self._executor, None
        if pool is not None:
            pool.shutdown(wait=False, cancel_futures=True)


class HeavyBodyGate:
    """Pure ASGI middleware: on the heavy routes, a body larger than ``BIG_BODY_BYTES`` (or chunked) is admitted
    before a byte of it is read, at most the pool's capacity at a time; beyond, 503 with Retry-After at once."""

    def __init__(self, app, pool: CheckPool):
        self.app = app
        self.pool = pool

    async def __call__(self, scope, receive, send) -> None:
        if scope["type"] != "http" or scope["method"] != "POST" or scope["path"] not in HEAVY_ROUTES:
            await self.app(scope, receive, send)
            return
        headers = dict(scope.get("headers") or ())
        length = headers.get(b"content-length")
        try:
            big = length is None and b"transfer-encoding" in headers or (length is not None
                                                                         and int(length) > BIG_BODY_BYTES)
        except ValueError:
            big = True
        if not big:
            await self.app(scope, receive, send)
            return
        if not self.pool.admit():
            pool = self.pool
            detail = (f"the service is busy with {pool.capacity} large requests (inline records over "
                      f"{BIG_BODY_BYTES} bytes) on {scope['path']}: at most {pool.workers} checked at a time and "
                      f"{pool.capacity - pool.workers} waiting (check_workers, check_queue); try again in a few "
                      "seconds")
            body = json.dumps({"detail": detail}).encode()
            await send({"type": "http.response.start", "status": 503,
                        "headers": [(b"content-type", b"application/json"),
                                    (b"retry-after", str(RETRY_AFTER_S).encode()),
                                    (b"content-length", str(len(body)).encode()), (b"connection", b"close")]})
            await send({"type": "http.response.body", "body": body})
            return
        try:
            await self.app(scope, receive, send)
        finally:
            self.pool.release()
