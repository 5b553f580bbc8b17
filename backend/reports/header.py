"""The header page(s): the lab's band (logo, name, address), the test's status banner when it did not run to its
end, who and what was tested, the conditions, the results from the steady cycles (headline figures, acceptance
verdict, tracking, limit trips), notes, rig and sensors, controller, and the Bouc-Wen parameters identified
beside the nominal ones (a block that can be added last, when a fit made elsewhere arrives).

Text flows from the top down (layout.Flow) and continues on a second page when the first is full; nothing is
cut short. Footers ("page N of M") are drawn by document.py once every page exists.
"""

from __future__ import annotations

from datetime import UTC, datetime

from sim.tracking_figure import tracking_text

from ..units import LAB
from .data import PHASE_WORDS, earthquake_kind, num, rig_text
from .identification import BOUC_WEN_FIELDS
from .layout import PAGE_BOTTOM, Flow, fmt_num, report_title, rule, wrap_items, wrap_pt

MAX_HEADER_LEVELS = 6  # the header page lists at most this many protocol levels ...
MAX_HEADER_RULES = 4  # ... and failing rules (all of them are on the verdicts page)

KEY_X, VALUE_X, RIGHT_X = 0.06, 0.25, 0.94
VALUE_WIDTH_PT = (RIGHT_X - VALUE_X) * 595.0  # A4 width in points: 595
BODY = 8.5  # pt: body text
PITCH = 11.0  # pt: body line pitch
RED, GREEN, GREY = "#c62828", "#1a7f37", "0.35"
VERDICT_COLOURS = {"PASSED": GREEN, "FAILED": RED, "INCOMPLETE": "#b45309", "NO VERDICT": GREY,
                   "NOT REACHED": GREY}
IDENTIFICATION_PT = 16 + 7 * 10.5 + 12  # the Bouc-Wen block's height: heading, 6 rows, note


def page_header(plt, bundle, report, iso, protocol, lab):
    """The header page(s), with the Bouc-Wen table."""
    flow = header_pages(plt, bundle, report, iso, protocol, lab)
    identification_block(flow, report["identification"], lab.unit_system if lab is not None else LAB)
    return flow.figs


def header_pages(plt, bundle, report, iso, protocol, lab) -> Flow:
    """The header page(s) up to the Bouc-Wen table, with room left for it (it needs the fit: ``identification_
    block`` draws it later on ``flow.fig``, so the number of header pages is known before the fit)."""
    record = bundle.record
    u = lab.unit_system if lab is not None else LAB
    flow = Flow(plt, report_title(record))
    fig = flow.new_page(continued=False)
    _lab_band(fig, record, lab)
    flow.y = 0.898
    flow.text(KEY_X, report_title(record), pitch=15, fontsize=13, weight="bold")
    run = report["run"]
    if run.get("banner"):
        _banner(flow, run["banner"])
    flow.skip(4)

    _section(flow, "Test")
    for key, value in _test_lines(bundle, report, iso, u):
        _kv(flow, key, value)
    _section(flow, "Conditions")
    for key, value in _condition_lines(record, protocol, u):
        _kv(flow, key, value)
    _results(flow, report, protocol, u)
    # the setup on a page of its own: page 1 is the summary a reader signs off
    flow.new_page(title=report_title(record) + ": test setup")
    _section(flow, "Rig and sensors")
    rig_name, sensors = rig_text(report["rig"], u)
    _kv(flow, "Rig", rig_name)
    for k, line in enumerate(sensors):
        _kv(flow, "Sensors" if k == 0 else "", line)
    _section(flow, "Controller")
    for key, value in _controller_lines(report["controller"], u):
        _kv(flow, key, value)
    version = (report.get("software") or {}).get("isorig") or "(version unknown)"
    _kv(flow, "Software", f"isorig {version}: loop metrics and headline figures sim.metrics, verdicts "
                          "sim.protocols, identification sim.identify_bouc_wen (report format "
                          f"{report.get('report_version')})")
    flow.skip(6)
    flow.room(IDENTIFICATION_PT)
    return flow


BOUC_WEN_QUANTITIES = {"rho_bw_per_m": "inverse_length", "sigma_bw": "ratio", "n": "ratio", "kd_n_per_m": "stiffness",
                       "kw_n": "force"}


