"""`isorig report`: the PDF test report (and optionally report.json) of a stored test or of a CSV record. An
approved record's report is the PDF kept at its approval (backend.review), written byte for byte with its SHA-256,
as the service serves it; it is never drawn again."""

from __future__ import annotations

import contextlib
import dataclasses
import gc
import json
import math
import os
import time
from pathlib import Path

from isorig.cli import UsageError

PROG = "isorig report"


def register(sub) -> None:
    p = sub.add_parser("report", help="PDF report (loops, per-cycle metrics, verdicts) of a stored test or a CSV",
                       description="Render the A4 PDF report of a stored test (TEST_ID) or of a CSV record (--csv). "
                                   "An approved record's report is the PDF kept at its approval: written as it was "
                                   "approved, with its SHA-256 (the lab and units options do not change it).")
    p.add_argument("test_id", nargs="?", type=int, help="id of a stored test (see GET /api/tests); approved: the "
                                                        "PDF kept at its approval")
    p.add_argument("--out", required=True, help="output PDF file")
    p.add_argument("--json", dest="json_out", help="also write report.json (all metrics) to this file")
    p.add_argument("--csv-out", help="also write the samples as CSV (the columns of isorig simulate) to this file")
    p.add_argument("--database-url", help="SQLAlchemy URL of the store (default: the service's, ISORIG_DATABASE_URL)")
    p.add_argument("--csv", help="report on a CSV record (columns time_s, displacement_m, force_n; target_m, "
                                 "voltage_v, ... when present) instead of a stored test")
    p.add_argument("--summary", help="with --csv: the run's summary.json (default: summary.json beside the CSV)")
    p.add_argument("--isolator", help="with --csv: the isolator's preset name or .json (nominal parameters)")
    p.add_argument("--supply-bar", type=float, help="with --csv: supply pressure in bar, for the header")
    p.add_argument("--protocol", help="with --csv: judge the record against this protocol (shipped name or file)")
    p.add_argument("--lab-name", "--lab", dest="lab_name",
                   help="the lab named at the top of the report (default: the setting lab_name, ISORIG_LAB_NAME)")
    p.add_argument("--lab-address", help="the lab's address under its name; ';' or a newline separates lines "
                                         "(default: ISORIG_LAB_ADDRESS)")
    p.add_argument("--lab-logo", metavar="FILE", help="an image (PNG, JPEG) beside the lab's name (default: "
                                                      "ISORIG_LAB_LOGO_FILE); missing or unreadable: a warning")
    p.add_argument("--bundle", metavar="FILE.zip", help="also write the whole test as a zip: record.json, "
                                                        "report.json, samples.csv, cycles.csv, report.pdf")
    p.add_argument("--units", choices=("lab", "si"),
                   help="the units every figure is printed in: lab (mm, kN, kN/mm, bar) or si (m, N, N/m, MPa); "
                        "default: the lab's units as the service's Lab page set them, else lab")
    p.add_argument("--rig", help="rig name for the header (a CSV record does not say)")
    p.add_argument("--operator", help="operator name for the header (when the record has none)")
    p.add_argument("--no-identify", action="store_true", help="skip the Bouc-Wen identification (faster)")
    p.add_argument("--serial", action="store_true",
                   help="work in this one process (by default, with 2 or more cores, one process loads the test "
                        "and one fits Bouc-Wen while this one draws the PDF)")
    p.set_defaults(func=run)


def _store_url(database_url: str | None):
    """(the URL text, the parsed URL) of the store to read: --database-url, else the service's; UsageError for a
    URL that does not parse or a SQLite file that is not there (a database is never created here)."""
    from sqlalchemy.engine import make_url

    if database_url is None:
        from backend.settings import Settings

        database_url = Settings().resolved_database_url
    try:
        url = make_url(database_url)
    except Exception:
        raise UsageError(f"{PROG}: --database-url {database_url!r} is not a valid SQLAlchemy URL") from None
    if url.get_backend_name() == "sqlite" and url.database not in (None, "", ":memory:") \
            and not Path(url.database).expanduser().exists():
        raise UsageError(f"{PROG}: no database at {url.database} (run the service first, or pass --database-url, "
                         "or use --csv FILE)")
    return database_url, url


