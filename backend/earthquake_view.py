"""``GET /api/tests/{id}/earthquake`` away from the service's event loop: rebuilding a history or hybrid test's
profile and its figures (the structure replayed from the record, the reference computed again) takes seconds of CPU
for a long test (measured: 1.5-4.2 s for a 60 s hybrid test, each time it was asked), and anyone who reaches the
console may ask, as often as they like. Here:

* the work runs in the check pool (backend.checks: a few worker processes, 503 with Retry-After when busy), which
  reads the test from the database itself, so the service's process holds neither the GIL nor the arrays;
* the answer for a test that has ended is kept (``ViewCache``: as JSON, the least recently asked dropped beyond
  ``CACHE_BYTES``): an ended test's record does not change, so asking again costs nothing;
* a database the workers cannot open (SQLite in memory) is served in the service's process, as before.
"""

from __future__ import annotations

import json
import threading
from collections import OrderedDict

import numpy as np
from fastapi.responses import Response
from sqlalchemy.engine import make_url

from . import db, store
from .errors import ApiError
from .store import clean_json

CACHE_BYTES = 32 * 1024**2  # the answers kept, as JSON (a 60 s hybrid test at 2000 points: 1.1 MB)
_ENGINES: dict = {}  # in a pool worker: one engine per database URL, made at its first job


class ViewCache:
    """Answers (JSON bytes) by key, at most ``max_bytes`` in all, the least recently used dropped first."""

    def __init__(self, max_bytes: int = CACHE_BYTES):
        self.max_bytes = max_bytes
        self.bytes = 0
        self._items: OrderedDict = OrderedDict()
        self._lock = threading.Lock()

    def get(self, key) -> bytes | None:
        with self._lock:
            value = self._items.get(key)
            if value is not None:
                self._items.move_to_end(key)
            return value

    def put(self, key, value: bytes) -> None:
        if len(value) > self.max_bytes:
            return
        with self._lock:
            old = self._items.pop(key, None)
            self.bytes += len(value) - (len(old) if old is not None else 0)
            self._items[key] = value
            while self.bytes > self.max_bytes:
                _, dropped = self._items.popitem(last=False)
                self.bytes -= len(dropped)


def answer(app, session, test, points: int) -> Response:
    """The answer of ``GET /api/tests/{id}/earthquake`` for ``test`` (known to exist): 422 for a test that is not a
    history or hybrid test, else from the cache, or computed in the check pool (kept if the test has ended)."""
    job_scenario = (test.request or {}).get("job_scenario") or {}
    if job_scenario.get("earthquake") is None:
        raise ApiError(422, f"test {test.id} is not a history or hybrid test", "test_id", test.id,
                       "a test with a profile of kind history or hybrid")
    cache = app.state.__dict__.setdefault("earthquake_views", ViewCache())
    key = (test.id, points, test.status, test.samples_stored)
    body = cache.get(key)
    if body is None:
        url = app.state.settings.resolved_database_url
        if _shared(url):
            body = app.state.checks.run("rebuild an earthquake test's figures", view_in_worker, url, test.id, points)
        else:
            body = _json(clean_json(view(session, test.id, points)))
        if test.status not in ("ready", "running"):
            cache.put(key, body)
    return Response(body, media_type="application/json")


def _shared(url: str) -> bool:
    """Can another process open this database? (Not SQLite in memory.)"""
    parsed = make_url(url)
    return not (parsed.get_backend_name() == "sqlite" and (not parsed.database or parsed.database == ":memory:"
                                                          or "mode=memory" in str(parsed)))


def _json(out: dict) -> bytes:
    return json.dumps(out, separators=(",", ":"), allow_nan=False).encode()


def view_in_worker(url: str, test_id: int, points: int) -> bytes:
    """In a check-pool worker: the answer as JSON, read from the database at ``url``."""
    engine = _ENGINES.get(url)
    if engine is None:
        engine = _ENGINES[url] = db.make_engine(url)
    with db.session_factory(engine)() as session:
        return _json(clean_json(view(session, test_id, points)))


def _thinned(values, step: int) -> list:
    return clean_json(np.asarray(values, dtype=float)[::step].tolist())


def view(session, test_id: int, points: int) -> dict:
    """The answer itself (see the route's docstring in backend.api.tests)."""
    test = store.get_test(session, test_id)
    job_scenario = (test.request or {}).get("job_scenario") or {}
    from .worker import earthquake_from_job

    try:
        profile = earthquake_from_job({"scenario": job_scenario})
    except ValueError as exc:
        raise ApiError(409, f"the profile of test {test_id} cannot be rebuilt: {exc}") from None
    n = profile.target.n_samples
    step = max(1, -(-n // points))
    planned = {"time_s": _thinned(profile.target.time_s, step), "target_m": _thinned(profile.target.r_m, step)}
    if profile.ground_acc_m_per_s2 is not None:  # 0 after the record (a hybrid test's rest), sample for sample
        ag = np.zeros(n)
        m = min(n, profile.ground_acc_m_per_s2.size)
        ag[:m] = profile.ground_acc_m_per_s2[:m]
        planned["ground_acc_m_per_s2"] = _thinned(ag, step)
    out = {"test_id": test_id, "kind": profile.kind, "status": test.status,
           "profile": clean_json(profile.description), "planned": planned, "record": None}
    if not test.samples_stored:
        return out
    if test.status == "running":  # the record so far (a page that joins late), no figures: the worker has the CPU
        s = store.load_samples(session, test_id)
        out["so_far"] = {"time_s": _thinned(s["time_s"], step), "target_m": _thinned(s["target_m"], step),
                         "displacement_m": _thinned(s["displacement_m"], step)}
        return out
    from .reports.content import earthquake_figures

    bundle = store.load_test_bundle(session, test_id)
    figures = earthquake_figures(bundle)
    if figures is None:
        return out
    record = {k: v for k, v in figures.items() if k not in ("arrays", "profile")}
    s = bundle.samples
    step = max(1, -(-len(s) // points))
    series = {"time_s": _thinned(s["time_s"], step), "target_m": _thinned(s["target_m"], step),
              "displacement_m": _thinned(s["displacement_m"], step), "force_n": _thinned(s["force_n"], step)}
    arrays = figures.get("arrays") or {}
    if arrays.get("structure") is not None:
        t_s = arrays["structure_time_s"]
        k = max(1, -(-len(t_s) // points))
        series["structure"] = {"time_s": _thinned(t_s, k),
                               **{name: _thinned(v, k) for name, v in arrays["structure"].items()}}
        whole = arrays["reference_whole"]
        m = len(next(iter(whole.values())))
        k = max(1, -(-m // points))
        series["reference"] = {"time_s": _thinned(np.arange(m) * profile.target.dt_s, k),
                               **{name: _thinned(v, k) for name, v in whole.items()}}
        series["stability"] = {"time_s": _thinned(t_s, max(1, -(-len(t_s) // points))),
                               "added_energy_j": _thinned(arrays["added_energy_j"], max(1, -(-len(t_s) // points))),
                               "limit_j": _thinned(arrays["limit_j"], max(1, -(-len(t_s) // points)))}
    out["record"] = {**clean_json(record), "series": series}
    return out