def identification_block(flow: Flow, ident: dict, u=LAB) -> None:
    """The Bouc-Wen table (nominal, identified, difference) in the lab's units ``u`` (backend.units.Units), where
    header_pages left room for it."""
    fig = flow.fig
    flow.text(KEY_X, "Bouc-Wen parameters: nominal and identified from this test", pitch=16, fontsize=10.5,
              weight="bold")
    nominal = ident.get("nominal") or {}
    rows = [("parameter", "unit", "nominal", "identified", "difference")]
    for k in BOUC_WEN_FIELDS:
        nv = num(nominal.get(k))
        iv = num((ident.get("identified") or {}).get(k))
        diff = f"{100 * (iv / nv - 1):+.1f} %" if nv and iv is not None else "-"
        q = BOUC_WEN_QUANTITIES[k]  # four significant digits in every unit: a parameter, not a reading
        rows.append((k, u.unit(q), u.fmt(q, nv, sig=4), u.fmt(q, iv, sig=4), diff))
    for row in rows:
        flow.row([(x, cell) for x, cell in zip((0.08, 0.26, 0.35, 0.51, 0.67), row, strict=True)], pitch=10.5,
                 fontsize=8.5, family="monospace", weight="bold" if row is rows[0] else "normal")
    if not ident.get("available"):
        note = ident.get("note", "")
    else:
        nrms = num((ident.get("fit") or {}).get("nrms_error"))
        note = f"{ident.get('source', '')}" + (f"; force NRMS error {100 * nrms:.2g} %" if nrms is not None else "")
    flow.y -= flow.frac(12)
    fig.text(0.08, max(flow.y, PAGE_BOTTOM), note[:160], fontsize=8, color="0.4")


# --- the parts of the page ------------------------------------------------------------------------------

def _lab_band(fig, record, lab) -> None:
    """Logo, lab name and address at the top left; report, test and issue date at the top right; a rule."""
    x = KEY_X
    if lab is not None and lab.logo is not None:
        h_px, w_px = lab.logo.shape[:2]
        height = 0.045  # of the page height: 38 pt, 13 mm
        width = min(0.25, height * 11.69 / 8.27 * w_px / h_px)
        ax = fig.add_axes((KEY_X, 0.975 - height, width, height))
        ax.imshow(lab.logo, interpolation="antialiased")
        ax.set_axis_off()
        ax.set_anchor("W")
        x = KEY_X + width + 0.015
    name = lab.name if lab is not None else ""
    if name:
        fig.text(x, 0.958, name, fontsize=12, weight="bold")
        for k, line in enumerate(lab.address_lines[:3]):
            fig.text(x, 0.944 - k * 0.0115, line, fontsize=8, color="0.25")
    else:
        fig.text(x, 0.958, "laboratory not set", fontsize=10, color="0.55", style="italic")
        fig.text(x, 0.944, "set ISORIG_LAB_NAME, ISORIG_LAB_ADDRESS, ISORIG_LAB_LOGO_FILE (or isorig report "
                 "--lab-name, --lab-address, --lab-logo)", fontsize=7, color="0.55")
    fig.text(RIGHT_X, 0.958, "TEST REPORT", fontsize=12, weight="bold", ha="right")
    tid = record.get("id")
    fig.text(RIGHT_X, 0.944, f"test record {tid}" if tid is not None else "CSV record", fontsize=8.5, ha="right")
    fig.text(RIGHT_X, 0.9325, f"issued {datetime.now(UTC).strftime('%Y-%m-%d %H:%M UTC')}", fontsize=7.5,
             color="0.4", ha="right")
    rule(fig, 0.912, color="0.3", lw=0.8)


def _banner(flow: Flow, banner: dict) -> None:
    """A coloured box across the page: what happened (ABORTED ...), why, and what ran."""
    from matplotlib.patches import Rectangle

    # bold Helvetica is up to 10 % wider than the regular widths wrap_pt measures: wrap as if the text were larger
    reason = wrap_pt(banner["reason"], (RIGHT_X - KEY_X - 0.04) * 595.0, 9.5 * 1.1) if banner.get("reason") else []
    lines = [(banner["title"], 13, "bold")] + [(r, 9.5, "bold") for r in reason] + [(banner["ran"], 9, "normal")]
    height = 8 + 17 + 12.5 * (len(lines) - 1) + 4
    flow.skip(4)
    fig, top = flow.fig, flow.y
    fig.add_artist(Rectangle((KEY_X, top - flow.frac(height)), RIGHT_X - KEY_X, flow.frac(height),
                             transform=fig.transFigure, facecolor=banner["colour"], edgecolor="none"))
    y = top - flow.frac(8 + 13)
    for k, (text, size, weight) in enumerate(lines):
        fig.text(KEY_X + 0.015, y, text, fontsize=size, weight=weight, color="white")
        y -= flow.frac(17 if k == 0 else 12.5)
    flow.y = top - flow.frac(height)


