"""The first and the second report of a service, timed: a 10-minute sine test (600 cycles of 20 mm at 1 Hz on
IUT_a, 600 000 samples, 600 cycles with their loops) stored in a fresh SQLite store, then a service started on it
(backend.app.create_app, TestClient) and ``GET /api/tests/{id}/report.pdf`` asked twice.

It prints the wall time of each report and the CPU time the process spent meanwhile (on a loaded machine the wall
time says more about the other processes). The record is simulated once (about 10 s) and kept in ``--cache``
(default /tmp/isorig-bench-report/store.db). By default the timing starts once the service's background warm-up
of the renderer has ended (``app.state.report_warm``: the target is the first report on a warmed-up renderer);
``--no-wait`` asks at once. ``--profile FILE`` makes the two reports in this thread as the route does (the lab
header, the stored bundle, the PDF), not over HTTP, and writes a cProfile of each (FILE.1, FILE.2): the route's
own thread is not profiled.

    PYTHONPATH=$PWD python scripts/bench_report.py
"""

from __future__ import annotations

import argparse
import cProfile
import shutil
import sys
import tempfile
import time
from pathlib import Path

CYCLES, AMPLITUDE_M, FREQUENCY_HZ = 600, 0.02, 1.0


def store_sine_test(url: str) -> int:
    """Simulate the test and store it as the service would (samples in chunks, cycles with loops, completed)."""
    from backend import store
    from backend.db import make_engine, session_factory, upgrade
    from sim.engine import Scenario, Simulation
    from sim.isolator import PRESETS
    from sim.metrics import scenario_cycle_metrics
    from sim.profiles import SineProfile

    profile = SineProfile(AMPLITUDE_M, FREQUENCY_HZ, CYCLES, 1)
    scenario = Scenario(PRESETS["IUT_a"], 100e5, [profile], controller="servo")
    samples = Simulation(scenario).run().samples
    cycles = scenario_cycle_metrics(samples, scenario)
    engine = make_engine(url)
    upgrade(engine)
    with session_factory(engine)() as session:
        test = store.create_test(session, rig_name="rig-1", label="bench 10 min sine", isolator="IUT_a",
                                 supply_bar=100.0, controller="servo", speed=1.0, driver="simulated",
                                 request={"profile": profile.to_dict()}, scenario=scenario.describe(), limits={},
                                 duration_s=scenario.duration_s, cycles_total=CYCLES)
        for i in range(0, len(samples), 5000):
            store.append_samples(session, test, samples[i:i + 5000])
        for c in cycles:
            j = min(c["i_end"] + 1, len(samples))
            metrics = {k: v for k, v in c.items() if k not in ("cycle", "phase")}
            store.add_cycle(session, test.id, c["cycle"], 0, c["t_start_s"], c["t_end_s"], metrics,
                            samples["displacement_m"][c["i_start"]:j], samples["force_n"][c["i_start"]:j],
                            phase=c.get("phase"))
        store.set_status(session, test, "completed")
        session.commit()
        test_id = test.id
    engine.dispose()
    return test_id


class GcClock:
    """The time the garbage collector spent, and its full (generation 2) collections, while it is on."""

    def __init__(self):
        self.s, self.full, self._t0 = 0.0, 0, None

    def __call__(self, phase: str, info: dict) -> None:
        if phase == "start":
            self._t0 = time.perf_counter()
        elif self._t0 is not None:
            self.s += time.perf_counter() - self._t0
            self.full += info.get("generation") == 2
            self._t0 = None

    def __enter__(self):
        import gc

        gc.callbacks.append(self)
        return self

    def __exit__(self, *exc):
        import gc

        gc.callbacks.remove(self)


def report_here(app, test_id: int) -> bytes:
    """What GET /api/tests/{id}/report.pdf does (backend.api.tests.report_pdf), in this thread."""
    import io

    from backend import lab as lab_settings
    from backend import store
    from backend.reports import render_report_pdf

    buf = io.BytesIO()
    with app.state.sessions() as session:
        lab = lab_settings.header(session, app.state.settings)
        render_report_pdf(store.load_test_bundle(session, test_id), buf, lab=lab)
    return buf.getvalue()


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--cache", type=Path, default=Path(tempfile.gettempdir()) / "isorig-bench-report")
    ap.add_argument("--no-wait", action="store_true", help="ask at once, not after the renderer's warm-up")
    ap.add_argument("--profile", type=Path, help="write a cProfile of the first report here")
    args = ap.parse_args(argv)

    args.cache.mkdir(parents=True, exist_ok=True)
    kept = args.cache / "store.db"
    if not kept.exists():
        t0 = time.perf_counter()
        test_id = store_sine_test(f"sqlite:///{kept}.part")
        Path(f"{kept}.part").rename(kept)
        print(f"stored the 10-minute sine test (test {test_id}) in {time.perf_counter() - t0:.1f} s",
              file=sys.stderr)
    work = Path(tempfile.mkdtemp(prefix="isorig-bench-report-"))
    try:
        shutil.copy(kept, work / "isorig.db")
        from fastapi.testclient import TestClient

        from backend.app import create_app
        from backend.settings import Settings

        settings = Settings(data_dir=work, operator_token="bench-token", viewer=False, allowed_hosts="testserver")
        t_start = time.perf_counter()
        app = create_app(settings)
        with TestClient(app) as client:
            started = time.perf_counter() - t_start
            warm = getattr(app.state, "report_warm", None)
            waited = 0.0
            if warm is not None and not args.no_wait:
                t0 = time.perf_counter()
                warm.wait(60)
                waited = time.perf_counter() - t0
            test_id = client.get("/api/tests").json()[0]["id"]
            times, cpu, gcs = [], [], []
            for k in range(2):
                gc_clock = GcClock().__enter__()
                t0, c0 = time.perf_counter(), time.process_time()
                if args.profile:
                    profiler = cProfile.Profile()
                    profiler.enable()
                    size = len(report_here(app, test_id))
                    profiler.disable()
                    profiler.dump_stats(f"{args.profile}.{k + 1}")
                else:
                    r = client.get(f"/api/tests/{test_id}/report.pdf")
                    if r.status_code != 200 or r.content[:5] != b"%PDF-":
                        print(f"report {k + 1}: HTTP {r.status_code}: {r.text[:300]}", file=sys.stderr)
                        return 1
                    size = len(r.content)
                times.append(time.perf_counter() - t0)
                cpu.append(time.process_time() - c0)
                gc_clock.__exit__()
                gcs.append(gc_clock)
        print(f"service start {started:.2f} s; warm-up " + ("not waited for" if args.no_wait or warm is None
                                                             else f"waited {waited:.2f} s more"))
        print(f"first report {times[0]:.2f} s, second report {times[1]:.2f} s ({size} bytes)"
              + (f"; profiles in {args.profile}.1 and .2" if args.profile else ""))
        # CPU seconds of this process (every thread) while each report was made: what a loaded machine's wall
        # time cannot show (the warm-up, when not waited for, counts in the first)
        print(f"CPU: first report {cpu[0]:.2f} s, second report {cpu[1]:.2f} s; load average "
              f"{' '.join(open('/proc/loadavg').read().split()[:3])}")
        print("garbage collection: " + ", ".join(f"{name} report {g.s:.2f} s ({g.full} full)"
                                                 for name, g in zip(("first", "second"), gcs, strict=True)))
        return 0
    finally:
        shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    sys.exit(main())
