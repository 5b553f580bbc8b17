"""The data a report is made of: a bundle (record, samples, cycles, events) and what its record says.

A bundle is anything with the attributes of ``backend.store.TestBundle``; ``bundle_from_csv`` builds a
``ReportBundle`` from a CSV record (e.g. ``isorig simulate``'s timeseries.csv, with its summary.json when it sits
beside it). ``isolator_of``, ``protocol_of`` and ``limit_trips`` read the test's conditions and events from a
record; ``num`` and ``clean_json`` turn values into what a report shows (no NaN: None).
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path

import numpy as np

from sim.samples import RECORD_FIELDS, SAMPLE_FIELDS, Samples

from ..units import LAB

UNREPORTED_COLUMNS = ("model_m", "load_pressure_pa")  # in the samples, but neither the PDF nor the JSON shows them
ESTIMATE_COLUMNS = ("ar_hat", "ay_hat", "as_hat")  # adaptive estimates: the report shows their final values


@dataclass
class ReportBundle:
    """The same shape as backend.store.TestBundle, for records that do not come from the store."""

    record: dict
    samples: np.ndarray
    cycles: list[dict] = field(default_factory=list)
    events: list[dict] = field(default_factory=list)


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
    from sim.measurement import measured_rows
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
    measured = measured_rows(samples["flags"])  # a lost period's row holds an older reading: not in the loops
    phases = []
    if blocks:
        from sim.tracking import cycle_phases

        starts, end = profile_cycle_starts_s(blocks)
        cycles = cycle_metrics(t, d, f, starts, end, measured=measured)
        phases = cycle_phases(blocks)
    else:
        cycles = cycle_metrics(t, d, f, measured=measured)
    for c in cycles:
        if phases:  # the split's own plan says which cycles are tapers (without a plan: unknown, none marked)
            c["phase"] = phases[c["cycle"] - 1] if c["cycle"] <= len(phases) else "steady"
        rows = c["i_start"] + np.flatnonzero(measured[c["i_start"]:min(c["i_end"] + 1, n)])
        c["displacement_m"] = d[rows]
        c["force_n"] = f[rows]

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
        # how the run ended, when its summary says (isorig simulate: a stop of the follow monitor, or --rig's status)
        "status": (summary or {}).get("status") or ("aborted" if (summary or {}).get("stopped") else "recorded"),
        "reason": (summary or {}).get("reason") or ((summary or {}).get("stopped") or {}).get("reason"),
        "created_at": datetime.fromtimestamp(stat.st_mtime, UTC).isoformat(),
        "isolator": iso.name if iso else None,
        "supply_bar": supply_bar if supply_bar is not None else scenario.get("supply_bar"),
        "controller": scenario.get("controller"),
        "profile": profile,
        "duration_s": num(scenario.get("duration_s")) or (float(t[-1] - t[0]) if n else 0.0),
        "time_s": float(t[-1]) if n else 0.0,
        "cycles_total": (sum(int(b.cycles) for b in blocks) if blocks else None),
        "cycles_done": len(cycles),
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


def num(x):
    return x if isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x) else None


def protocol_of(record: dict):
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


EARTHQUAKE_KINDS = ("history", "hybrid")


def earthquake_kind(record: dict) -> str | None:
    """``history`` or ``hybrid`` for an earthquake test (the profile's kind; a CSV record of ``isorig simulate
    --history`` has a history in its scenario), else None."""
    profile = record.get("profile")
    kind = profile.get("kind") if isinstance(profile, dict) else None
    if kind in EARTHQUAKE_KINDS:
        return kind
    if kind is None and isinstance((record.get("scenario") or {}).get("history"), dict):
        return "history"
    return None


def earthquake_of(record: dict):
    """(the earthquake profile rebuilt from the record's spec: sim.earthquake.EarthquakeProfile, or None; a note
    when it could not be rebuilt or differs from what the test ran)."""
    spec = record.get("earthquake")
    if not isinstance(spec, dict):
        return None, "the profile's spec is not in this record: the criteria come from the samples alone"
    iso = isolator_of(record)
    if iso is None:
        return None, "the isolator is not known: the profile cannot be rebuilt"
    try:
        from sim.earthquake import earthquake_from_spec

        profile = earthquake_from_spec(spec, iso, record.get("vertical_load_n"))
    except (ImportError, ValueError) as exc:
        return None, f"the profile cannot be rebuilt from its spec: {exc}"
    expected = record.get("earthquake_fingerprint")
    if expected and profile.fingerprint != expected:
        return profile, ("the target rebuilt from the spec now differs from the one the test ran (another version "
                         "of the numerics?): the reference may not be the one of the test")
    return profile, None


def isolator_of(record: dict):
    from sim.isolator import PRESETS, isolator_from_dict

    scenario = record.get("scenario") or {}
    if isinstance(scenario.get("isolator"), dict):
        try:
            return isolator_from_dict(scenario["isolator"])
        except ValueError:
            pass
    name = record.get("isolator")
    return PRESETS.get(name) if isinstance(name, str) else None


def limit_trips(events: list[dict]) -> list[dict]:
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


# --- what the record says about the run, the rig and the events, in words -------------------------------

STATUS_BANNERS = {  # statuses of a test that did not run to its planned end: (banner title, colour)
    "aborted": ("TEST ABORTED", "#c62828"),
    "failed": ("TEST FAILED", "#c62828"),
    "interrupted": ("TEST INTERRUPTED", "#b45309"),
    "stopped": ("TEST STOPPED BEFORE ITS END", "#b45309"),
    "running": ("TEST STILL RUNNING: PROVISIONAL FIGURES", "#6b7280"),
    "ready": ("TEST NOT RUN", "#6b7280"),
}
PHASE_WORDS = {"taper_in": "taper in", "steady": "steady", "taper_out": "taper out", "ramp_out": "ramp out"}


def run_of(bundle) -> dict:
    """What the test actually ran, beside what was planned: status and reason, time run (the last stored
    sample) against the planned duration, cycles done against planned, samples; and the banner a report puts at
    its top when the test did not run to its end (None when it did)."""
    r = bundle.record
    n = len(bundle.samples)
    time_run = num(r.get("time_s"))
    if time_run is None and n:
        time_run = num(float(bundle.samples["time_s"][-1]))
    planned = num(r.get("duration_s"))
    cycles_done = r.get("cycles_done")
    if not isinstance(cycles_done, int):
        cycles_done = len(bundle.cycles)
    cycles_total = r.get("cycles_total") if isinstance(r.get("cycles_total"), int) else None
    status = str(r.get("status") or "unknown")
    reason = r.get("reason") or None
    out = {"status": status, "reason": reason, "time_run_s": time_run, "planned_duration_s": planned,
           "cycles_done": cycles_done, "cycles_planned": cycles_total, "samples": n,
           "control_period_s": num((r.get("scenario") or {}).get("control_period_s")),
           "ended_early": status in STATUS_BANNERS, "banner": None, "kind": earthquake_kind(r)}
    if status in STATUS_BANNERS:
        title, colour = STATUS_BANNERS[status]
        ran = run_text(out)
        out["banner"] = {"title": title, "colour": colour,
                         "reason": reason or ("no reason was recorded" if status not in ("ready", "running")
                                              else ""),
                         "ran": ran}
    archived = r.get("archived")
    if isinstance(archived, dict) and archived.get("at"):
        out["archived"] = archived
    return out


def run_text(run: dict) -> str:
    """'Ran 11.50 s of the 40 s planned; 5 of 20 cycles' (or what of it is known)."""
    parts = []
    t, planned = run["time_run_s"], run["planned_duration_s"]
    if t is not None:
        parts.append(f"ran {t:.2f} s" + (f" of the {planned:g} s planned" if planned is not None else ""))
    elif planned is not None:
        parts.append(f"planned {planned:g} s, nothing recorded")
    done, total = run["cycles_done"], run["cycles_planned"]
    if total == 0 and not done:
        parts.append("no cycles (a hybrid simulation)" if run.get("kind") == "hybrid" else "no cycles (a time history)")
    else:
        parts.append(f"{done} of {total} cycles completed" if total is not None else f"{done} cycles completed")
    text = "; ".join(parts)
    return text[:1].upper() + text[1:]


def rig_of(record: dict) -> dict:
    """The rig the test ran on and its instrumentation: the driver (``simulated`` or ``udp://HOST:PORT``), the
    speed of a simulated test, the sensors (latency, noise, resolution of the position and load pressure
    readings: sim.rig's defaults with the scenario's ``rig_changes``; a UDP rig's own transducers are not
    described over the link) and the link figures of a UDP rig."""
    scenario = record.get("scenario") or {}
    driver = record.get("driver")
    changes = scenario.get("rig_changes") or {}
    simulated = driver == "simulated" or (driver is None and scenario.get("control_period_s") is not None)
    out: dict = {"driver": driver or ("simulated" if simulated else None), "name": record.get("rig"),
                 "rig_name": record.get("rig_name"),  # the lab's name of the rig (isorig serve --rig-name)
                 "rig_file": record.get("rig_file"), "simulated": bool(simulated), "speed": num(record.get("speed")),
                 "control_period_s": num(scenario.get("control_period_s")), "rig_changes": changes, "sensors": []}
    try:
        from sim.rig import DEFAULT_RIG, RigParameters
    except ImportError:  # pragma: no cover - sim is part of the package
        return out
    meta = {f["name"]: f for f in RigParameters().describe()}
    for key in SENSOR_PARAMETERS:
        value = num(changes.get(key, getattr(DEFAULT_RIG, key)))
        out["sensors"].append({"name": key, "value": value, "unit": meta[key]["unit"], "meaning": meta[key]["note"],
                               "changed": key in changes})
    other = {k: v for k, v in changes.items() if k not in SENSOR_PARAMETERS and k in meta}
    out["other_changes"] = [{"name": k, "value": v, "unit": meta[k]["unit"], "meaning": meta[k]["note"]}
                            for k, v in other.items()]
    link = (record.get("summary") or {}).get("link")
    if isinstance(link, dict) and link:
        out["link"] = link
    lost = (record.get("summary") or {}).get("lost_periods")
    if isinstance(lost, int):
        out["lost_periods"] = lost
    return out


SENSOR_PARAMETERS = ("position_latency_s", "position_noise_rms_m", "position_resolution_m", "pressure_latency_s",
                     "pressure_noise_rms_pa")


def rig_text(rig: dict, u=LAB) -> tuple[str, list[str]]:
    """The rig in one line (the lab's name of it first) and its sensors in lines, for the header, in the lab's
    units ``u`` (backend.units.Units)."""
    driver = rig.get("driver")
    if rig.get("name"):
        name = str(rig["name"])
    elif rig.get("simulated"):
        name = "simulated rig (sim.plant: the calibrated fifth-order model of sim.rig)"
    elif isinstance(driver, str) and driver.startswith("udp://"):
        name = f"UDP rig at {driver} (docs/rig-protocol.md)"
    else:
        name = str(driver or "not recorded")
    if rig.get("rig_name"):  # which of the lab's rigs (several may share the records)
        name = f"{rig['rig_name']}: {name}"
    period = rig.get("control_period_s")
    if period:
        name += f"; control and acquisition at {1 / period:g} Hz"
    if rig.get("simulated") and rig.get("speed") not in (None, 1.0):
        name += f"; simulated at {rig['speed']:g}x real time"
    sensors = []
    if rig.get("simulated"):
        by = {s["name"]: s for s in rig.get("sensors", [])}

        def v(key, quantity):
            s = by.get(key)
            return "-" if s is None or s["value"] is None else u.text(quantity, s["value"], sig=3)

        if by and all(x["value"] == 0 for x in by.values()):
            sensors.append("ideal (sim.rig's defaults): the true position and load pressure, without latency, noise "
                           "or rounding; force = A_p x load pressure")
        elif by:
            sensors.append(f"position: latency {v('position_latency_s', 'time')}, noise RMS "
                           f"{v('position_noise_rms_m', 'length')}, resolution {v('position_resolution_m', 'length')}"
                           " (0: ideal)")
            sensors.append(f"load pressure: latency {v('pressure_latency_s', 'time')}, noise RMS "
                           f"{v('pressure_noise_rms_pa', 'pressure')}; force = A_p x load pressure (simulated)")
    else:
        sensors.append("the rig's own transducers (position, force, load and supply pressure): not described over "
                       "the link; see the rig's calibration records")
    if isinstance(rig.get("rig_file"), dict):
        sensors.insert(0, rig_file_text(rig["rig_file"], u))
    for c in rig.get("other_changes", []):
        sensors.append(f"rig parameter {c['name']} = {u.si_unit_text(c['value'], c['unit'], sig=6)} (changed from "
                       "sim.rig's default)")
    link = rig.get("link")
    if link:
        sensors.append("link: " + link_text(link))
    elif rig.get("lost_periods"):
        sensors.append(f"{rig['lost_periods']} control periods without a fresh measurement (held)")
    return name, sensors


def rig_file_text(rig_file: dict, u=LAB) -> str:
    """The rig file in force and its commissioning, in one line: where its values came from."""
    text = f"rig file {rig_file.get('name')} ({rig_file.get('source')})"
    c = rig_file.get("commissioning")
    if not c:
        return text + ": not commissioned (values as written, not measured by isorig identify rig)"
    fit = []
    if num(c.get("flow_r2")) is not None:
        fit.append(f"flow balance R^2 {c['flow_r2']:.4f}")
    if num(c.get("velocity_nrmse")) is not None:
        fit.append(f"replay {100 * c['velocity_nrmse']:.1f} % RMS")
    supply = num(c.get("supply_pa"))
    return (text + f": commissioned {str(c.get('date', '?'))[:10]} on {c.get('rig')}"
            + (f" at {u.text('pressure', supply)}" if supply is not None else "")
            + (f", {c.get('specimen')} mounted" if c.get("specimen") not in (None, "none") else ", no specimen")
            + (f" ({', '.join(fit)})" if fit else ""))


def tracking_verdict_of(record: dict) -> dict:
    """The test's tracking verdict (sim.follow, in its summary), or a note that the record has none."""
    verdict = (record.get("summary") or {}).get("tracking_verdict")
    if isinstance(verdict, dict) and verdict.get("words"):
        return verdict
    return {"verdict": "not_judged", "words": "not judged (recorded before isorig judged how well the table "
                                              "followed)"}


def link_text(link: dict) -> str:
    parts = []
    if link.get("authenticated") is False:
        parts.append(f"link not authenticated (rig protocol {link.get('protocol_version', 1)})")
    elif link.get("authenticated") is True:
        parts.append(f"authenticated (rig protocol {link.get('protocol_version', 2)})")
    for key, words in (("received", "packets received"), ("lost", "lost"), ("lost_periods", "periods lost"),
                       ("rejected", "rejected"), ("rig_commands_missed", "commands the rig missed")):
        if isinstance(link.get(key), (int, float)):
            parts.append(f"{link[key]:g} {words}")
    for key, words in (("round_trip_p50_ms", "round trip median"), ("round_trip_p99_ms", "p99"),
                       ("round_trip_max_ms", "max"), ("host_stall_max_ms", "longest host stall")):
        if num(link.get(key)) is not None:
            parts.append(f"{words} {link[key]:.3g} ms")
    return ", ".join(parts) or "no link figures"


# quantity name suffix -> its quantity (backend.units) or, for one the lab's units do not cover, its unit: longest
# suffix first
_UNITS = (("_m_per_s", "velocity"), ("_pa", "pressure"), ("_ms", "ms"), ("_hz", "frequency"), ("_m", "length"),
          ("_n", "force"), ("_v", "voltage"), ("_s", "time"))
_WORDS = {"voltage_v": "valve command", "tracking_error_m": "|y - r|", "target_m": "target r",
          "displacement_m": "displacement y", "force_n": "force", "load_pressure_pa": "load pressure",
          "supply_pressure_pa": "supply pressure", "time_s": "time"}


def scaled_text(key: str, value, u=LAB) -> str:
    """A value named in SI (``force_n``) in the lab's units ``u`` from its name's suffix: 30062.6 -> '30.06 kN'."""
    for suffix, quantity in _UNITS:
        if key.endswith(suffix) and num(value) is not None:
            return f"{value:.4g} ms" if quantity == "ms" else u.text(quantity, value)
    return f"{value:.4g}" if num(value) is not None and isinstance(value, float) else str(value)


def quantity_text(key: str, value, u=LAB) -> str:
    """``force_n``, 30062.6 -> 'force 30.06 kN'."""
    name = _WORDS.get(key)
    if name is None:
        name = key
        for suffix, _quantity in _UNITS:
            if key.endswith(suffix):
                name = key[:-len(suffix)]
                break
        name = name.replace("_", " ")
    return f"{name} {scaled_text(key, value, u)}"


def stability_trip_text(values: dict) -> str:
    """The RTHS stability monitor's figures recorded with its trip (sim.hybrid_metrics.EnergyMonitor.to_dict):
    at the trip (``at_trip``) and at the end of the block that tripped (the energies go on after the trip)."""
    def figures(v: dict) -> str:
        return ", ".join(f"{words} {v[k]:.4g} J" for k, words in
                         (("added_energy_j", "E_err"), ("limit_j", "limit"), ("reference_energy_j", "reference energy"),
                          ("specimen_energy_j", "work on the specimen"),
                          ("command_energy_j", "work on the commanded path")) if num(v.get(k)) is not None)
    parts = []
    at_trip = values.get("at_trip")
    if isinstance(at_trip, dict) and figures(at_trip):
        when = num(at_trip.get("time_s"))
        parts.append("at the trip" + (f" (t = {when:.3f} s)" if when is not None else "") + ": " + figures(at_trip))
    if figures(values):
        parts.append("at the end of that block: " + figures(values))
    return "; ".join(parts)


def limit_trip_text(values: dict, u=LAB) -> str:
    """A limit trip's recorded values in words (in the lab's units ``u``): what the rig read at the sample that
    tripped, and the limit."""
    from sim.measurement import describe_status

    if values.get("detector") == "rths_stability":
        return stability_trip_text(values)

    shown = ("displacement_m", "target_m", "tracking_error_m", "velocity_m_per_s", "force_n", "load_pressure_pa",
             "supply_pressure_pa", "voltage_v")
    skip = set(shown) | {"detector", "time_s", "limit", "limit_name", "flags", "action", "indication", "escalation"}
    parts = [quantity_text(k, values[k], u) for k in shown if num(values.get(k)) is not None]
    parts += [quantity_text(k, v, u) for k, v in values.items() if k not in skip and isinstance(v, (int, float, str))
              and not isinstance(v, bool) and (num(v) is not None or isinstance(v, str))]
    text = "read at that sample: " + ", ".join(parts) if parts else ""
    name, limit = values.get("limit_name"), num(values.get("limit"))
    if isinstance(name, str) and limit is not None:
        word = _WORDS.get(name, name.replace("_", " "))
        text += f"; limit: {word if word.startswith('|') else '|' + word + '|'} <= {scaled_text(name, limit, u)}"
    flags = values.get("flags")
    if isinstance(flags, (int, float)) and flags:
        text += f"; rig status: {describe_status(int(flags))}"
    return text.lstrip("; ")


def event_text(event: dict, u=LAB) -> str:
    """An event in words: its message (as recorded), and for a limit trip or a rig fault what was recorded with it
    (in the lab's units ``u``)."""
    message = str(event.get("message") or event.get("kind") or "")
    values = event.get("values") or {}
    if event.get("kind") in ("limit_trip", "limit_indicate") and values:
        detail = limit_trip_text(values, u)
        return f"{message} ({detail})" if detail else message
    if event.get("kind") == "rig_fault" and isinstance(values.get("link"), dict):
        return f"{message} (link: {link_text(values['link'])})"
    return message