def _section(flow: Flow, title: str) -> None:
    flow.room(16 + 2 * PITCH)  # a heading never ends a page
    flow.text(KEY_X, title, pitch=16, fontsize=10.5, weight="bold")
    flow.skip(1)


def _kv(flow: Flow, key: str, value, **kw) -> None:
    """A key and its value wrapped to the value column: every word shown, as many lines as it needs (a list of
    items is broken between items only)."""
    lines = wrap_items(value, VALUE_WIDTH_PT, BODY) if isinstance(value, list) else wrap_pt(value, VALUE_WIDTH_PT,
                                                                                              BODY)
    for k, line in enumerate(lines):
        flow.room(PITCH)
        flow.y -= flow.frac(PITCH)
        if k == 0 and key:
            flow.fig.text(KEY_X, flow.y, key, fontsize=BODY, weight="bold" if not key.startswith(" ") else "normal")
        flow.fig.text(VALUE_X, flow.y, line, fontsize=BODY, **kw)


def _date(value) -> str | None:
    return str(value)[:19].replace("T", " ") + " UTC" if value else None


def _test_lines(bundle, report, iso, u=LAB) -> list[tuple[str, str]]:
    r = bundle.record
    run = report["run"]
    lines = [("Specimen", str(r.get("specimen_id") or "not recorded"))]
    if iso is not None:
        lines.append(("Isolator model", f"{iso.name}" + (f" - {iso.description}" if iso.description else "")
                      + f"; nominal Bouc-Wen (eq. 4): rho_BW = {u.text('inverse_length', iso.rho_bw_per_m)}, sigma_BW "
                        f"= {iso.sigma_bw:g}, n = {iso.n:g}, k_d = {u.text('stiffness', iso.kd_n_per_m)}, k_w = "
                        f"{u.text('force', iso.kw_n, sig=4)}"))
    else:
        lines.append(("Isolator model", str(r.get("isolator") or "not recorded")))
    approval = report["approval"]
    by = f" (started by {approval['started_by']!r})" if approval.get("started_by") else ""
    lines.append(("Operator", approval.get("tested_by") or f"not recorded{by}"))
    started, ended, created = _date(r.get("started_at")), _date(r.get("ended_at")), _date(r.get("created_at"))
    if started:
        lines.append(("Date", f"started {started}" + (f", ended {ended}" if ended else "")))
    else:
        lines.append(("Date", f"created {created}" if created else "not recorded"))
    status = run["status"] + (f": {run['reason']}" if run.get("reason") else "")
    lines.append(("Status", status))
    t, planned = run["time_run_s"], run["planned_duration_s"]
    if t is None:
        lines.append(("Duration", "nothing recorded" + (f" (planned {planned:g} s)" if planned is not None else "")))
    elif planned is None:
        lines.append(("Duration", f"{t:.2f} s (the last sample)"))
    elif run["ended_early"]:
        lines.append(("Duration", f"{t:.2f} s run of the {planned:g} s planned ({100 * t / planned:.0f} %)"
                      if planned > 0 else f"{t:.2f} s run"))
    else:
        lines.append(("Duration", f"{t:.2f} s (planned {planned:g} s)"))
    head = report["headline"]
    parts = [f"{run['cycles_done']} completed" + (f" of {run['cycles_planned']} planned" if run["cycles_planned"]
                                                 else "")]
    if report.get("earthquake") and not run["cycles_done"]:
        parts = ["none: an earthquake test has no cycles (it is judged by the J criteria)"]
    elif head.get("phases_known"):
        phases = ", ".join(f"{n} {PHASE_WORDS.get(p, p)}" for p, n in head["excluded_cycles"].items())
        parts.append(f"{head['steady_cycles']} steady" + (f", {phases}" if phases else ""))
    else:
        parts.append("phases not known (no profile): every cycle counted as steady")
    lines.append(("Cycles", "; ".join(parts)))
    period = run.get("control_period_s")
    lines.append(("Samples", f"{run['samples']}" + (f" at {1 / period:g} Hz" if period else "")))
    if run.get("archived"):
        a = run["archived"]
        lines.append(("Archived", f"{_date(a.get('at'))} by {a.get('by')}: {a.get('reason')}"))
    if r.get("source"):
        lines.append(("Source", str(r["source"])))
    notes = str(r.get("notes") or "").strip()
    if notes:
        lines.append(("Notes", notes))
    return lines


