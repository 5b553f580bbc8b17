"""`isorig report`: the PDF test report (and optionally report.json) of a stored test or of a CSV record."""

from __future__ import annotations

import json
import math
import time
from pathlib import Path

from isorig.cli import UsageError

PROG = "isorig report"


def register(sub) -> None:
    p = sub.add_parser("report", help="PDF report (loops, per-cycle metrics, verdicts) of a stored test or a CSV",
                       description="Render the A4 PDF report of a stored test (TEST_ID) or of a CSV record (--csv).")
    p.add_argument("test_id", nargs="?", type=int, help="id of a stored test (see GET /api/tests)")
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
    p.add_argument("--lab", help="lab name for the header")
    p.add_argument("--rig", help="rig name for the header")
    p.add_argument("--operator", help="operator name for the header")
    p.add_argument("--no-identify", action="store_true", help="skip the Bouc-Wen identification (faster)")
    p.set_defaults(func=run)


def _load_stored(test_id: int, database_url: str | None):
    from sqlalchemy.engine import make_url
    from sqlalchemy.exc import SQLAlchemyError

    from backend import store
    from backend.db import make_engine, session_factory

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


def run(args) -> int:
    if (args.test_id is None) == (args.csv is None):
        raise UsageError(f"{PROG}: give exactly one of TEST_ID (a stored test) or --csv FILE")
    if args.csv is None and any(v is not None for v in (args.summary, args.isolator, args.supply_bar, args.protocol)):
        raise UsageError(f"{PROG}: --summary, --isolator, --supply-bar and --protocol go with --csv only")
    if args.supply_bar is not None and not (math.isfinite(args.supply_bar) and args.supply_bar > 0):
        raise UsageError(f"{PROG}: --supply-bar = {args.supply_bar:g} must be a positive number of bar")
    out = Path(args.out)
    if not out.parent.exists():
        raise UsageError(f"{PROG}: the folder of --out {out} does not exist")

    from backend.reports import bundle_from_csv, render_report_pdf, report_json

    t0, cpu0 = time.perf_counter(), time.process_time()
    if args.csv is not None:
        bundle = bundle_from_csv(args.csv, summary_path=args.summary, isolator=args.isolator,
                                 supply_bar=args.supply_bar, protocol=args.protocol)
        source = args.csv
    else:
        bundle = _load_stored(args.test_id, args.database_url)
        source = f"test {args.test_id}"
    t1 = time.perf_counter()
    meta = {"lab": args.lab, "rig": args.rig, "operator": args.operator}
    report = report_json(bundle, identify=not args.no_identify, meta=meta)
    t2 = time.perf_counter()
    try:
        render_report_pdf(bundle, out, meta=meta, report=report)
    except OSError as exc:
        raise UsageError(f"{PROG}: cannot write {out}: {exc.strerror}") from None
    t3 = time.perf_counter()
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
    ident = report["identification"]
    verdict = report["acceptance"]["summary"]["passed"]
    print(f"wrote {out}" + "".join(f", {f}" for f in (args.json_out, args.csv_out) if f)
          + f": {source}, {bundle.samples.shape[0]} samples, {len(bundle.cycles)} cycles, acceptance "
          + {None: "none (no protocol)", True: "PASSED", False: "FAILED"}[verdict])
    t_ident = ident.get("time_s") or 0.0
    print(f"time {t3 - t0:.2f} s (CPU {time.process_time() - cpu0:.2f} s): load {t1 - t0:.2f} s, metrics and "
          f"verdicts {t2 - t1 - t_ident:.2f} s, Bouc-Wen identification {t_ident:.2f} s, PDF {t3 - t2:.2f} s")
    return 0