def _load_stored(test_id: int, database_url: str | None):
    from sqlalchemy.exc import SQLAlchemyError

    from backend import store
    from backend.db import make_engine, session_factory

    database_url, url = _store_url(database_url)
    engine = make_engine(database_url)
    try:
        with session_factory(engine)() as session:
            return store.load_test_bundle(session, test_id)
    except KeyError:
        raise UsageError(f"{PROG}: test {test_id} does not exist in {url.render_as_string(hide_password=True)}") \
            from None
    except SQLAlchemyError as exc:
        raise UsageError(f"{PROG}: cannot read the store: {type(exc).__name__}: {str(exc).splitlines()[0][:200]}") \
            from None
    finally:
        engine.dispose()


@dataclasses.dataclass(frozen=True)
class KeptReport:
    """The PDF kept with an approved record (backend.review.keep_report) and who approved it when."""

    pdf: bytes
    sha256: str
    approved_by: str | None
    approved_at: str | None
    lab_name: str
    units: str


def _kept_report(test_id: int, database_url: str | None) -> KeptReport | None:
    """The report kept at the record's approval (an approved record's report is fixed then: docs/reports.md), or
    None: not approved, approved before reports were kept, no such test, or a store this cannot read (then
    _load_stored says what is wrong). UsageError when the kept PDF no longer matches the SHA-256 of its approval
    (it was changed in the database; the service does not serve it either)."""
    from sqlalchemy.exc import SQLAlchemyError

    from backend import review, store
    from backend.db import make_engine, session_factory

    try:
        database_url, _ = _store_url(database_url)
    except UsageError:
        return None
    engine = make_engine(database_url)
    try:
        with session_factory(engine)() as session:
            test = store.get_test(session, test_id)
            kept = review.stored_report(session, test) if test is not None else None
            if kept is None:
                return None
            if review.sha256_of(kept.pdf) != test.report_sha256:
                raise UsageError(f"{PROG}: the report kept with test {test_id}'s approval no longer matches its "
                                 f"SHA-256 {test.report_sha256}: it was changed in the database; not written")
            at = test.reviewed_at.isoformat() if test.reviewed_at is not None else None
            return KeptReport(bytes(kept.pdf), test.report_sha256, test.reviewed_by, at, kept.lab_name or "",
                              kept.units or "lab")
    except SQLAlchemyError:  # an older store (no approved_reports table): the report is drawn as before
        return None
    finally:
        engine.dispose()


def _write_kept(args, kept: KeptReport, out: Path, meta: dict, lab) -> int:
    """Write the approved record's kept PDF to ``out``, byte for byte, and say so with its SHA-256; --json,
    --csv-out and --bundle are made from the record as before (the bundle's report.pdf is the kept one)."""
    import sys

    changed = [flag for flag, value in (("--lab-name", args.lab_name), ("--lab-address", args.lab_address),
                                        ("--lab-logo", args.lab_logo), ("--units", args.units),
                                        ("--rig", args.rig), ("--operator", args.operator)) if value is not None]
    if changed:
        print(f"{PROG}: warning: test {args.test_id} is approved: its report is the PDF kept at the approval; "
              f"{', '.join(changed)} do not change it", file=sys.stderr)
    try:
        out.write_bytes(kept.pdf)
    except OSError as exc:
        raise UsageError(f"{PROG}: cannot write {out}: {exc.strerror}") from None
    if args.json_out or args.csv_out or args.bundle:
        from backend.reports import report_json

        bundle = _load_stored(args.test_id, args.database_url)
        report = report_json(bundle, identify=not args.no_identify, meta=meta, lab=lab) \
            if args.json_out or args.bundle else {}
        _extras(args, bundle, report, meta, kept.pdf)
    when = f" on {kept.approved_at[:19].replace('T', ' ')} UTC" if kept.approved_at else ""
    print(f"wrote {out}" + "".join(f", {f}" for f in (args.json_out, args.csv_out, args.bundle) if f)
          + f": test {args.test_id} is approved (by {kept.approved_by or 'unknown'}{when}): the report kept at its "
          f"approval, not drawn again ({kept.lab_name or 'no lab name'}, {kept.units} units, {len(kept.pdf)} bytes)")
    print(f"SHA-256 {kept.sha256}")
    return 0


def _stored_lab(database_url: str | None):
    """The lab header the service's reports use (backend.lab: the database's settings over the environment's)."""
    from backend import lab
    from backend.db import make_engine, session_factory
    from backend.reports.lab import lab_header

    try:
        database_url, _ = _store_url(database_url)
    except UsageError:  # _load_stored says what is wrong
        return lab_header()
    engine = make_engine(database_url)
    try:
        with session_factory(engine)() as session:
            return lab.header(session, None)
    except Exception:  # an older store without the table: the environment's settings
        return lab_header()
    finally:
        engine.dispose()