def _condition_lines(r: dict, protocol, u=LAB) -> list[tuple[str, str]]:
    lines = []
    sb = num(r.get("supply_bar"))
    lines.append(("Supply pressure", u.text("pressure", sb * 1e5) if sb is not None else "not recorded"))
    load = num(r.get("vertical_load_n", (r.get("scenario") or {}).get("vertical_load_n")))
    lines.append(("Vertical load", u.text("force", load) if load is not None else "not recorded"))
    for k, text in enumerate(_profile_text(r, protocol, u) if earthquake_kind(r) is None
                             else earthquake_profile_lines(r, u)):
        lines.append(("Profile" if k == 0 else "", text))
    limits = r.get("limits") or {}
    if limits:
        parts = []
        actions = limits.get("actions") or {}
        for key, words, quantity in (("displacement_m", "|y|", "length"), ("force_n", "|F|", "force"),
                                     ("velocity_m_per_s", "|dy/dt|", "velocity"),
                                     ("load_pressure_pa", "|P_L|", "pressure"),
                                     ("tracking_error_m", "|y - r|", "length")):
            if num(limits.get(key)) is not None:
                action = actions.get(key, "valve_close")
                note = "" if action == "valve_close" else f" ({action.replace('_', ' ')})"
                parts.append(f"{words} <= {u.text(quantity, limits[key], sig=4)}{note}")
        lines.append(("Limits", ", ".join(parts) + "; supply pressure >= 50 % of its setting; rig faults; a frozen "
                      "position reading"))
        if follow_action(limits) == "indicate":  # said always: the detector may have fired or not, nothing stopped
            lines.append(("", FOLLOW_INDICATE_WORDS))
    return lines


FOLLOW_INDICATE_WORDS = "follow detector: indicate (a table that does not follow is an event, the test goes on)"


def follow_action(limits: dict) -> str | None:
    """The follow detector's action as the record's limits give it (``actions.follow``, else ``follow.action``:
    sim.safety.SafetyLimits.to_dict), or None when they do not say."""
    action = (limits.get("actions") or {}).get("follow")
    if action is None and isinstance(limits.get("follow"), dict):
        action = limits["follow"].get("action")
    return action


def _profile_text(record: dict, protocol, u=LAB) -> list[str]:
    if protocol is not None:
        lines = [f"protocol {protocol.name}: {protocol.title}"]
        for i, lv in enumerate(protocol.levels[:MAX_HEADER_LEVELS], start=1):
            lines.append(f"level {i}: {u.text('length', lv.amplitude_m)} at {lv.frequency_hz:g} Hz, {lv.cycles} test "
                         f"cycles + {lv.taper_cycles} taper cycles each side")
        if len(protocol.levels) > MAX_HEADER_LEVELS:
            lines.append(f"... and {len(protocol.levels) - MAX_HEADER_LEVELS} more levels (all on the verdicts "
                         "page)")
        return lines
    prof = record.get("profile") or {}
    blocks = (record.get("scenario") or {}).get("profile") or ([prof] if prof.get("kind") == "sine" else [])
    if not blocks:
        return ["profile not recorded"]
    return [f"sine {u.text('length', b['amplitude_m'])} at {b['frequency_hz']:g} Hz, {b['cycles']} cycles "
            f"(taper {b.get('taper_cycles', 0)} each side, offset {u.text('length', b.get('offset_m', 0.0))})"
            for b in blocks[:MAX_HEADER_LEVELS]] + ([f"... and {len(blocks) - MAX_HEADER_LEVELS} more blocks"]
                                                    if len(blocks) > MAX_HEADER_LEVELS else [])


