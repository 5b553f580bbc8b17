"""The text pages in fixed-pitch monospace lines: the per-cycle metrics table, and the acceptance verdicts with
the event log and limit trips.
"""

from __future__ import annotations

import json

from .data import clean_json, limit_trips, num
from .layout import A4_PORTRAIT_IN, draw_lines, fmt_num, footer, wrap_text

TABLE_ROWS = 61  # per-cycle table rows per page
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
            str(c["cycle"]), fmt_num(c.get("t_start_s"), "{:.2f}"),
            fmt_num(c.get("d_max_m"), "{:.3f}", 1e3), fmt_num(c.get("d_min_m"), "{:.3f}", 1e3),
            fmt_num(c.get("f_max_n"), "{:.3f}", 1e-3), fmt_num(c.get("f_min_n"), "{:.3f}", 1e-3),
            fmt_num(c.get("k_eff_n_per_m"), "{:.4f}", 1e-6), fmt_num(c.get("edc_j"), "{:.2f}"),
            fmt_num(c.get("xi_eff"), "{:.2f}", 100), fmt_num(c.get("qd_n"), "{:.3f}", 1e-3),
            fmt_num(c.get("kd_n_per_m"), "{:.4f}", 1e-6),
            (role + " " + check).strip(),
        ))
    return rows


def _table_line(cells, widths) -> str:
    return " ".join(str(x).rjust(w) if i < len(widths) - 1 else " " + str(x)
                    for i, (x, w) in enumerate(zip(cells, widths, strict=True)))


def pages_table(plt, bundle, acc, first_page, protocol=None):
    rows = _table_rows(bundle, acc, protocol)
    widths = (5, 9, 8, 8, 8, 8, 8, 9, 7, 8, 8, 1)
    figs = []
    chunks = [rows[i:i + TABLE_ROWS] for i in range(0, len(rows), TABLE_ROWS)] or [[]]
    for k, chunk in enumerate(chunks):
        fig = plt.figure(figsize=A4_PORTRAIT_IN)
        fig.text(0.06, 0.955, "Per-cycle metrics" + (f" ({k + 1}/{len(chunks)})" if len(chunks) > 1 else ""),
                 fontsize=12, weight="bold")
        draw_lines(fig, [(line, "0.3") for line in TABLE_NOTE.splitlines()], 0.06, 0.935, 7.5, 9.5)
        lines = [_table_line(TABLE_HEAD, widths), _table_line(TABLE_UNITS, widths),
                 "-" * (sum(widths) + len(widths))]
        lines += [(_table_line(r, widths), "#c62828" if r[-1].endswith("FAIL") else "black") for r in chunk]
        draw_lines(fig, lines if chunk else ["no complete cycle recorded"], 0.05, 0.885, 8.5, 11.0)
        footer(fig, bundle.record, first_page + k)
        figs.append(fig)
    return figs


def pages_verdicts_events(plt, bundle, acc, first_page):
    red = "#c62828"
    lines: list = []
    summary = acc["summary"]
    if acc["protocol"] is None:
        lines.append(acc.get("note") or "no acceptance rules")
    else:
        lines.extend(wrap_text(f"Protocol {acc['protocol']}: {acc.get('title', '')}", 105))
        for n, t in zip(acc["rule_names"], acc["rules"], strict=True):
            ok = sum(1 for v in acc["verdicts"] if v["rule"] == n and v["passed"])
            total = sum(1 for v in acc["verdicts"] if v["rule"] == n)
            lines.append((f"  {n}: {t} - {ok}/{total} passed"[:110], "black" if ok == total else red))
        lines.append("")
        failed = [v for v in acc["verdicts"] if not v["passed"]]
        lines.append((f"Failed checks ({len(failed)}):", red) if failed else "All checks passed.")
        for v in failed:
            lines.extend(("  " + w, red) for w in wrap_text(v["message"], 103))
    lines.append("")
    lines.append(f"Events ({len(bundle.events)}; limit trips: {len(limit_trips(bundle.events))})")
    for e in bundle.events:
        t = num(e.get("time_s"))
        head = f"  {'t = ' + format(t, '8.3f') + ' s' if t is not None else ' ' * 14}  {e.get('kind', ''):<10} "
        msg = str(e.get("message", ""))
        if e.get("kind") == "limit_trip" and e.get("values"):
            msg += "  " + json.dumps(clean_json(e["values"]))[:150]
        color = red if e.get("kind") == "limit_trip" else "black"
        wrapped = wrap_text(msg, 105 - len(head))
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
        draw_lines(fig, chunk, 0.05, 0.925, 8.0, 10.5)
        footer(fig, bundle.record, first_page + k)
        figs.append(fig)
    return figs