def _load(args):
    """The bundle of a stored test or of a CSV record, as the arguments say."""
    from backend.reports import bundle_from_csv

    if args.csv is not None:
        return bundle_from_csv(args.csv, summary_path=args.summary, isolator=args.isolator,
                               supply_bar=args.supply_bar, protocol=args.protocol,
                               all_columns=bool(args.csv_out or args.bundle))
    return _load_stored(args.test_id, args.database_url)


def _parallel() -> bool:
    """Three processes pay off with two or more cores, where fork and memfd_create are (Linux)."""
    import multiprocessing

    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)
    return cores >= 2 and "fork" in multiprocessing.get_all_start_methods() and hasattr(os, "memfd_create")


def run(args) -> int:
    if (args.test_id is None) == (args.csv is None):
        raise UsageError(f"{PROG}: give exactly one of TEST_ID (a stored test) or --csv FILE")
    if args.csv is None and any(v is not None for v in (args.summary, args.isolator, args.supply_bar, args.protocol)):
        raise UsageError(f"{PROG}: --summary, --isolator, --supply-bar and --protocol go with --csv only")
    if args.supply_bar is not None and not (math.isfinite(args.supply_bar) and args.supply_bar > 0):
        raise UsageError(f"{PROG}: --supply-bar = {args.supply_bar:g} must be a positive number of bar")
    out = Path(args.out)
    for flag, path in (("--out", out), ("--json", args.json_out), ("--csv-out", args.csv_out),
                       ("--bundle", args.bundle)):
        if path is not None and not Path(path).parent.exists():
            raise UsageError(f"{PROG}: the folder of {flag} {path} does not exist")

    source = args.csv if args.csv is not None else f"test {args.test_id}"
    meta = {"rig": args.rig, "operator": args.operator}
    kept = _kept_report(args.test_id, args.database_url) if args.test_id is not None else None
    from backend.reports.lab import lab_header

    if args.test_id is not None and (args.lab_name, args.lab_address, args.lab_logo) == (None, None, None):
        lab = _stored_lab(args.database_url)  # the lab as the service's Lab page set it, as the service's reports
    else:
        lab = lab_header(args.lab_name, args.lab_address, args.lab_logo)
    if args.units is not None:
        lab = dataclasses.replace(lab, units=args.units)
    if lab.warning:  # one line, and the report is made without the logo
        import sys

        print(f"{PROG}: warning: {lab.warning}", file=sys.stderr)
    if kept is not None:  # an approved record's report is the one kept at its approval, never drawn again
        return _write_kept(args, kept, out, meta, lab)
    t0, cpu0 = time.perf_counter(), _cpu_s()
    # A one-off command: reference counting frees nearly everything, and the cycle collector's passes over
    # matplotlib's many objects cost 0.2-0.3 s of drawing. Back on afterwards (tests call this in-process).
    collecting = gc.isenabled()
    gc.disable()
    try:
        made = None if args.serial or not _parallel() else _make_parallel(args, meta, out, lab)
        if made is None:  # one process asked for, or no second core, fork or shared memory here
            bundle, report, times = _make_serial(args, meta, out, lab)
            how = "1 process"
        else:
            bundle, report, times = made
            how = f"{2 if args.no_identify else 3} processes"
    finally:
        if collecting:
            gc.enable()
    wall = time.perf_counter() - t0
    _extras(args, bundle, report, meta, out.read_bytes() if args.bundle else b"")
    ident = report["identification"]
    verdict = report["acceptance"]["verdict"]
    status = report["run"]["status"]
    print(f"wrote {out}" + "".join(f", {f}" for f in (args.json_out, args.csv_out, args.bundle) if f)
          + f": {source} ({status}), {bundle.samples.shape[0]} samples, {len(bundle.cycles)} cycles, acceptance "
          + ("none (no protocol)" if verdict == "NO VERDICT" else verdict))
    t_ident = ident.get("time_s") or 0.0
    print(f"time {wall:.2f} s (CPU {_cpu_s() - cpu0:.2f} s in {how}): load {times['load_s']:.2f} s, metrics and "
          f"verdicts {times['metrics_s']:.2f} s, Bouc-Wen identification {t_ident:.2f} s, PDF {times['pdf_s']:.2f} s"
          + ("; they overlap" if how != "1 process" else ""))
    return 0


