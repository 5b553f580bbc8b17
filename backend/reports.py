"""Test reports: a printable A4 PDF (matplotlib) and a JSON of all metrics, from a store bundle or a CSV.

``render_report_pdf(bundle, out)`` and ``report_json(bundle)`` take anything with the attributes of
``backend.store.TestBundle`` (``record``, ``samples``, ``cycles``, ``events``); ``bundle_from_csv`` builds one
from a CSV record (e.g. ``isorig simulate``'s timeseries.csv, with its summary.json when it sits beside it).
Numerics come from sim/ (metrics, protocols, identification); nothing is recomputed here that sim/ provides.
Layout and choices: docs/reports.md.
"""

from __future__ import annotations

import functools
import io
import json
import math
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path

import numpy as np

from sim.samples import RECORD_FIELDS, SAMPLE_FIELDS, Samples

A4_PORTRAIT_IN = (8.27, 11.69)
PLOT_POINTS = 2500  # min/max buckets per time history (5000 points: peaks kept, file small)
MAX_LOOPS = 40  # loops drawn in the overview (evenly chosen; all of them if fewer)
LOOP_POINTS = 400  # points per drawn loop
TABLE_ROWS = 61  # per-cycle table rows per page
MAX_HEADER_LEVELS = 6  # the header page lists at most this many protocol levels ...
MAX_HEADER_RULES = 4  # ... and rules (all of them are on the verdicts page)
BOUC_WEN_FIELDS = ("rho_bw_per_m", "sigma_bw", "n", "kd_n_per_m", "kw_n")
IDENTIFY_MAX_SAMPLES = 60_000  # the Bouc-Wen fit uses the first 60 000 samples (60 s at 1 kHz) ...
IDENTIFY_FIT_POINTS = 6_000  # ... thinned to at most 6 000 points (>= 100 Hz), to keep the report fast
UNREPORTED_COLUMNS = ("model_m", "load_pressure_pa")  # in the samples, but neither the PDF nor the JSON shows them
ESTIMATE_COLUMNS = ("ar_hat", "ay_hat", "as_hat")  # adaptive estimates: the report shows their final values


@dataclass
class ReportBundle:
    """The same shape as backend.store.TestBundle, for records that do not come from the store."""

    record: dict
    samples: np.ndarray
    cycles: list[dict] = field(default_factory=list)
    events: list[dict] = field(default_factory=list)


# --- building a bundle from a CSV ------------------------------------------------------------------------

def bundle_from_csv(path, summary_path=None, isolator=None, supply_bar: float | None = None,
                    protocol=None, meta: dict | None = None, all_columns: bool = True) -> ReportBundle:
    """A bundle from a CSV record (columns time_s, displacement_m, force_n required; target_m, voltage_v,
    model_m, ar_hat, ay_hat, as_hat, load_pressure_pa used when present).

    ``summary_path`` (default: summary.json beside the CSV, if any) supplies the scenario that
    ``isorig simulate`` ran: isolator, supply pressure, profile and controller; cycles are then split by the
    command's phase. ``isolator`` (name, dict or Isolator), ``supply_bar`` and ``protocol`` (name, path or
    Protocol) override it. ``all_columns=False`` reads only what a report shows: model_m and load_pressure_pa
    stay NaN, and the adaptive estimates (whose final values the report shows) are read from the last rows
    only, NaN before them (0.9 s less for 10 minutes; their other cells are then not checked). Raises
    sim.metrics.RecordError (a ValueError) for a malformed CSV.
    """
    from sim.isolator import Isolator, isolator_from_dict, load_isolator
    from sim.metrics import cycle_metrics, profile_cycle_starts_s, read_csv_columns
    from sim.protocols import Protocol, load_protocol

    path = Path(path)
    optional = [c for c in RECORD_FIELDS if c not in ("time_s", "displacement_m", "force_n")
                and (all_columns or c not in UNREPORTED_COLUMNS + ESTIMATE_COLUMNS)]
    cols = read_csv_columns(path, optional=optional)
    n = cols["time_s"].size
    if not all_columns:
        final = _final_estimates(path, n)
        if final is None:  # not settled by the last rows: read their whole columns (and check every cell)
            cols.update(read_csv_columns(path, required=(), optional=ESTIMATE_COLUMNS, min_rows=0))
        else:
            cols.update(final)
    # column by column into a column-major array: contiguous copies, and no NaN fill of 67 MB to overwrite
    array = np.empty((len(SAMPLE_FIELDS), n)).T
    for j, name in enumerate(SAMPLE_FIELDS):
        array[:, j] = cols[name] if name in cols else np.nan
    samples = Samples(array)

    summary = None
    summary_file = Path(summary_path) if summary_path else path.with_name("summary.json")
    if summary_file.exists():
        try:
            summary = json.loads(summary_file.read_text())
        except (OSError, json.JSONDecodeError) as exc:
            if summary_path:
                raise ValueError(f"cannot read the summary {summary_file}: {exc}") from None
    scenario = (summary or {}).get("scenario") or {}

    iso = None
    if isinstance(isolator, Isolator):
        iso = isolator
    elif isinstance(isolator, dict):
        iso = isolator_from_dict(isolator)
    elif isolator:
        iso = load_isolator(isolator)
    elif isinstance(scenario.get("isolator"), dict):
        iso = isolator_from_dict(scenario["isolator"])
    proto = protocol if isinstance(protocol, Protocol) or protocol is None else load_protocol(protocol)

    blocks = None
    if proto is not None:
        blocks = proto.blocks
    elif scenario.get("profile"):
        from sim.profiles import SineProfile

        blocks = [SineProfile(b["amplitude_m"], b["frequency_hz"], int(b["cycles"]), int(b["taper_cycles"]),
                              b.get("offset_m", 0.0)) for b in scenario["profile"]]
    t, d, f = cols["time_s"], cols["displacement_m"], cols["force_n"]
    if blocks:
        starts, end = profile_cycle_starts_s(blocks)
        cycles = cycle_metrics(t, d, f, starts, end)
    else:
        cycles = cycle_metrics(t, d, f)
    for c in cycles:
        j1 = min(c["i_end"] + 1, n)
        c["displacement_m"] = d[c["i_start"]:j1]
        c["force_n"] = f[c["i_start"]:j1]

    if proto is not None:
        profile = {"kind": "protocol", "protocol": proto.to_dict()}
    elif blocks:
        profile = blocks[0].to_dict() if len(blocks) == 1 else {"kind": "blocks",
                                                                "blocks": [b.to_dict() for b in blocks]}
    else:
        profile = None
    stat = path.stat()
    record = {
        "id": None,
        "label": path.name,
        "source": str(path),
        "status": "recorded",
        "created_at": datetime.fromtimestamp(stat.st_mtime, UTC).isoformat(),
        "isolator": iso.name if iso else None,
        "supply_bar": supply_bar if supply_bar is not None else scenario.get("supply_bar"),
        "controller": scenario.get("controller"),
        "profile": profile,
        "duration_s": float(t[-1] - t[0]) if n else 0.0,
        "samples_stored": n,
        "scenario": {**scenario, **({"isolator": iso.to_dict()} if iso else {})},
        "summary": {k: v for k, v in (summary or {}).items() if k not in ("scenario", "cycles")},
        **(meta or {}),
    }
    return ReportBundle(record=record, samples=samples, cycles=cycles, events=[])


