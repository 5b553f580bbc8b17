"""The renderer warmed up once per process, in the background, when the service starts.

The first report of a process pays for what every later one finds ready (profiled on a stored 10-minute sine
test, scripts/bench_report.py): importing matplotlib and pyplot, scipy.optimize and the Bouc-Wen fit, loading
numba's cached kernels of the fit and the isolator model, and matplotlib's first PDF: finding and reading the
core fonts in every size and weight the pages use, its text layout caches. A page of a few texts left most of
that to the first report; ``warm_up`` makes a whole report of a small record instead. backend.app runs
``warm_once`` in a daemon thread when the service starts (the setting ``report_warm_up``), with an event set when
it ends for a benchmark or a test to wait for. Once per process: a second service in the same process (the
tests) finds it done. This module is imported in that thread, not at the service's start (backend.reports costs
0.3 s to import).
"""

from __future__ import annotations

import io
import logging
import threading
import time

log = logging.getLogger("isorig.reports")

_LOCK = threading.Lock()
WARM_TIME = {"done": False, "s": None}  # whether the warm-up has run in this process, and how long it took (s)


WARM_CYCLES, WARM_AMPLITUDE_M, WARM_FREQUENCY_HZ, WARM_DT_S = 32, 0.02, 1.0, 1e-3  # > 30 s: every page kind


def warm_bundle():
    """A small sine record of the isolator model alone (IUT_a's Bouc-Wen force under a 20 mm, 1 Hz sine; no rig,
    no engine), with the record, cycles and events a stored test has: what warm_up reports on."""
    import numpy as np

    from sim.isolator import PRESETS, simulate_loop
    from sim.metrics import cycle_metrics
    from sim.samples import Samples

    from .data import ReportBundle

    iso = PRESETS["IUT_a"]
    t = np.arange(int(WARM_CYCLES / WARM_FREQUENCY_HZ / WARM_DT_S) + 1) * WARM_DT_S
    d = WARM_AMPLITUDE_M * np.sin(2 * np.pi * WARM_FREQUENCY_HZ * t)
    samples = Samples.empty(t.size)
    for name, column in (("time_s", t), ("target_m", d), ("displacement_m", d), ("measured_displacement_m", d),
                         ("force_n", simulate_loop(iso, d, WARM_DT_S)), ("voltage_v", 0.1 * np.cos(t))):
        samples[name][:] = column
    cycles = cycle_metrics(t, d, samples["force_n"], list(np.arange(WARM_CYCLES) / WARM_FREQUENCY_HZ),
                           WARM_CYCLES / WARM_FREQUENCY_HZ)
    for c in cycles:
        c["phase"] = "taper_in" if c["cycle"] == 1 else ("taper_out" if c["cycle"] == WARM_CYCLES else "steady")
        c["displacement_m"] = d[c["i_start"]:c["i_end"] + 1]
        c["force_n"] = samples["force_n"][c["i_start"]:c["i_end"] + 1]
    profile = {"kind": "sine", "amplitude_m": WARM_AMPLITUDE_M, "frequency_hz": WARM_FREQUENCY_HZ,
               "cycles": WARM_CYCLES, "taper_cycles": 1, "offset_m": 0.0}
    record = {"id": 0, "label": "warm-up", "status": "completed", "isolator": iso.name, "supply_bar": 100.0,
              "vertical_load_n": 1e5, "controller": "servo", "driver": "simulated", "profile": profile,
              "duration_s": float(t[-1]), "cycles_total": WARM_CYCLES, "cycles_done": len(cycles),
              "limits": {"displacement_m": 0.15, "force_n": 5e5},
              "scenario": {"isolator": iso.to_dict(), "profile": [profile], "control_period_s": WARM_DT_S}}
    events = [{"kind": "limit_indicate", "time_s": 1.0, "message": "warm-up",
               "values": {"displacement_m": 0.02, "force_n": 3e4, "limit": 0.015, "limit_name": "displacement_m"}}]
    return ReportBundle(record, samples, cycles, events)


def warm_up() -> None:
    """Make a whole report of a small record (warm_bundle), Bouc-Wen fit included, into memory: every import,
    kernel, font and cache a report uses is then ready (seconds the first time in a process)."""
    from .document import render_report_pdf
    from .lab import lab_header

    render_report_pdf(warm_bundle(), io.BytesIO(), lab=lab_header(use_settings=False))


def warm_once() -> float | None:
    """warm_up, once per process: later calls wait for the first one and return at once. Returns how long the
    warm-up took (None if it failed: the first report then takes longer, nothing else).

    Not at a lower CPU priority: the thread shares the GIL with the service's threads, and a thread the system
    runs last while it holds the GIL would hold them up the longer."""
    with _LOCK:
        if WARM_TIME["done"]:
            return WARM_TIME["s"]
        t0 = time.perf_counter()
        try:
            warm_up()
            WARM_TIME["s"] = time.perf_counter() - t0
            log.info("report renderer warmed up in %.2f s", WARM_TIME["s"])
        except Exception:  # noqa: BLE001 - a failed warm-up costs the first report its time, never the service
            log.warning("the report renderer could not be warmed up; the first report will take longer",
                        exc_info=True)
        WARM_TIME["done"] = True
        return WARM_TIME["s"]


def warm_store(sessions) -> None:
    """The store's queries of a report made once (statements compiled, one stored cycle and event read: the ORM's
    first objects), so the first report does not pay for them (0.3-0.5 s of its load, measured under load)."""
    from sqlalchemy import select

    from .. import store
    from ..models import CycleRecord

    with sessions() as session:
        newest = session.scalars(select(CycleRecord.test_id).order_by(CycleRecord.id.desc()).limit(1)).first()
        test_id = newest if newest is not None else 0
        store.load_events(session, test_id)
        store.load_samples(session, 0)  # the query only: a test's samples may be hundreds of MB
        session.scalars(select(CycleRecord).where(CycleRecord.test_id == test_id).limit(1)).all()
        test = store.get_test(session, test_id)
        if test is not None:
            store.test_record(session, test)


def freeze_startup_objects() -> None:
    """Once the service has started and warmed up: the objects alive now (modules, matplotlib's font and text
    caches, the ORM's mappers; long-lived by nature) are moved out of the garbage collector's reach (gc.freeze),
    so that a collection during a report traverses only what is new. Without it, the first report of a service ran
    one full collection over all of them (scripts/bench_report.py prints the collector's time: 0.35-0.39 s of a
    2.33-2.80 s first report, against 0.03-0.04 s with it; docs/reports.md). Objects frozen here are never
    collected: what the start made, and whatever a request in flight at that moment holds."""
    import gc

    gc.collect()
    gc.freeze()