def _extras(args, bundle, report: dict, meta: dict, pdf: bytes) -> None:
    """--json (report.json), --csv-out (the samples) and --bundle (the zip, with ``pdf`` as its report.pdf)."""
    if args.json_out:
        try:
            Path(args.json_out).write_text(json.dumps(report, indent=1))
        except OSError as exc:
            raise UsageError(f"{PROG}: cannot write {args.json_out}: {exc.strerror}") from None
    if args.csv_out:
        from sim.records import write_csv

        try:
            write_csv(args.csv_out, bundle.samples)
        except OSError as exc:
            raise UsageError(f"{PROG}: cannot write {args.csv_out}: {exc.strerror}") from None
    if args.bundle:
        from backend.reports import write_bundle_zip
        from backend.reports.data import protocol_of

        try:
            write_bundle_zip(args.bundle, _with_meta(bundle, meta), report, pdf, protocol_of(bundle.record)[0])
        except OSError as exc:
            raise UsageError(f"{PROG}: cannot write {args.bundle}: {exc.strerror}") from None


def _cpu_s() -> float:
    """CPU seconds of this process and of its finished children."""
    import resource

    return time.process_time() + sum(getattr(resource.getrusage(resource.RUSAGE_CHILDREN), k)
                                     for k in ("ru_utime", "ru_stime"))


def _with_meta(bundle, meta: dict):
    """The bundle with what the command's options add to its record (rig, operator)."""
    extra = {k: v for k, v in meta.items() if v}
    if not extra:
        return bundle
    from backend.reports import ReportBundle

    return ReportBundle(record={**bundle.record, **extra}, samples=bundle.samples, cycles=bundle.cycles,
                        events=bundle.events)


def _make_serial(args, meta, out, lab):
    """Load, compute and draw one after the other in this process (as the service does)."""
    from backend.reports import report_json

    t0 = time.perf_counter()
    bundle = _load(args)
    t1 = time.perf_counter()
    report = report_json(bundle, identify=not args.no_identify, meta=meta, lab=lab)
    t2 = time.perf_counter()
    _render(bundle, out, meta, report, lab)
    t3 = time.perf_counter()
    t_ident = report["identification"].get("time_s") or 0.0
    return bundle, report, {"load_s": t1 - t0, "metrics_s": t2 - t1 - t_ident, "pdf_s": t3 - t2}


def _render(bundle, out, meta, report, lab, identification=None) -> None:
    from backend.reports import render_report_pdf

    try:
        render_report_pdf(bundle, out, meta=meta, report=report, identification=identification, lab=lab)
    except OSError as exc:
        raise UsageError(f"{PROG}: cannot write {out}: {exc.strerror}") from None


# --- three processes -------------------------------------------------------------------------------------
# A fresh `isorig report` of a 10-minute test spends about as long importing matplotlib and warming up its
# fonts, loading and decoding the samples (or parsing the CSV), and importing scipy and numba and loading (or
# compiling) the Bouc-Wen kernels. None needs the others until the end, so with two cores they overlap: a
# loader process reads the test and computes the metrics, an identifier process prepares the fit and runs it
# as soon as the loader hands it the first minute of the record, and this process draws every page but the
# header meanwhile, then the header with the fit (docs/reports.md, Speed).