def _controller_lines(ctrl: dict, u=LAB) -> list[tuple[str, str | list[str]]]:
    name = ctrl.get("name")
    if not name:
        return [("Controller", "not recorded")]
    asked = ctrl.get("options") or {}
    lines = [("Controller", f"{name}; " + ("options set for this test (marked *): " + ", ".join(asked)
                                           if asked else "its default options"))]
    opts = []
    for o in ctrl.get("options_in_force") or []:
        v = o["value"]
        if isinstance(v, float):  # in the lab's units when the option is one of its quantities (m, N, N/m ...)
            text = u.si_unit_text(v, o.get("unit"))
        else:
            unit = o.get("unit")
            text = str(v) + (f" {unit}" if unit and unit != "-" and not isinstance(v, (bool, str)) else "")
        opts.append(f"{o['name']}{'*' if o.get('set_for_test') else ''} = {text}")
    if opts:
        lines.append(("  options in force", opts))
    adapted = ctrl.get("adapted") or []
    if adapted:
        parts = []
        for a in adapted:
            final = num(a.get("final"))
            parts.append(f"{a['name']} = {u.si_unit_text(final, a['unit'], sig=5)}" if final is not None
                         else f"{a['name']}: not recorded")
        lines.append(("  adapted (final)", parts))
    else:
        lines.append(("  adapted", "nothing: a fixed-gain controller"))
    return lines


# --- results: headline figures, acceptance, tracking, limit trips ----------------------------------------

# the headline figures: metric, its name, its quantity (backend.units: the unit and digits of the lab's units)
HEADLINE_COLUMNS = (("k_eff_n_per_m", "K_eff", "stiffness"), ("edc_j", "EDC", "energy"),
                    ("xi_eff", "xi_eff", "percent"), ("qd_n", "Q_d", "force"), ("kd_n_per_m", "K_d", "stiffness"))


def headline_rows(head: dict, u=LAB, design: dict | None = None) -> list[tuple[str, str]]:
    """The headline table as monospace lines (and their colour), in the lab's units ``u``. A protocol's figures
    are per level only (a mean over levels of different amplitudes means little), each level followed by its
    design values and verdict when ``design`` (acceptance's ``design``) has them."""
    def line(label, cells, tail):
        return f"{label:<27}" + "".join(f"{c:>9}" for c in cells) + f"   {tail}"

    rows = [(line("", [c[1] for c in HEADLINE_COLUMNS], "steady cycles"), "black"),
            (line("", [u.unit(c[2]) for c in HEADLINE_COLUMNS], ""), "0.4")]

    def values(means):
        return [u.fmt(q, (means or {}).get(k), trailing_zeros=True) for k, _n, q in HEADLINE_COLUMNS]

    levels = head.get("levels") or []
    if not levels:
        rows.append((line("mean of the steady cycles", values(head["means"]),
                          f"{head['steady_cycles']} of {head['cycles']}"), "black"))
    by_level = {lv["level"]: lv for lv in (design or {}).get("levels") or []}
    for lv in levels:
        label = f"level {lv['level']}: {u.text('length', lv['amplitude_m'])} {lv['frequency_hz']:g} Hz"
        tail = f"{lv['steady_cycles']} of {lv['cycles']}" if lv["cycles"] else "not reached"
        rows.append((line(label[:27], values(lv["means"]), tail), "black" if lv["cycles"] else "0.45"))
        d = by_level.get(lv["level"])
        if d is not None:
            cells = [u.fmt(q, d["design"].get(k), trailing_zeros=True) if k in d["design"] else "-"
                     for k, _n, q in HEADLINE_COLUMNS]
            rows.append((line("  design value", cells, d["verdict"]), VERDICT_COLOURS.get(d["verdict"], GREY)))
    return rows