def _final_estimates(path: Path, n_rows: int, tail_bytes: int = 1 << 16) -> dict[str, np.ndarray] | None:
    """The adaptive estimates over the last rows of a CSV record (about 500), NaN before: the report shows only
    their last finite values. Columns absent, or empty in the first data row, are left out, as
    sim.metrics.read_csv_columns leaves them out. None when the last rows do not settle it (a cell that is not
    a number, a short or blank row, no finite value): the caller then reads the whole columns."""
    from sim.metrics import csv_header_names

    with open(path, "rb") as fh:
        header = fh.readline().decode("utf-8", "replace")
        start = fh.tell()  # the first data row: a tail that reaches it holds every row
        first = fh.readline().decode("utf-8", "replace").rstrip("\r\n").split(",")
        size = fh.seek(0, 2)
        fh.seek(max(start, size - tail_bytes))
        at_start = fh.tell() == start
        tail = fh.read().decode("utf-8", "replace").split("\n")
    names = csv_header_names(header)
    wanted = {c: names.index(c) for c in ESTIMATE_COLUMNS
              if c in names and names.index(c) < len(first) and first[names.index(c)].strip()}
    lines = [line.rstrip("\r") for line in (tail if at_start else tail[1:])]  # the first one may be cut
    if lines and not lines[-1]:
        lines.pop()  # the file's last newline
    if not lines or any(not line.strip() for line in lines) or len(lines) > n_rows or \
            (at_start and len(lines) != n_rows):
        return None
    out = {}
    for name, j in wanted.items():
        values = np.full(n_rows, np.nan)
        for k, line in enumerate(lines, start=n_rows - len(lines)):
            cells = line.split(",")
            cell = cells[j].strip() if j < len(cells) else None
            if cell is None or "_" in cell:
                return None
            try:
                values[k] = float(cell) if cell else np.nan
            except ValueError:
                return None
        if not np.isfinite(values).any():
            return None
        out[name] = values
    return out


# --- what the report says (shared by the PDF and the JSON) -----------------------------------------------

def _num(x):
    return x if isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x) else None


def _protocol_of(record: dict):
    """The protocol a test ran, or None for a plain sine (or if it cannot be rebuilt; then a note)."""
    profile = record.get("profile")
    if not isinstance(profile, dict) or profile.get("kind") != "protocol":
        return None, None
    try:
        from sim.protocols import profile_from_spec

        _blocks, protocol = profile_from_spec(profile)
        return protocol, None
    except (ImportError, ValueError) as exc:
        return None, f"the test's protocol cannot be rebuilt: {exc}"


def _isolator_of(record: dict):
    from sim.isolator import PRESETS, isolator_from_dict

    scenario = record.get("scenario") or {}
    if isinstance(scenario.get("isolator"), dict):
        try:
            return isolator_from_dict(scenario["isolator"])
        except ValueError:
            pass
    name = record.get("isolator")
    return PRESETS.get(name) if isinstance(name, str) else None


def _last_finite(column: np.ndarray):
    finite = np.nonzero(np.isfinite(column))[0]
    return float(column[finite[-1]]) if finite.size else None


def controller_state(bundle) -> dict:
    """Controller name, options and the final adapted parameters (last finite ar_hat, ay_hat, as_hat)."""
    record = bundle.record
    scenario = record.get("scenario") or {}
    s = bundle.samples
    adapted = {}
    if len(s):
        for name in ("ar_hat", "ay_hat", "as_hat"):
            value = _last_finite(s[name])
            if value is not None:
                adapted[name] = value
    name = record.get("controller") or scenario.get("controller")
    options = scenario.get("controller_options") or {}
    parameters = {}
    if name:
        try:  # the controller's effective parameters: its defaults overridden by the test's options
            from sim.controllers import make_controller

            parameters = {k: v for k, v in make_controller(name, **options).options.items()
                          if isinstance(v, (int, float, str, bool))}
        except (ImportError, ValueError, TypeError):
            parameters = {}
    try:
        from sim.controllers import ADAPTED_LABELS

        labels = ADAPTED_LABELS.get(name, {})
    except ImportError:
        labels = {}
    return {"name": name, "options": options, "parameters": parameters, "final_adapted": adapted,
            "adapted_labels": {k: labels[k] for k in adapted if k in labels}}


def identified_bouc_wen(bundle, max_samples: int = IDENTIFY_MAX_SAMPLES) -> dict:
    """Bouc-Wen parameters identified from the test's record beside the nominal ones.

    Uses a stored result (``record["identification"]`` with ``identified``) when there is one; else calls
    ``fit_bouc_wen`` of sim.identify_bouc_wen on the first ``max_samples`` samples
    (the fit assumes the record starts at rest, so it must start at the beginning), thinned to at most
    IDENTIFY_FIT_POINTS points, starting from the nominal rho_BW, sigma_BW, n. Returns {"available": False,
    "note": why} when the fit fails or the record has too little motion.
    """
    answer, task = identification_task(bundle, max_samples)
    return answer if task is None else run_identification(answer, task)