def _make_parallel(args, meta, out, lab):
    """(bundle, report, times) made by three processes, or None when they cannot be started."""
    import multiprocessing
    import sys
    import threading

    from backend.reports import ReportBundle, clean_json, plot_style

    try:  # the samples and loop arrays (70 MB for 10 minutes) go through shared memory: a pipe took 0.4 s
        shared = os.memfd_create("isorig-report")
    except OSError:
        return None
    ctx = multiprocessing.get_context("fork")
    pipes = []
    try:
        for _ in range(3):
            pipes.append(ctx.Pipe(duplex=False))
    except OSError:  # out of file descriptors: one process will do
        for ends in pipes:
            for end in ends:
                end.close()
        os.close(shared)
        return None
    (data_r, data_w), (task_r, task_w), (fit_r, fit_w) = pipes
    # data: loader -> this process (the record, metrics, report, array layout); task: loader -> identifier (what
    # to fit); fit: identifier -> this process (the identification)
    identify = not args.no_identify
    parent = os.getpid()
    children = [ctx.Process(target=_loader, args=(args, meta, lab, data_w, task_w if identify else None, shared,
                                                  (data_r, task_r, fit_r, fit_w) + (() if identify else (task_w,)),
                                                  parent),
                            daemon=True, name="isorig-report-loader")]
    if identify:
        children.append(ctx.Process(target=_identifier, args=(task_r, fit_w, (data_r, data_w, task_w, fit_r),
                                                              parent),
                                    daemon=True, name="isorig-report-identifier"))
    sys.stdout.flush()
    sys.stderr.flush()
    try:
        for child in children:
            child.start()
    except OSError:  # no fork now (out of processes or memory): one process will do
        for child in children:
            if child.pid is not None:
                child.kill()
                child.join()
        for end in (data_r, data_w, task_r, task_w, fit_r, fit_w):
            end.close()
        os.close(shared)
        return None
    for end in (data_w, task_r, task_w, fit_w):
        end.close()
    on_term = _exit_on_sigterm()  # a kill of this process alone: its finally still ends the children
    received: dict = {}
    receiver = threading.Thread(target=_receive, args=(data_r, received), daemon=True)
    receiver.start()  # the loader never waits for this process to finish importing matplotlib
    failed = True
    try:
        plot_style()
        receiver.join()
        t_data = time.perf_counter()
        if "error" in received:
            kind, text = received["error"]
            if kind == NO_SHARED_MEMORY:
                return None  # the finally ends the children; one process will do
            if kind == "usage":
                raise UsageError(text)
            if kind == "value":
                raise ValueError(text)
            last = text.strip().splitlines()[-1] if text.strip() else "no reason given"  # a crash's exception line
            raise UsageError(f"{PROG}: the loading process failed: {last}")
        record, cycles, events, report, times, layout = received["message"]
        samples = _unpack(shared, layout, cycles)
        bundle = ReportBundle(record=record, samples=samples, cycles=cycles, events=events)

        def identification() -> dict:
            try:
                return clean_json(fit_r.recv())
            except (EOFError, OSError):
                return {**report["identification"], "available": False,
                        "note": "identification failed: its process ended without an answer"}

        _render(bundle, out, meta, report, lab, identification if identify else None)
        times["pdf_s"] = time.perf_counter() - t_data
        failed = False
        return bundle, report, times
    finally:
        _restore_sigterm(on_term)
        for child in children:
            if failed:  # an error (e.g. no such test) is told at once, not after the identifier's warm-up
                child.terminate()
            child.join(timeout=10.0)
            if child.is_alive():
                child.kill()
                child.join()
        # the receiver may still wait in recv (a SIGTERM during its join): with the loader gone it reads EOF; a
        # pipe closed under it would end it with a traceback instead
        receiver.join(timeout=10.0)
        os.close(shared)
        data_r.close()
        fit_r.close()


LOOP_KEYS = ("displacement_m", "force_n")
NO_SHARED_MEMORY = "no shared memory"  # the loader's answer when the samples do not fit in the shared memory
IDENTIFIER_NICENESS = 5  # CPU share against the other two: 1/4 (it waits for the loader anyway)


def _pack(fd: int, samples, cycles) -> dict:
    """Write the samples and the cycles' loop arrays into the shared memory file; return where each went."""
    import mmap

    import numpy as np

    loops, offset = [], samples.size
    for c in cycles:
        loops.append([])
        for key in LOOP_KEYS:
            n = len(c[key])
            loops[-1].append((offset, n))
            offset += n
    layout = {"shape": samples.shape, "loops": loops}
    if offset:
        os.ftruncate(fd, 8 * offset)
        with mmap.mmap(fd, 8 * offset) as mm:
            buf = np.frombuffer(mm, dtype=np.float64)
            buf[:samples.size].reshape(samples.shape)[...] = samples
            for c, places in zip(cycles, loops, strict=True):
                for key, (start, n) in zip(LOOP_KEYS, places, strict=True):
                    buf[start:start + n] = c[key]
            del buf  # the mapping closes only when no array uses it
    return layout


def _unpack(fd: int, layout: dict, cycles: list):
    """The samples (and each cycle's loop arrays, put back into ``cycles``) as views of the shared memory."""
    import mmap

    import numpy as np

    shape = layout["shape"]
    size = os.fstat(fd).st_size
    buf = np.frombuffer(mmap.mmap(fd, size), dtype=np.float64) if size else np.empty(0)
    for c, places in zip(cycles, layout["loops"], strict=True):
        for key, (start, n) in zip(LOOP_KEYS, places, strict=True):
            c[key] = buf[start:start + n]
    from sim.samples import Samples

    return Samples(buf[:shape[0] * shape[1]].reshape(shape))