def earthquake_profile_lines(record: dict, u=LAB) -> list[str]:
    """The profile of a history or hybrid test in words (from the record's ``profile``: sim.earthquake's
    description)."""
    prof = record.get("profile") or {}
    kind = prof.get("kind")
    lines = []
    if kind == "hybrid":
        st = prof.get("structure") or {}
        masses = ", ".join(u.fmt("mass", m) for m in st.get("masses_kg") or [])
        springs = ", ".join(u.fmt("stiffness", k) for k in st.get("stiffness_n_per_m") or [])
        periods = ", ".join(f"{p:.3f}" for p in prof.get("fixed_base_periods_s") or [])
        lines.append(f"real-time hybrid simulation: {st.get('name') or 'a shear building'} above the isolator "
                     f"(base {u.text('mass', num(st.get('base_mass_kg')) or 0)}, storeys {masses} "
                     f"{u.unit('mass')}, springs {springs} {u.unit('stiffness')}, "
                     f"{100 * (num(st.get('damping_ratio')) or 0):g} % Rayleigh; fixed-base periods {periods} s)")
        stab = prof.get("stability") or {}
        if stab:
            lines.append(f"stability monitor: trips above max({stab.get('limit_j', 0):g} J, "
                         f"{100 * stab.get('relative_limit', 0):g} % of the input energy)")
    elif kind == "history" or kind is None:
        source = prof.get("source") or ((record.get("scenario") or {}).get("history") or {}).get("source")
        lines.append(f"time history: {source or 'source not recorded'}")
    gm = prof.get("ground_motion")
    if isinstance(gm, dict):
        if gm.get("preset"):
            lines.append(f"ground motion {gm['preset']} x {prof.get('scale', 1):g} (synthetic, seed {gm.get('seed')}, "
                         f"{num(gm.get('duration_s')) or 0:g} s, PGA {num(gm.get('pga_g')) or 0:.3g} g before scaling)")
        elif gm.get("inline"):
            lines.append(f"ground motion given inline x {prof.get('scale', 1):g} ({gm.get('samples')} samples at "
                         f"{num(gm.get('dt_s')) or 0:g} s in {gm.get('units')}, PGA {num(gm.get('pga_g')) or 0:.3g} g)")
    history = (record.get("scenario") or {}).get("history") or {}
    dur = num(prof.get("duration_s", history.get("duration_s")))
    peak = num(prof.get("peak_displacement_m", history.get("peak_displacement_m")))
    vel = num(prof.get("peak_velocity_m_per_s", history.get("peak_velocity_m_per_s")))
    what = "predicted (the reference) " if kind == "hybrid" else ""
    if dur is not None and peak is not None:
        tapers = (f", tapers {prof.get('taper_in_s', history.get('taper_in_s', 0)):g} s in and "
                  f"{prof.get('taper_out_s', history.get('taper_out_s', 0)):g} s out") if kind != "hybrid" else ""
        lines.append(f"{dur:g} s at 1 kHz; {what}peak displacement {u.text('length', peak)}, peak velocity "
                     f"{u.text('velocity', vel or 0)}{tapers}")
    return lines


CRITERIA_WORDS = {"j1_delay_ms": "delay of y behind r", "j2_rms_percent": "RMS of y - r / RMS of r",
                  "j3_peak_percent": "peak |y - r| / peak |r|",
                  "j4_rms_percent": "base displacement: RMS error / reference RMS",
                  "j5_peak_percent": "base displacement: peak error / reference peak"}


def criteria_rows(eq: dict) -> list[tuple[str, str]]:
    """The J criteria as monospace lines: criterion, value, target, met or not, what it measures (and the
    colour: green met, red not met)."""
    rows = [(f"{'criterion':<10}{'value':>10}  {'target':<15}{'result':<9}what it measures", "black")]
    for v in eq.get("verdicts") or []:
        value = "-" if v["value"] is None else f"{v['value']:.3f} {v['unit']}"
        result = "met" if v["met"] else ("NOT MET" if v["met"] is False else "-")
        rows.append((f"{v['name']:<10}{value:>10}  {v['bound']:<15}{result:<9}"
                     f"{CRITERIA_WORDS.get(v['key'], v['meaning'])}",
                     GREEN if v["met"] else (RED if v["met"] is False else "black")))
    return rows