def identification_task(bundle, max_samples: int = IDENTIFY_MAX_SAMPLES) -> tuple[dict, tuple | None]:
    """What identified_bouc_wen decides before fitting: its answer so far and the fit to run (None: none).

    The task is small and pickles (at most IDENTIFY_FIT_POINTS samples and the start), so another process can
    run it with run_identification while this one goes on (``isorig report`` does); the fit is imported there.
    """
    nominal = _isolator_of(bundle.record)
    out = {"available": False, "nominal": nominal.to_dict() if nominal else None}
    stored = bundle.record.get("identification")
    if isinstance(stored, dict) and stored.get("identified"):
        return {**out, **stored, "available": True, "source": "stored with the test"}, None
    s = bundle.samples
    stride = max(1, math.ceil(min(max_samples, len(s)) / IDENTIFY_FIT_POINTS))
    t, d, f = (np.ascontiguousarray(s[c][:max_samples:stride]) for c in ("time_s", "displacement_m", "force_n"))
    bad = ~(np.isfinite(t) & np.isfinite(d) & np.isfinite(f))
    if bad.any():
        t, d, f = t[:int(np.argmax(bad))], d[:int(np.argmax(bad))], f[:int(np.argmax(bad))]
    if t.size < 100 or np.ptp(d) <= 0:
        out["note"] = "too few samples with motion to identify"
        return out, None
    start = None if nominal is None else {"rho_bw_per_m": nominal.rho_bw_per_m, "sigma_bw": nominal.sigma_bw,
                                          "n": nominal.n}
    return out, (t, d, f, start)


def run_identification(answer: dict, task: tuple) -> dict:
    """Run the fit of identification_task and complete its answer (a failure becomes a note, never raises)."""
    import time

    from sim.identify_bouc_wen import fit_bouc_wen

    t, d, f, start = task
    out = dict(answer)
    t0 = time.perf_counter()
    try:
        result = fit_bouc_wen(t, d, f, name="identified", start=start)
    except Exception as exc:  # an identification failure must not cost the report
        out["note"] = f"identification failed: {type(exc).__name__}: {exc}"[:300]
        return out
    params = {k: float(getattr(result.isolator, k)) for k in BOUC_WEN_FIELDS
              if _num(float(getattr(result.isolator, k))) is not None}
    if not params:
        out["note"] = "the identification returned no Bouc-Wen parameters"
        return out
    quality = {k: getattr(result, k) for k in ("nrms_error", "rms_error_n", "relative_std", "flat_directions")}
    out.update({"available": True, "identified": params, "fit": clean_json(quality), "samples_used": int(t.size),
                "record_span_s": float(t[-1] - t[0]), "time_s": time.perf_counter() - t0,
                "source": "fit_bouc_wen on the first " + f"{t[-1] - t[0]:.3g} s of the record"})
    return out


def acceptance(bundle) -> dict:
    """Verdicts of the test's protocol (sim.protocols.evaluate_acceptance) and their summary."""
    protocol, note = _protocol_of(bundle.record)
    if protocol is None:
        return {"protocol": None, "note": note or "no acceptance rules: the test ran a plain sine profile",
                "summary": {"passed": None, "verdicts": 0, "failed": 0, "failed_rules": []}, "verdicts": []}
    from sim.protocols import acceptance_summary, evaluate_acceptance

    metrics = [{k: v for k, v in c.items() if k not in ("displacement_m", "force_n")} for c in bundle.cycles]
    verdicts = evaluate_acceptance(protocol, metrics, isolator=_isolator_of(bundle.record))
    return {"protocol": protocol.name, "title": protocol.title, "rules": [r.text() for r in protocol.rules],
            "rule_names": [r.name for r in protocol.rules], "summary": acceptance_summary(verdicts),
            "verdicts": verdicts}


def tracking(bundle) -> dict:
    s = bundle.samples
    if not len(s):
        return {}
    closed = np.isfinite(s["target_m"])  # the three columns only: copying whole rows cost 0.35 s at 600 000
    if not closed.any():
        return {}
    e = s["displacement_m"][closed] - s["target_m"][closed]
    u = s["voltage_v"][closed]
    return {"rms_y_minus_r_m": float(np.sqrt(np.mean(e * e))), "peak_abs_y_minus_r_m": float(np.max(np.abs(e))),
            "peak_abs_voltage_v": _num(float(np.nanmax(np.abs(u)))) if np.isfinite(u).any() else None}


def _limit_trips(events: list[dict]) -> list[dict]:
    return [e for e in events if e.get("kind") == "limit_trip"]