def _receive(conn, received: dict) -> None:
    try:
        msg = conn.recv()
    except (EOFError, OSError) as exc:
        received["error"] = ("crash", f"it ended without sending the test ({type(exc).__name__})")
        return
    if msg[0] == "ok":
        received["message"] = msg[1]
    else:
        received["error"] = msg


def _exit_on_sigterm():
    """Make SIGTERM raise SystemExit(143) in this process (main thread only); the handler it replaced, or None."""
    import signal
    import threading

    if threading.current_thread() is not threading.main_thread():
        return None

    def stop(signum, _frame):
        raise SystemExit(128 + signum)

    return signal.signal(signal.SIGTERM, stop)


def _restore_sigterm(previous) -> None:
    import signal

    if previous is not None:
        signal.signal(signal.SIGTERM, previous)


def _child_setup(unused, parent: int) -> None:
    """In a child, first thing: leave Ctrl-C to the parent (which ends the children: no traceback from each), end
    with the parent when it dies (Linux), and close the pipe ends it does not use (a dead writer reads as EOF)."""
    import signal

    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    _end_with_parent(parent)
    for end in unused:
        end.close()


def _end_with_parent(parent: int) -> None:
    """Ask the kernel to SIGTERM this process when its parent dies; exit now if it is already dead
    (backend.children.end_with_parent)."""
    import signal

    from backend.children import end_with_parent

    end_with_parent(parent, signal.SIGTERM)


def _send(conn, message) -> None:
    """Send to the parent; if it is gone (a closed pipe), nobody waits for the answer: end quietly."""
    try:
        conn.send(message)
    except OSError:
        os._exit(1)


def _loader(args, meta, lab, conn, task_conn, shared, unused, parent) -> None:
    """Child: load the test, hand the first minute to the identifier, compute the metrics, send all here."""
    _child_setup(unused, parent)
    import traceback

    from backend.reports import identification_task, report_json

    try:
        t0 = time.perf_counter()
        bundle = _load(args)
        t1 = time.perf_counter()
        answer = None
        if task_conn is not None:
            answer, task = identification_task(bundle)
            try:
                task_conn.send((answer, task))
            except OSError:
                pass  # the identifier died early: the report goes on without the fit, and says so
            task_conn.close()
        report = report_json(bundle, identify=False, meta=meta, identification=answer, lab=lab)
        times = {"load_s": t1 - t0, "metrics_s": time.perf_counter() - t1}
        try:
            layout = _pack(shared, bundle.samples.array, bundle.cycles)
        except OSError as exc:  # no room for the shared memory file (ftruncate, mmap)
            _send(conn, (NO_SHARED_MEMORY, str(exc)))
            return
        cycles = [{k: v for k, v in c.items() if k not in LOOP_KEYS} for c in bundle.cycles]
        _send(conn, ("ok", (bundle.record, cycles, bundle.events, report, times, layout)))
    except UsageError as exc:
        _send(conn, ("usage", str(exc)))
    except ValueError as exc:
        _send(conn, ("value", str(exc)))
    except Exception:
        _send(conn, ("crash", traceback.format_exc(limit=-3).strip()))
    finally:
        conn.close()


def _identifier(task_conn, conn, unused, parent) -> None:
    """Child: import the fit and load (or compile) its kernels, then fit what the loader sends."""
    _child_setup(unused, parent)
    import threading

    from backend.reports import run_identification

    with contextlib.suppress(OSError):  # the loader and the drawing come first: this has time to spare
        os.nice(IDENTIFIER_NICENESS)
    received: dict = {}

    def receive() -> None:
        try:
            received["task"] = task_conn.recv()
        except (EOFError, OSError):
            pass  # the loader failed: it tells this process's parent why

    receiver = threading.Thread(target=receive, daemon=True)
    receiver.start()  # the task (about 150 kB) would not fit the pipe: the loader must not wait for the warm-up
    _warm_up_fit()
    receiver.join()
    if "task" in received:
        answer, task = received["task"]
        _send(conn, answer if task is None else run_identification(answer, task))
    conn.close()


def _warm_up_fit() -> None:
    """Load the fit's compiled kernels now rather than when the record arrives (a cold numba cache compiles)."""
    try:
        from sim.identify_bouc_wen import warm_up

        warm_up()
    except Exception:  # only a head start: the fit itself reports any real problem
        pass
