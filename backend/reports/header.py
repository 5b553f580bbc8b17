"""The header page(s): lab, rig, operator, test conditions, controller, the acceptance verdict, tracking, limit
trips, and the Bouc-Wen parameters identified beside the nominal ones (a block that can be added last, when a
fit made elsewhere arrives).
"""

from __future__ import annotations

import json
from datetime import UTC, datetime

from .data import limit_trips, num
from .identification import BOUC_WEN_FIELDS
from .layout import A4_PORTRAIT_IN, fmt_num, footer, report_title, wrap_text

MAX_HEADER_LEVELS = 6  # the header page lists at most this many protocol levels ...
MAX_HEADER_RULES = 4  # ... and rules (all of them are on the verdicts page)


def page_header(plt, bundle, ctrl, iso, protocol, acc, ident, trk, page):
    """The header page(s), with the Bouc-Wen table."""
    figs, y = header_pages(plt, bundle, ctrl, iso, protocol, acc, trk, page)
    identification_block(figs[-1], y, ident, bundle.record, page + len(figs) - 1)
    return figs


def header_pages(plt, bundle, ctrl, iso, protocol, acc, trk, page):
    """The header page(s) up to the Bouc-Wen table, and where that table starts (it needs the fit)."""
    fig = plt.figure(figsize=A4_PORTRAIT_IN)
    fig.text(0.07, 0.955, report_title(bundle.record), fontsize=14, weight="bold")
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
        for chunk in wrap_text(line, 105):
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
        peak_u = fmt_num(trk.get("peak_abs_voltage_v"), "{:.2f}")
        fig.text(0.30, y, f"RMS |y - r| = {trk['rms_y_minus_r_m'] * 1e3:.3f} mm, peak |y - r| = "
                          f"{trk['peak_abs_y_minus_r_m'] * 1e3:.3f} mm, peak |u| = {peak_u} V", fontsize=9)
    else:
        fig.text(0.30, y, "no target recorded", fontsize=9)
    y -= 0.022
    trips = limit_trips(bundle.events)
    fig.text(0.07, y, "Limit trips", fontsize=11, weight="bold")
    fig.text(0.30, y, f"{len(trips)}" + (f": {trips[0].get('message', '')}"[:100] if trips else " (none)"),
             fontsize=9, color="#c62828" if trips else "black")
    y -= 0.035
    # identification table (on a second header page when the first is full)
    figs = [fig]
    if y < 0.20:
        footer(fig, bundle.record, page)
        fig = plt.figure(figsize=A4_PORTRAIT_IN)
        figs.append(fig)
        fig.text(0.07, 0.955, report_title(bundle.record) + " (continued)", fontsize=12, weight="bold")
        y = 0.91
    return figs, y


def identification_block(fig, y, ident, record, page):
    """The Bouc-Wen table (nominal, identified, difference) and the footer of the last header page."""
    fig.text(0.07, y, "Bouc-Wen parameters: nominal and identified from this test", fontsize=11, weight="bold")
    y -= 0.024
    nominal = ident.get("nominal") or {}
    rows = [("parameter", "unit", "nominal", "identified", "difference")]
    units = {"rho_bw_per_m": "1/m", "sigma_bw": "-", "n": "-", "kd_n_per_m": "N/m", "kw_n": "N"}
    for k in BOUC_WEN_FIELDS:
        nv = num(nominal.get(k))
        iv = num((ident.get("identified") or {}).get(k))
        diff = f"{100 * (iv / nv - 1):+.1f} %" if nv and iv is not None else "-"
        rows.append((k, units[k], fmt_num(nv), fmt_num(iv), diff))
    for row in rows:
        for x, cell in zip((0.09, 0.27, 0.36, 0.52, 0.68), row, strict=True):
            fig.text(x, y, cell, fontsize=8.5, family="monospace", weight="bold" if row is rows[0] else "normal")
        y -= 0.018
    if not ident.get("available"):
        fig.text(0.09, y, ident.get("note", ""), fontsize=8, color="0.4")
    else:
        nrms = num((ident.get("fit") or {}).get("nrms_error"))
        fig.text(0.09, y, f"{ident.get('source', '')}" + (f"; force NRMS error {100 * nrms:.2g} %" if nrms is not None
                                                            else ""), fontsize=8, color="0.4")
    footer(fig, record, page)


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
    sb = num(r.get("supply_bar"))
    lines.append(("Supply pressure", f"{sb:g} bar" if sb is not None else "not recorded"))
    load = num(r.get("vertical_load_n", (r.get("scenario") or {}).get("vertical_load_n")))
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
    dur = num(r.get("duration_s"))
    lines.append(("Duration, samples", f"{dur:g} s, {bundle.samples.shape[0]} samples" if dur is not None
                  else f"{bundle.samples.shape[0]} samples"))
    if r.get("source"):
        lines.append(("Source", str(r["source"])[-100:]))
    return lines


def _operator(bundle) -> str | None:
    if bundle.record.get("operator"):
        return bundle.record["operator"]
    for e in bundle.events:
        if e.get("kind") == "operator" and (e.get("values") or {}).get("action") == "start" and e.get("actor"):
            return e["actor"]
    return None


def _profile_text(record: dict, protocol) -> list[str]:
    if protocol is not None:
        lines = wrap_text(f"protocol {protocol.name}: {protocol.title}", 88)
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


def _wrapped_lines(key: str, text: str, width: int = 85, max_lines: int = 3) -> list[tuple[str, str]]:
    """Header lines for a long value: wrapped to the page's width, at most ``max_lines`` (then "...")."""
    chunks = wrap_text(text, width)
    if len(chunks) > max_lines:
        chunks = chunks[:max_lines]
        chunks[-1] += " ..."
    return [(key if k == 0 else "", chunk) for k, chunk in enumerate(chunks)]