def clean_json(value):
    """A value ready for strict JSON: NaN and infinities become None, numpy values Python ones."""
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, np.generic):
        return clean_json(value.item())
    if isinstance(value, np.ndarray):
        return [clean_json(v) for v in value.tolist()]
    if isinstance(value, dict):
        return {k: clean_json(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [clean_json(v) for v in value]
    return value


def report_json(bundle, identify: bool = True, meta: dict | None = None, identification: dict | None = None) -> dict:
    """All metrics of a test: header, per-cycle metrics, acceptance, identification, tracking, events.

    ``identify=False`` skips the Bouc-Wen fit (the slowest part: seconds); ``identification`` is one already
    made (identified_bouc_wen's answer). ``meta`` (lab, rig, operator) fills in what the record does not hold.
    """
    record = {**bundle.record, **{k: v for k, v in (meta or {}).items() if v}}
    cycles = [{k: v for k, v in c.items() if k not in ("displacement_m", "force_n")} for c in bundle.cycles]
    iso = _isolator_of(record)
    out = {
        "report_version": 1,
        "generated_at": datetime.now(UTC).isoformat(timespec="seconds"),
        "test": {k: record.get(k) for k in ("id", "label", "status", "reason", "created_at", "started_at",
                                            "ended_at", "isolator", "supply_bar", "controller", "profile",
                                            "duration_s", "samples_stored", "lab", "rig", "operator", "source")
                 if k in record},
        "isolator_nominal": iso.to_dict() if iso else None,
        "controller": controller_state(bundle),
        "tracking": tracking(bundle),
        "cycles": cycles,
        "acceptance": acceptance(bundle),
        "identification": identification if identification is not None else identified_bouc_wen(bundle)
        if identify else {"available": False, "nominal": iso.to_dict() if iso else None,
                          "note": "identification not requested"},
        "events": bundle.events,
        "limit_trips": _limit_trips(bundle.events),
    }
    return clean_json(out)


# --- the PDF ----------------------------------------------------------------------------------------------

def _minmax_decimate(t: np.ndarray, *ys: np.ndarray, buckets: int = PLOT_POINTS):
    """Per bucket, the min and the max of each series in time order: peaks survive, ~2 x buckets points."""
    n = t.size
    if n <= 4 * buckets:
        return (t, *ys)
    size = n // buckets
    m = size * buckets
    t_out = t[:m].reshape(buckets, size)[:, [0, -1]].ravel()
    outs = []
    for y in ys:
        yy = y[:m].reshape(buckets, size)
        i_lo = np.argmin(np.where(np.isnan(yy), np.inf, yy), axis=1)
        i_hi = np.argmax(np.where(np.isnan(yy), -np.inf, yy), axis=1)
        rows = np.arange(buckets)
        lo, hi = yy[rows, i_lo], yy[rows, i_hi]
        pair = np.where((i_lo <= i_hi)[:, None], np.column_stack([lo, hi]), np.column_stack([hi, lo]))
        outs.append(pair.ravel())
    return (t_out, *outs)


def _fmt(x, fmt="{:.4g}", scale=1.0, none="-"):
    v = _num(x)
    return none if v is None else fmt.format(v * scale)


def plot_style():
    """pyplot, with the report's style (core PDF fonts, sizes, grid) and the Agg backend."""
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    plt.rcParams.update({"font.size": 8.5, "axes.titlesize": 10, "axes.labelsize": 8.5, "legend.fontsize": 7.5,
                         "xtick.labelsize": 7.5, "ytick.labelsize": 7.5, "axes.grid": True, "grid.alpha": 0.3,
                         "lines.linewidth": 0.8, "pdf.compression": 6, "path.simplify": True,
                         # the PDF's 14 core fonts: no glyph embedding, text pages render ~10x faster
                         "pdf.use14corefonts": True, "font.family": "sans-serif",
                         "font.sans-serif": ["Helvetica"], "font.monospace": ["Courier"],
                         "axes.unicode_minus": False})
    return plt


def _title(record: dict) -> str:
    tid = record.get("id")
    label = record.get("label") or ""
    return f"Isolator test report - test {tid}" + (f" - {label}" if label else "") if tid is not None else \
        f"Isolator test report - {label or 'record'}"


def _footer(fig, record, page: int):
    fig.text(0.5, 0.015, f"{_title(record)}  |  page {page}  |  isorig", ha="center", fontsize=7, color="0.4")


def _operator(bundle) -> str | None:
    if bundle.record.get("operator"):
        return bundle.record["operator"]
    for e in bundle.events:
        if e.get("kind") == "operator" and (e.get("values") or {}).get("action") == "start" and e.get("actor"):
            return e["actor"]
    return None


def _profile_text(record: dict, protocol) -> list[str]:
    if protocol is not None:
        lines = _wrap(f"protocol {protocol.name}: {protocol.title}", 88)
        for i, lv in enumerate(protocol.levels[:MAX_HEADER_LEVELS], start=1):
            lines.append(f"  level {i}: {lv.amplitude_m * 1e3:.2f} mm at {lv.frequency_hz:g} Hz, {lv.cycles} test "
                         f"cycles + {lv.taper_cycles} ramp cycles each side")
        if len(protocol.levels) > MAX_HEADER_LEVELS:
            lines.append(f"  ... and {len(protocol.levels) - MAX_HEADER_LEVELS} more levels")
        return lines
    prof = record.get("profile") or {}
    blocks = (record.get("scenario") or {}).get("profile") or ([prof] if prof.get("kind") == "sine" else [])
    if not blocks:
        return ["profile not recorded"]
    return [f"sine {b['amplitude_m'] * 1e3:.2f} mm at {b['frequency_hz']:g} Hz, {b['cycles']} cycles "
            f"(taper {b.get('taper_cycles', 0)}, offset {b.get('offset_m', 0.0) * 1e3:.2f} mm)" for b in blocks[:6]]


def _header_lines(bundle, ctrl: dict, iso, protocol) -> list[tuple[str, str]]:
    r = bundle.record
    scenario = r.get("scenario") or {}
    date = r.get("started_at") or r.get("created_at") or "-"
    status = str(r.get("status") or "-") + (f" ({r['reason']})" if r.get("reason") else "")
    driver = r.get("driver")
    rig = r.get("rig") or ("simulated rig (sim.rig defaults)" if driver == "simulated" else driver) or \
        ("simulated rig (sim.rig defaults)" if scenario.get("control_period_s") else "-")
    lines = [
        ("Lab", r.get("lab") or "-"),
        ("Rig", rig),
        ("Operator", _operator(bundle) or "-"),
        ("Date", str(date)[:19].replace("T", " ") + (" UTC" if date != "-" else "")),
        ("Test status", status[:110]),
    ]
    if iso is not None:
        lines.append(("Isolator", f"{iso.name}" + (f" - {iso.description}" if iso.description else "")))
        lines.append(("  Bouc-Wen (eq. 4)", f"rho_BW = {iso.rho_bw_per_m:g} 1/m, sigma_BW = {iso.sigma_bw:g}, "
                                            f"n = {iso.n:g}, k_d = {iso.kd_n_per_m:.4g} N/m, k_w = {iso.kw_n:.4g} N"))
    else:
        lines.append(("Isolator", str(r.get("isolator") or "not recorded")))
    sb = _num(r.get("supply_bar"))
    lines.append(("Supply pressure", f"{sb:g} bar" if sb is not None else "not recorded"))
    load = _num(r.get("vertical_load_n", (r.get("scenario") or {}).get("vertical_load_n")))
    lines.append(("Vertical load", f"{load / 1e3:g} kN" if load is not None else "not recorded (before 2026-11-24: "
                  "the rig's 125 kN)"))
    for k, text in enumerate(_profile_text(r, protocol)):
        lines.append(("Profile" if k == 0 else "", text))
    lines.append(("Controller", str(ctrl.get("name") or "not recorded")
                  + (f", options {json.dumps(ctrl['options'])}" if ctrl.get("options") else "")))
    if ctrl.get("parameters"):
        text = ", ".join(f"{k} = {v:.4g}" if isinstance(v, float) else f"{k} = {v}"
                         for k, v in ctrl["parameters"].items())
        lines += _wrapped_lines("  parameters", text)
    if ctrl.get("final_adapted"):
        labels = ctrl.get("adapted_labels") or {}
        lines += _wrapped_lines("  final adapted", ", ".join(f"{labels.get(k, k)} = {v:.5g}"
                                                             for k, v in ctrl["final_adapted"].items()))
    dur = _num(r.get("duration_s"))
    lines.append(("Duration, samples", f"{dur:g} s, {bundle.samples.shape[0]} samples" if dur is not None
                  else f"{bundle.samples.shape[0]} samples"))
    if r.get("source"):
        lines.append(("Source", str(r["source"])[-100:]))
    return lines


def _wrapped_lines(key: str, text: str, width: int = 85, max_lines: int = 3) -> list[tuple[str, str]]:
    """Header lines for a long value: wrapped to the page's width, at most ``max_lines`` (then "...")."""
    chunks = _wrap(text, width)
    if len(chunks) > max_lines:
        chunks = chunks[:max_lines]
        chunks[-1] += " ..."
    return [(key if k == 0 else "", chunk) for k, chunk in enumerate(chunks)]


def _page_header(plt, bundle, ctrl, iso, protocol, acc, ident, trk, page):
    """The header page(s), with the Bouc-Wen table."""
    figs, y = _header_pages(plt, bundle, ctrl, iso, protocol, acc, trk, page)
    _identification_block(figs[-1], y, ident, bundle.record, page + len(figs) - 1)
    return figs


def _header_pages(plt, bundle, ctrl, iso, protocol, acc, trk, page):
    """The header page(s) up to the Bouc-Wen table, and where that table starts (it needs the fit)."""
    fig = plt.figure(figsize=A4_PORTRAIT_IN)
    fig.text(0.07, 0.955, _title(bundle.record), fontsize=14, weight="bold")
    fig.text(0.07, 0.935, f"generated {datetime.now(UTC).strftime('%Y-%m-%d %H:%M UTC')}", fontsize=8, color="0.4")
    y = 0.90
    for key, value in _header_lines(bundle, ctrl, iso, protocol):
        fig.text(0.07, y, key, fontsize=9, weight="bold" if key and not key.startswith("  ") else "normal")
        fig.text(0.30, y, value, fontsize=9)
        y -= 0.021
    # verdict box
    y -= 0.015
    summary = acc["summary"]
    if summary["passed"] is None:
        verdict, color = "NO VERDICT", "0.35"
        detail = [acc.get("note") or "no acceptance rules"]
    elif summary["passed"]:
        verdict, color = "PASSED", "#1a7f37"
        detail = [f"protocol {acc['protocol']}: all {summary['verdicts']} checks passed"]
    else:
        verdict, color = "FAILED", "#c62828"
        detail = [f"protocol {acc['protocol']}: {summary['failed']} of {summary['verdicts']} checks failed"]
        for r in summary["failed_rules"][:MAX_HEADER_RULES]:
            detail.append(f"rule {r['rule']}: {r['failures']} failures, e.g. {r['first']}")
        if len(summary["failed_rules"]) > MAX_HEADER_RULES:
            detail.append(f"... and {len(summary['failed_rules']) - MAX_HEADER_RULES} more failing rules: see the "
                          "verdicts page")
    fig.text(0.07, y, "Acceptance", fontsize=11, weight="bold")
    fig.text(0.30, y, verdict, fontsize=13, weight="bold", color=color)
    y -= 0.024
    for line in detail[:8]:
        for chunk in _wrap(line, 105):
            fig.text(0.09, y, chunk, fontsize=8.5)
            y -= 0.017
    if acc.get("rules"):
        y -= 0.004
        for n, t in list(zip(acc["rule_names"], acc["rules"], strict=True))[:MAX_HEADER_RULES]:
            fig.text(0.09, y, f"rule {n}: {t}"[:120], fontsize=8, color="0.3")
            y -= 0.016
    # tracking and limit trips
    y -= 0.01
    fig.text(0.07, y, "Tracking", fontsize=11, weight="bold")
    if trk:
        peak_u = _fmt(trk.get("peak_abs_voltage_v"), "{:.2f}")
        fig.text(0.30, y, f"RMS |y - r| = {trk['rms_y_minus_r_m'] * 1e3:.3f} mm, peak |y - r| = "
                          f"{trk['peak_abs_y_minus_r_m'] * 1e3:.3f} mm, peak |u| = {peak_u} V", fontsize=9)
    else:
        fig.text(0.30, y, "no target recorded", fontsize=9)
    y -= 0.022
    trips = _limit_trips(bundle.events)
    fig.text(0.07, y, "Limit trips", fontsize=11, weight="bold")
    fig.text(0.30, y, f"{len(trips)}" + (f": {trips[0].get('message', '')}"[:100] if trips else " (none)"),
             fontsize=9, color="#c62828" if trips else "black")
    y -= 0.035
    # identification table (on a second header page when the first is full)
    figs = [fig]
    if y < 0.20:
        _footer(fig, bundle.record, page)
        fig = plt.figure(figsize=A4_PORTRAIT_IN)
        figs.append(fig)
        fig.text(0.07, 0.955, _title(bundle.record) + " (continued)", fontsize=12, weight="bold")
        y = 0.91
    return figs, y


def _identification_block(fig, y, ident, record, page):
    """The Bouc-Wen table (nominal, identified, difference) and the footer of the last header page."""
    fig.text(0.07, y, "Bouc-Wen parameters: nominal and identified from this test", fontsize=11, weight="bold")
    y -= 0.024
    nominal = ident.get("nominal") or {}
    rows = [("parameter", "unit", "nominal", "identified", "difference")]
    units = {"rho_bw_per_m": "1/m", "sigma_bw": "-", "n": "-", "kd_n_per_m": "N/m", "kw_n": "N"}
    for k in BOUC_WEN_FIELDS:
        nv = _num(nominal.get(k))
        iv = _num((ident.get("identified") or {}).get(k))
        diff = f"{100 * (iv / nv - 1):+.1f} %" if nv and iv is not None else "-"
        rows.append((k, units[k], _fmt(nv), _fmt(iv), diff))
    for row in rows:
        for x, cell in zip((0.09, 0.27, 0.36, 0.52, 0.68), row, strict=True):
            fig.text(x, y, cell, fontsize=8.5, family="monospace", weight="bold" if row is rows[0] else "normal")
        y -= 0.018
    if not ident.get("available"):
        fig.text(0.09, y, ident.get("note", ""), fontsize=8, color="0.4")
    else:
        nrms = _num((ident.get("fit") or {}).get("nrms_error"))
        fig.text(0.09, y, f"{ident.get('source', '')}" + (f"; force NRMS error {100 * nrms:.2g} %" if nrms is not None
                                                            else ""), fontsize=8, color="0.4")
    _footer(fig, record, page)


def _wrap(text: str, width: int) -> list[str]:
    import textwrap

    return textwrap.wrap(text, width) or [""]


def _page_loops(plt, bundle, protocol, page):
    from matplotlib.collections import LineCollection

    fig, axes = plt.subplots(2, 1, figsize=A4_PORTRAIT_IN, gridspec_kw={"height_ratios": [3, 2]})
    fig.subplots_adjust(left=0.12, right=0.88, top=0.94, bottom=0.07, hspace=0.28)
    ax = axes[0]
    cycles = [c for c in bundle.cycles if c.get("displacement_m") is not None and len(c["displacement_m"]) > 2]
    if cycles:
        step = max(1, math.ceil(len(cycles) / MAX_LOOPS))
        shown = cycles[::step]
        if shown[-1] is not cycles[-1]:
            shown.append(cycles[-1])
        segs = []
        for c in shown:
            d = np.asarray(c["displacement_m"]) * 1e3
            f = np.asarray(c["force_n"]) * 1e-3
            k = max(1, d.size // LOOP_POINTS)
            segs.append(np.column_stack([d[::k], f[::k]]))
        numbers = np.array([c["cycle"] for c in shown], dtype=float)
        lc = LineCollection(segs, cmap="viridis", linewidths=0.8)
        lc.set_array(numbers)
        ax.add_collection(lc)
        ax.autoscale()
        cb = fig.colorbar(lc, ax=ax, pad=0.01, fraction=0.04)
        cb.set_label("cycle")
        ax.set_title(f"Force-displacement loops ({len(shown)} of {len(cycles)} cycles shown)")
    else:
        ax.text(0.5, 0.5, "no complete cycle recorded", ha="center", va="center", transform=ax.transAxes)
        ax.set_title("Force-displacement loops")
    ax.set_xlabel("displacement [mm]")
    ax.set_ylabel("force [kN]")
    ax.axhline(0, color="0.6", lw=0.5)
    ax.axvline(0, color="0.6", lw=0.5)
    # per-cycle K_eff and EDC
    ax2 = axes[1]
    if bundle.cycles:
        n = [c["cycle"] for c in bundle.cycles]
        keff = [(_num(c.get("k_eff_n_per_m")) or np.nan) * 1e-6 for c in bundle.cycles]
        edc = [_num(c.get("edc_j")) if _num(c.get("edc_j")) is not None else np.nan for c in bundle.cycles]
        marker = "o" if len(n) <= 80 else None
        ax2.plot(n, keff, color="C0", marker=marker, ms=3, label="K_eff")
        ax2.set_ylabel("K_eff [kN/mm]", color="C0")
        ax3 = ax2.twinx()
        ax3.plot(n, edc, color="C3", marker=marker, ms=3, label="EDC")
        ax3.set_ylabel("EDC [J]", color="C3")
        ax3.grid(False)
        title = "Effective stiffness and energy dissipated per cycle"
        if protocol is not None:
            for p in protocol.cycle_plan():
                if p["test"]:
                    ax2.axvspan(p["cycle"] - 0.5, p["cycle"] + 0.5, color="0.92", lw=0, zorder=0)
            title += " (shaded: judged test cycles)"
        ax2.set_title(title)
        from matplotlib.ticker import MaxNLocator

        ax2.xaxis.set_major_locator(MaxNLocator(integer=True))
    ax2.set_xlabel("cycle")
    _footer(fig, bundle.record, page)
    return fig


def _page_time(plt, bundle, page):
    s = bundle.samples
    fig, axes = plt.subplots(3, 1, figsize=A4_PORTRAIT_IN, sharex=True)
    fig.subplots_adjust(left=0.12, right=0.95, top=0.94, bottom=0.07, hspace=0.18)
    if len(s):
        t = s["time_s"]
        y, r, u = s["displacement_m"] * 1e3, s["target_m"] * 1e3, s["voltage_v"]
        e = y - r
        td, yd, rd, ud, ed = _minmax_decimate(t, y, r, u, e)
        axes[0].plot(td, rd, color="0.55", lw=1.4, label="target r")
        axes[0].plot(td, yd, color="C0", lw=0.7, label="displacement y")
        axes[0].legend(loc="upper right")
        axes[1].plot(td, ud, color="C2", lw=0.7)
        axes[2].plot(td, ed, color="C3", lw=0.7)
        if np.isfinite(e).any():
            rms = float(np.sqrt(np.nanmean(e * e)))
            axes[2].set_title(f"Tracking error y - r (RMS {rms:.3f} mm)", loc="left")
        for ev in bundle.events:
            if ev.get("kind") == "limit_trip" and _num(ev.get("time_s")) is not None:
                for ax in axes:
                    ax.axvline(ev["time_s"], color="#c62828", lw=1.0, ls="--")
    axes[0].set_title("Displacement and target", loc="left")
    axes[0].set_ylabel("displacement [mm]")
    axes[1].set_title("Servo-valve command voltage", loc="left")
    axes[1].set_ylabel("voltage [V]")
    axes[2].set_ylabel("y - r [mm]")
    axes[2].set_xlabel("time [s]")
    _footer(fig, bundle.record, page)
    return fig


DETAIL_WINDOW_S = 5.0  # long records get a page with the first and last seconds at full resolution


def _page_time_detail(plt, bundle, page):
    """First and last DETAIL_WINDOW_S seconds at full resolution (the overview page is an envelope)."""
    s = bundle.samples
    t = s["time_s"]
    fig, axes = plt.subplots(3, 2, figsize=A4_PORTRAIT_IN, sharey="row")
    fig.subplots_adjust(left=0.12, right=0.95, top=0.93, bottom=0.07, hspace=0.25, wspace=0.08)
    fig.suptitle(f"Detail: the first and the last {DETAIL_WINDOW_S:g} s", fontsize=11, weight="bold", y=0.975)
    windows = [(t[0], t[0] + DETAIL_WINDOW_S), (t[-1] - DETAIL_WINDOW_S, t[-1])]
    for col, (a, b) in enumerate(windows):
        sel = (t >= a) & (t <= b)
        tt = t[sel]
        y, r, u = s["displacement_m"][sel] * 1e3, s["target_m"][sel] * 1e3, s["voltage_v"][sel]
        axes[0, col].plot(tt, r, color="0.55", lw=1.4, label="target r")
        axes[0, col].plot(tt, y, color="C0", lw=0.8, label="displacement y")
        axes[1, col].plot(tt, u, color="C2", lw=0.8)
        axes[2, col].plot(tt, y - r, color="C3", lw=0.8)
        axes[2, col].set_xlabel("time [s]")
        axes[0, col].set_title("start" if col == 0 else "end", loc="left")
    axes[0, 0].legend(loc="upper right")
    axes[0, 0].set_ylabel("displacement [mm]")
    axes[1, 0].set_ylabel("voltage [V]")
    axes[2, 0].set_ylabel("y - r [mm]")
    _footer(fig, bundle.record, page)
    return fig


TABLE_HEAD = ("cycle", "t_start", "d+", "d-", "F+", "F-", "K_eff", "EDC", "xi_eff", "Q_d", "K_d", "check")
TABLE_UNITS = ("", "s", "mm", "mm", "kN", "kN", "kN/mm", "J", "%", "kN", "kN/mm", "(L.cycle)")


TABLE_NOTE = ("F+ and F- are the forces at d+ and d-.  K_eff = (F+ - F-) / (d+ - d-).  EDC = loop area.\n"
              "xi_eff = 2 EDC / (pi K_eff (d+ - d-)^2).  Q_d = force intercept at the loop centre (mean of both "
              "branches).\nK_d = slope on both loading legs beyond half the amplitude.  Details: docs/metrics.md.")


def _table_rows(bundle, acc, protocol=None) -> list[tuple]:
    failed, judged = {}, set()
    for v in acc["verdicts"]:
        judged.add(v["cycle"])
        if not v["passed"]:
            failed.setdefault(v["cycle"], []).append(v["rule"])
    plan = {p["cycle"]: p for p in protocol.cycle_plan()} if protocol is not None else {}
    rows = []
    for c in bundle.cycles:
        p = plan.get(c["cycle"])
        role = "" if p is None else (f"L{p['level']}.{p['level_cycle']}" if p["test"] else f"L{p['level']} ramp")
        check = "FAIL" if c["cycle"] in failed else ("pass" if c["cycle"] in judged else "")
        rows.append((
            str(c["cycle"]), _fmt(c.get("t_start_s"), "{:.2f}"),
            _fmt(c.get("d_max_m"), "{:.3f}", 1e3), _fmt(c.get("d_min_m"), "{:.3f}", 1e3),
            _fmt(c.get("f_max_n"), "{:.3f}", 1e-3), _fmt(c.get("f_min_n"), "{:.3f}", 1e-3),
            _fmt(c.get("k_eff_n_per_m"), "{:.4f}", 1e-6), _fmt(c.get("edc_j"), "{:.2f}"),
            _fmt(c.get("xi_eff"), "{:.2f}", 100), _fmt(c.get("qd_n"), "{:.3f}", 1e-3),
            _fmt(c.get("kd_n_per_m"), "{:.4f}", 1e-6),
            (role + " " + check).strip(),
        ))
    return rows


def _table_line(cells, widths) -> str:
    return " ".join(str(x).rjust(w) if i < len(widths) - 1 else " " + str(x)
                    for i, (x, w) in enumerate(zip(cells, widths, strict=True)))


def _draw_lines(fig, lines, x: float, y_top: float, fontsize: float, pitch_pt: float) -> None:
    """Monospace lines at a fixed pitch below (x, y_top) in figure fractions (exact spacing in any PDF viewer)."""
    items = [item if isinstance(item, tuple) else (item, "black") for item in lines]
    fig.add_artist(_lines_artist()(x, y_top, [(t, c) for t, c in items if t],
                                   [k for k, (t, _c) in enumerate(items, start=1) if t], fontsize, pitch_pt))


@functools.cache
def _lines_artist():
    """An artist that hands each line straight to the renderer, at its baseline.

    One matplotlib Text per line cost about 0.5 ms, mostly measuring every character for a layout that a
    left-aligned, baseline-anchored monospace line does not need: 0.3 s for the 600-row table.
    """
    from matplotlib.artist import Artist
    from matplotlib.font_manager import FontProperties

    class Lines(Artist):
        def __init__(self, x, y_top, lines, rows, fontsize, pitch_pt):
            super().__init__()
            self.x, self.y_top, self.lines, self.rows, self.pitch_pt = x, y_top, lines, rows, pitch_pt
            self.prop = FontProperties(family="monospace", size=fontsize)

        def draw(self, renderer):
            if not self.get_visible() or not self.lines:
                return
            x0, y0 = self.figure.transFigure.transform((self.x, self.y_top))
            step = renderer.points_to_pixels(self.pitch_pt)
            gc = renderer.new_gc()
            for (text, color), k in zip(self.lines, self.rows, strict=True):
                gc.set_foreground(color)
                renderer.draw_text(gc, x0, y0 - k * step, text, self.prop, 0.0)
            gc.restore()
            self.stale = False

    return Lines


def _pages_table(plt, bundle, acc, first_page, protocol=None):
    rows = _table_rows(bundle, acc, protocol)
    widths = (5, 9, 8, 8, 8, 8, 8, 9, 7, 8, 8, 1)
    figs = []
    chunks = [rows[i:i + TABLE_ROWS] for i in range(0, len(rows), TABLE_ROWS)] or [[]]
    for k, chunk in enumerate(chunks):
        fig = plt.figure(figsize=A4_PORTRAIT_IN)
        fig.text(0.06, 0.955, "Per-cycle metrics" + (f" ({k + 1}/{len(chunks)})" if len(chunks) > 1 else ""),
                 fontsize=12, weight="bold")
        _draw_lines(fig, [(line, "0.3") for line in TABLE_NOTE.splitlines()], 0.06, 0.935, 7.5, 9.5)
        lines = [_table_line(TABLE_HEAD, widths), _table_line(TABLE_UNITS, widths),
                 "-" * (sum(widths) + len(widths))]
        lines += [(_table_line(r, widths), "#c62828" if r[-1].endswith("FAIL") else "black") for r in chunk]
        _draw_lines(fig, lines if chunk else ["no complete cycle recorded"], 0.05, 0.885, 8.5, 11.0)
        _footer(fig, bundle.record, first_page + k)
        figs.append(fig)
    return figs


def _pages_verdicts_events(plt, bundle, acc, first_page):
    red = "#c62828"
    lines: list = []
    summary = acc["summary"]
    if acc["protocol"] is None:
        lines.append(acc.get("note") or "no acceptance rules")
    else:
        lines.extend(_wrap(f"Protocol {acc['protocol']}: {acc.get('title', '')}", 105))
        for n, t in zip(acc["rule_names"], acc["rules"], strict=True):
            ok = sum(1 for v in acc["verdicts"] if v["rule"] == n and v["passed"])
            total = sum(1 for v in acc["verdicts"] if v["rule"] == n)
            lines.append((f"  {n}: {t} - {ok}/{total} passed"[:110], "black" if ok == total else red))
        lines.append("")
        failed = [v for v in acc["verdicts"] if not v["passed"]]
        lines.append((f"Failed checks ({len(failed)}):", red) if failed else "All checks passed.")
        for v in failed:
            lines.extend(("  " + w, red) for w in _wrap(v["message"], 103))
    lines.append("")
    lines.append(f"Events ({len(bundle.events)}; limit trips: {len(_limit_trips(bundle.events))})")
    for e in bundle.events:
        t = _num(e.get("time_s"))
        head = f"  {'t = ' + format(t, '8.3f') + ' s' if t is not None else ' ' * 14}  {e.get('kind', ''):<10} "
        msg = str(e.get("message", ""))
        if e.get("kind") == "limit_trip" and e.get("values"):
            msg += "  " + json.dumps(clean_json(e["values"]))[:150]
        color = red if e.get("kind") == "limit_trip" else "black"
        wrapped = _wrap(msg, 105 - len(head))
        lines.append((head + wrapped[0], color))
        lines.extend((" " * len(head) + w, color) for w in wrapped[1:])
    if not bundle.events:
        lines.append("  none recorded")
    per_page = 66
    figs = []
    chunks = [lines[i:i + per_page] for i in range(0, len(lines), per_page)]
    for k, chunk in enumerate(chunks):
        fig = plt.figure(figsize=A4_PORTRAIT_IN)
        fig.text(0.06, 0.955, "Acceptance verdicts, events and limit trips"
                 + (f" ({k + 1}/{len(chunks)})" if len(chunks) > 1 else ""), fontsize=12, weight="bold")
        verdict = {None: ("NO VERDICT", "0.35"), True: ("PASSED", "#1a7f37"), False: ("FAILED", red)}[
            summary["passed"]]
        fig.text(0.94, 0.955, verdict[0], fontsize=12, weight="bold", color=verdict[1], ha="right")
        _draw_lines(fig, chunk, 0.05, 0.925, 8.0, 10.5)
        _footer(fig, bundle.record, first_page + k)
        figs.append(fig)
    return figs


def render_report_pdf(bundle, out, meta: dict | None = None, report: dict | None = None,
                      identify: bool = True, identification=None) -> None:
    """Write the A4 report of a test to ``out`` (a path or a binary file object).

    Pages: header (lab, rig, operator, date, isolator, supply, protocol, controller with its final adapted
    parameters, overall verdict, identified Bouc-Wen parameters), loops and per-cycle K_eff/EDC, time histories
    (displacement and target, voltage, tracking error), the per-cycle table, verdicts, events and limit trips.
    ``meta`` (lab, rig, operator) fills in what the record does not hold; ``report`` (from report_json) saves
    computing the metrics twice; ``identify=False`` skips the Bouc-Wen fit. ``identification``, a function
    returning identified_bouc_wen's answer, lets the fit finish elsewhere meanwhile: the header page that shows
    it is then drawn last and put first (it replaces ``report["identification"]``).
    """
    import logging

    if meta:
        bundle = ReportBundle(record={**bundle.record, **{k: v for k, v in meta.items() if v}},
                              samples=bundle.samples, cycles=bundle.cycles, events=bundle.events)
    if report is None and identification is None:
        report = report_json(bundle, identify=identify)
    elif report is None:
        report = report_json(bundle, identify=False)
    plt = plot_style()
    from matplotlib.backends.backend_pdf import PdfPages

    # the core-font AFM files say "medium" where matplotlib asks for "normal": harmless, silence it
    font_log = logging.getLogger("matplotlib.font_manager")
    level = font_log.level
    font_log.setLevel(logging.ERROR)
    record = bundle.record
    iso = _isolator_of(record)
    protocol, _note = _protocol_of(record)
    acc, trk, ctrl = report["acceptance"], report["tracking"], report["controller"]
    target = out if hasattr(out, "write") else open(out, "wb")
    try:
        with PdfPages(target, metadata={"Title": _title(record), "Creator": "isorig"}) as pdf:
            page_list = _page_list(pdf) if identification is not None else None
            if identification is not None and page_list is None:  # cannot reorder: wait for the fit now
                report["identification"] = identification()
                identification = None
            if identification is None:
                header = _page_header(plt, bundle, ctrl, iso, protocol, acc, report["identification"], trk, 1)
                _save(plt, pdf, header)
            else:  # all but the Bouc-Wen table now; the table when the fit is there
                header, y = _header_pages(plt, bundle, ctrl, iso, protocol, acc, trk, 1)
            figs = [_page_loops(plt, bundle, protocol, len(header) + 1)]
            figs.append(_page_time(plt, bundle, len(header) + len(figs) + 1))
            s = bundle.samples
            if len(s) > 1 and s["time_s"][-1] - s["time_s"][0] > 6 * DETAIL_WINDOW_S:
                figs.append(_page_time_detail(plt, bundle, len(header) + len(figs) + 1))
            figs += _pages_table(plt, bundle, acc, len(header) + len(figs) + 1, protocol)
            figs += _pages_verdicts_events(plt, bundle, acc, len(header) + len(figs) + 1)
            _save(plt, pdf, figs)
            if identification is not None:
                report["identification"] = identification()
                _identification_block(header[-1], y, report["identification"], record, len(header))
                _save(plt, pdf, header)
                page_list[:] = page_list[-len(header):] + page_list[:-len(header)]
    finally:
        font_log.setLevel(level)
        if target is not out:
            target.close()


def _save(plt, pdf, figs) -> None:
    for fig in figs:
        pdf.savefig(fig)
        plt.close(fig)


def _page_list(pdf) -> list | None:
    """The page list of a PdfPages file, to reorder pages before it is closed (matplotlib's PdfFile.pageList,
    not a public API: None where it is not there)."""
    try:
        pages = pdf._ensure_file().pageList
    except AttributeError:
        return None
    return pages if isinstance(pages, list) and not pages else None


def report_pdf_bytes(bundle, meta: dict | None = None, identify: bool = True) -> bytes:
    """The PDF as bytes (for an HTTP response)."""
    buf = io.BytesIO()
    render_report_pdf(bundle, buf, meta, identify=identify)
    return buf.getvalue()