def _earthquake_results(flow: Flow, report: dict) -> None:
    eq = report["earthquake"]
    kind = eq.get("kind")
    _section(flow, "Results (the J criteria of the RTHS benchmark)")
    verdicts = eq.get("verdicts") or []
    if verdicts:
        for text, colour in criteria_rows(eq):
            flow.text(KEY_X + 0.02, text, pitch=10.5, fontsize=8.0, family="monospace", color=colour)
        met = sum(1 for v in verdicts if v["met"])
        judged = eq.get("judged") or {}
        note = (f"{met} of {len(verdicts)} targets met. J1-J3: the target against the measured displacement over "
                f"{judged.get('what', 'the record')} ({judged.get('samples', 0)} samples)")
        if kind == "hybrid":
            note += ("; J4-J5: the structure's base displacement against the full-numerical reference; "
                     + (eq.get("reference") or {}).get("note", ""))
        for line in wrap_pt(note + ".", (RIGHT_X - KEY_X) * 595.0, 7.8):
            flow.text(KEY_X + 0.02, line, pitch=10, fontsize=7.8, color="0.35")
    else:
        flow.text(KEY_X + 0.02, "no criteria: " + str((eq.get("judged") or {}).get("note") or eq.get("note") or
                                                        "too few samples"), pitch=PITCH, fontsize=BODY, color=RED)
    if eq.get("note") and verdicts:
        _kv(flow, "Note", eq["note"], color=RED)
    stab = eq.get("stability")
    if kind == "hybrid" and stab:
        tripped = bool(stab.get("tripped"))
        if tripped:  # the reason has the figures at the trip; the others are the monitor's last state
            text = (f"TRIPPED: {stab.get('reason')}. At the end of the record: E_err = "
                    f"{fmt_num(stab.get('added_energy_j'), '{:.4g}')} J, reference energy "
                    f"{fmt_num(stab.get('reference_energy_j'), '{:.4g}')} J")
        else:
            text = (f"not tripped: added energy E_err = {fmt_num(stab.get('added_energy_j'), '{:.4g}')} J at the end, "
                    f"{100 * (num(stab.get('indicator')) or 0):.1f} % of its limit "
                    f"{fmt_num(stab.get('limit_j'), '{:.4g}')} J (max({fmt_num(stab.get('absolute_limit_j'), '{:g}')}"
                    f" J, {100 * (num(stab.get('relative_limit')) or 0):g} % of the reference energy "
                    f"{fmt_num(stab.get('reference_energy_j'), '{:.4g}')} J))")
            peak = num(stab.get("peak_indicator"))
            if peak is not None:
                text += (f"; at most {100 * peak:.1f} % of the limit during the test (t = "
                         f"{fmt_num(stab.get('peak_indicator_time_s'), '{:.3f}')} s)")
        _kv(flow, "Stability", text, color=RED if tripped else "black")
    flow.skip(4)


def _results(flow: Flow, report: dict, protocol, u=LAB) -> None:
    if report.get("earthquake"):
        _earthquake_results(flow, report)
    else:
        _headline_results(flow, report["headline"], u, report["acceptance"].get("design"))
    _acceptance_and_tracking(flow, report, u)


def _headline_results(flow: Flow, head: dict, u=LAB, design: dict | None = None) -> None:
    _section(flow, "Results (from the steady cycles)")
    if head["steady_cycles"]:
        for text, colour in headline_rows(head, u, design):
            flow.text(VALUE_X - 0.19 + 0.02, text, pitch=10.5, fontsize=8.3, family="monospace", color=colour)
        left_out = ", ".join(f"{n} {PHASE_WORDS.get(p, p)}" for p, n in head["excluded_cycles"].items())
        note = ("Means over the steady cycles" + (" of each level" if head.get("levels") else "")
                + " (sim.metrics.headline_figures)"
                + (f"; left out: {left_out} (lower amplitude)" if left_out else "")
                + ". Every cycle is in the table and the plots; the tapers are marked.")
        if design and design.get("levels"):
            t = design["tolerances"]
            note += (f" Design value: the declared isolator model through the level's target; each test cycle "
                     f"within +-{100 * t['k_eff']:g} % (K_eff), +-{100 * t['edc']:g} % (EDC), "
                     f"+-{100 * t['xi_eff']:g} % (xi_eff) of it and the level's mean within +-{100 * t['mean']:g} "
                     f"% ({design.get('source')}).")
        for line in wrap_pt(note, (RIGHT_X - KEY_X) * 595.0, 7.8):
            flow.text(KEY_X + 0.02, line, pitch=10, fontsize=7.8, color="0.35")
    else:
        flow.text(KEY_X + 0.02, f"no steady cycle completed ({head['cycles']} cycles in all): no headline figures",
                  pitch=PITCH, fontsize=BODY, color=RED)
    flow.skip(4)


def _acceptance_and_tracking(flow: Flow, report: dict, u=LAB) -> None:
    acc = report["acceptance"]
    word = acc["verdict"]
    flow.room(14 + 3 * PITCH)
    flow.row([(KEY_X, "Acceptance", {"fontsize": 10, "weight": "bold"}),
              (VALUE_X, word, {"fontsize": 12, "weight": "bold", "color": VERDICT_COLOURS[word]})], pitch=15)
    summary = acc["summary"]
    detail: list[tuple[str, str]] = []
    if acc["protocol"] is None:
        detail.append((acc.get("note") or "no acceptance rules", "black"))
    else:
        made = summary["verdicts"] - acc.get("checks_missing", 0)
        if word == "INCOMPLETE":
            detail.append((f"protocol {acc['protocol']}: the test ended before its end; {acc['checks_missing']} of "
                           f"{summary['verdicts']} checks have no measured steady cycle. Of the {made} checks made, "
                           f"{made - (summary['failed'] - acc['checks_missing'])} passed and "
                           f"{summary['failed'] - acc['checks_missing']} failed. Not a complete test.", "black"))
        elif word == "PASSED":
            detail.append((f"protocol {acc['protocol']}: all {summary['verdicts']} checks of its rules passed "
                           "(steady cycles only)", "black"))
        else:
            detail.append((f"protocol {acc['protocol']}: {summary['failed']} of {summary['verdicts']} checks "
                           "of its rules failed (steady cycles only)", "black"))
        design = acc.get("design") or {}
        if design.get("levels"):
            words = ", ".join(f"level {lv['level']} {lv['verdict']}" for lv in design["levels"])
            bad = any(lv["verdict"] in ("FAILED", "INCOMPLETE") for lv in design["levels"])
            detail.append((f"against the design values (K_eff, EDC, xi_eff): {words}", RED if bad else "black"))
        elif design.get("note"):
            detail.append((design["note"], "0.35"))
        for r in acc.get("rule_details", []):
            ok = r["passed"] == r["checks"]
            detail.append((f"rule {r['name']}: {r['text']} - {r['passed']} of {r['checks']} passed",
                           "black" if ok else RED))
        for r in summary["failed_rules"][:MAX_HEADER_RULES]:
            if word != "INCOMPLETE" or any(v["rule"] == r["rule"] and v["status"] == "fail"
                                           for v in acc["verdicts"]):
                first = next((v["message"] for v in acc["verdicts"] if v["rule"] == r["rule"] and
                              v["status"] == "fail"), r["first"])
                detail.append((f"first failure: {first}", RED))
        detail.append(("each check and the cycle it came from: see the verdicts page", "0.35"))
    for text, colour in detail:
        for line in wrap_pt(text, VALUE_WIDTH_PT, BODY):
            flow.text(VALUE_X, line, pitch=PITCH, fontsize=BODY, color=colour)
    flow.skip(3)

    verdict = report.get("tracking_verdict") or {}
    if verdict:  # the one tracking figure, as every command prints it (sim.tracking_figure, docs/metrics.md)
        _kv(flow, "Tracking error", tracking_text(verdict), color=RED if verdict.get("verdict") == "did_not_follow"
            else "black")
    trk = report["tracking"]
    if trk:
        # three significant digits: at the display resolution (0.01 mm) a tracking error of 0.012 mm read 0.01
        _kv(flow, "Raw |y - r|", f"RMS {u.text('length', trk['rms_y_minus_r_m'], sig=3)}, peak "
                                 f"{u.text('length', trk['peak_abs_y_minus_r_m'], sig=3)}, peak |u| = "
                                 f"{u.text('voltage', trk.get('peak_abs_voltage_v'))} (whole test, same-instant "
                                 "target: incl. latency and taper; not the tracking error)")
    else:
        _kv(flow, "Raw |y - r|", "no target recorded")
    trips = report["limit_trips"]
    if trips:
        _kv(flow, "Limit trips", f"{len(trips)}: " + trips[0]["text"], color=RED)
    else:
        _kv(flow, "Limit trips", "none")
    indicated = report.get("limit_indications") or {}
    if indicated:
        _kv(flow, "Limits indicated", ", ".join(f"{key}: {count} time{'s' if count != 1 else ''}"
                                                 for key, count in indicated.items()) + " (the test went on)")
