"""The text pages in fixed-pitch monospace lines: the per-cycle metrics table (taper cycles marked and greyed, the
steady cycles' means at its end), the protocol with its rules and every check with the cycle it came from, the
events in words, and the approval block (tested, reviewed, approved by) that ends the report.
"""

from __future__ import annotations

from ..units import LAB
from .data import PHASE_WORDS, num
from .header import VERDICT_COLOURS
from .layout import A4_PORTRAIT_IN, PAGE_BOTTOM, Flow, draw_lines, fmt_num, rule, wrap_text

TABLE_ROWS = 59  # per-cycle table rows per page
TABLE_HEAD = ("cycle", "t_start", "d+", "d-", "F+", "F-", "K_eff", "EDC", "xi_eff", "Q_d", "K_d", "phase/check")
# the quantity (backend.units) of each metric column: its unit and digits in the lab's units
TABLE_COLUMNS = (("d_max_m", "length"), ("d_min_m", "length"), ("f_max_n", "force"), ("f_min_n", "force"),
                 ("k_eff_n_per_m", "stiffness"), ("edc_j", "energy"), ("xi_eff", "percent"), ("qd_n", "force"),
                 ("kd_n_per_m", "stiffness"))
MEAN_COLUMNS = TABLE_COLUMNS[4:]  # the headline figures, the table's last row


def table_units(u=LAB) -> tuple:
    """The table's second heading line: the unit of each column."""
    return ("", "s", *(u.unit(q) for _k, q in TABLE_COLUMNS), "")


TABLE_UNITS = table_units(LAB)
TABLE_NOTE = ("F+ and F- are the forces at d+ and d-.  K_eff = (F+ - F-) / (d+ - d-).  EDC = loop area.\n"
              "xi_eff = 2 EDC / (pi K_eff (d+ - d-)^2).  Q_d = force intercept at the loop centre (mean of both "
              "branches).\nK_d = slope on both loading legs beyond half the amplitude.  Details: docs/metrics.md.\n"
              "Grey rows: taper cycles (lower amplitude; ramp out: the taper of an operator's stop), left out of the\n"
              "headline figures and of the verdicts.  Last rows: the mean of the steady cycles (the headline figures;\n"
              "for a protocol one per level: mean L1 ...).")
TAPER_GREY = "0.5"
RED = "#c62828"
WIDTHS = (5, 8, 8, 8, 8, 8, 8, 8, 7, 8, 8, 1)

# a protocol's quantities (the metrics its rules judge) -> their quantity in backend.units
QUANTITY_UNITS = {**dict(TABLE_COLUMNS), "f_peak_max_n": "force", "f_peak_min_n": "force"}
EVENT_KINDS = {"limit_trip": "limit trip", "limit_indicate": "limit indicated", "rig_fault": "rig fault",
               "operator": "operator", "status": "status"}


def _table_rows(bundle, acc, protocol=None, u=LAB) -> list[tuple]:
    failed, judged = {}, set()
    for v in acc["verdicts"]:
        judged.add(v["cycle"])
        if not v["passed"] and v["status"] != "missing":
            failed.setdefault(v["cycle"], []).append(v["rule"])
    for lv in (acc.get("design") or {}).get("levels") or []:  # the check against the design values
        for c in lv["checks"]:
            judged.add(c["cycle"])
            if c["status"] == "fail":
                failed.setdefault(c["cycle"], []).append("design " + c["name"])
    plan = {p["cycle"]: p for p in protocol.cycle_plan()} if protocol is not None else {}
    rows = []
    for c in bundle.cycles:
        phase = c.get("phase", "steady")
        if phase != "steady":
            mark = PHASE_WORDS.get(phase, phase)
        else:
            p = plan.get(c["cycle"])
            role = "" if p is None else (f"L{p['level']}.{p['level_cycle']}" if p["test"] else f"L{p['level']} taper")
            check = "FAIL" if c["cycle"] in failed else ("pass" if c["cycle"] in judged else "")
            mark = (role + " " + check).strip()
        rows.append((str(c["cycle"]), fmt_num(c.get("t_start_s"), "{:.2f}"),
                     *(u.fmt(q, num(c.get(k)), trailing_zeros=True) for k, q in TABLE_COLUMNS), mark))
    return rows


def _table_line(cells, widths=WIDTHS) -> str:
    return " ".join(str(x).rjust(w) if i < len(widths) - 1 else " " + str(x)
                    for i, (x, w) in enumerate(zip(cells, widths, strict=True)))


def _row_colour(bundle_cycle: dict, row: tuple) -> str:
    if row[-1].endswith("FAIL"):
        return RED
    return TAPER_GREY if bundle_cycle.get("phase", "steady") != "steady" else "black"


def pages_table(plt, bundle, acc, protocol=None, head: dict | None = None, u=LAB):
    """The per-cycle table in the lab's units ``u`` (backend.units.Units), the steady cycles' means last."""
    rows = _table_rows(bundle, acc, protocol, u)
    colours = [_row_colour(c, r) for c, r in zip(bundle.cycles, rows, strict=True)]
    lines = [(_table_line(r), col) for r, col in zip(rows, colours, strict=True)]
    if head and rows:
        lines.append("-" * (sum(WIDTHS) + len(WIDTHS)))
        # a protocol: one mean per level (levels differ in amplitude); else the mean of the steady cycles
        groups = [(f"mean L{lv['level']}", lv.get("means") or {}, lv.get("steady_cycles", 0))
                  for lv in head.get("levels") or []] or [("mean", head.get("means") or {},
                                                           head.get("steady_cycles", 0))]
        for label, means, n in groups:
            lines.append(_table_line((label, "", "", "", "", "",
                                      *(u.fmt(q, num(means.get(k)), trailing_zeros=True) for k, q in MEAN_COLUMNS),
                                      f"{n} steady")))
    figs = []
    chunks = [lines[i:i + TABLE_ROWS] for i in range(0, len(lines), TABLE_ROWS)] or [[]]
    tail = 1 + len(head.get("levels") or [None]) if head and rows else 0  # the rule and the means
    if len(chunks) > 1 and len(chunks[-1]) <= tail:  # the means never alone on a page
        k = tail + 1 - len(chunks[-1])
        chunks[-2:] = [chunks[-2][:-k], chunks[-2][-k:] + chunks[-1]]
    for k, chunk in enumerate(chunks):
        fig = plt.figure(figsize=A4_PORTRAIT_IN)
        fig.text(0.06, 0.955, "Per-cycle metrics" + (f" ({k + 1}/{len(chunks)})" if len(chunks) > 1 else ""),
                 fontsize=12, weight="bold")
        draw_lines(fig, [(line, "0.3") for line in TABLE_NOTE.splitlines()], 0.06, 0.935, 7.5, 9.5)
        head_lines = [_table_line(TABLE_HEAD), _table_line(table_units(u)), "-" * (sum(WIDTHS) + len(WIDTHS))]
        draw_lines(fig, head_lines + chunk if chunk else ["no complete cycle recorded"], 0.05, 0.868, 8.5, 11.0)
        figs.append(fig)
    return figs


# --- protocol, verdicts, events, approval -----------------------------------------------------------------

def _value(quantity: str, value, u=LAB) -> str:
    v = num(value)
    if quantity not in QUANTITY_UNITS:
        return "-" if v is None else f"{v:.4g}"
    return u.fmt(QUANTITY_UNITS[quantity], v, trailing_zeros=True)


def _unit(quantity: str, u=LAB) -> str:
    return u.unit(QUANTITY_UNITS[quantity]) if quantity in QUANTITY_UNITS else ""


def verdict_lines(acc: dict, protocol, u=LAB) -> list:
    """The protocol, its rules (with pass counts) and one line per check: rule, level and test cycle, the cycle
    it came from, value, reference and the cycle the reference came from, deviation, tolerance, result."""
    lines: list = []
    if acc["protocol"] is None:
        lines.extend(wrap_text(acc.get("note") or "no acceptance rules", 100))
        return lines
    lines.extend(wrap_text(f"Protocol {acc['protocol']}: {acc.get('title', '')}", 100))
    if protocol is not None:
        plan = protocol.cycle_plan()
        for i, lv in enumerate(protocol.levels, start=1):
            judged = [p["cycle"] for p in plan if p["level"] == i and p["test"]]
            tapers = [p["cycle"] for p in plan if p["level"] == i and not p["test"]]
            text = (f"  level {i}{' (' + lv.label + ')' if lv.label else ''}: {u.text('length', lv.amplitude_m)} at "
                    f"{lv.frequency_hz:g} Hz, test cycles {_span(judged)}"
                    + (f", taper cycles {', '.join(map(str, tapers))}" if tapers else ""))
            lines.extend(wrap_text(text, 100))
    lines.append("")
    lines.append("Rules (judged on the steady cycles only; a cycle not measured is a failed check):")
    for r in acc.get("rule_details", []):
        ok = r["passed"] == r["checks"]
        lines.append((f"  {r['name']}: {r['text']} - {r['passed']} of {r['checks']} passed", "black" if ok else RED))
        if r.get("description"):
            lines.extend(("      " + w, "0.35") for w in wrap_text(r["description"], 94))
    lines.append("")
    lines += design_lines(acc.get("design") or {}, u)
    head = (f"  {'rule':<20}{'L.n':>6}{'cycle':>6}{'value':>11}  {'reference':>10}{'(cycle)':>8}"
            f"{'deviation':>10}{'tol.':>8}  {'unit':<7}{'result':<8}")
    lines.extend(wrap_text(f"Checks ({len(acc['verdicts'])}; {acc['summary']['failed']} failed). L.n: level L, its "
                           "test cycle n; cycle: the cycle of the test it judged; (cycle): the cycle the reference "
                           "value came from.", 100))
    lines.append(head)
    lines.append("  " + "-" * (len(head) - 2))
    for v in acc["verdicts"]:
        unit = _unit(v["quantity"], u)
        dev = num(v.get("deviation_fraction"))
        ref_cycle = v.get("reference_cycle")
        result = {"pass": "pass", "fail": "FAIL", "not_evaluated": "not evaluated"}.get(v["status"], v["status"])
        if v["status"] == "missing":
            message = str(v.get("message"))
            result = "no cycle" if "no measured cycle" in message else ("no ref." if "no reference" in message
                                                                        else "no value")
        check = f"L{v['level']}.{v['level_cycle']}"
        dev_text = f"{100 * dev:+.1f} %" if dev is not None else "-"
        tol_text = f"+-{100 * v['tolerance_fraction']:g} %"
        ref_text = f"({ref_cycle})" if ref_cycle else ""
        lines.append((f"  {v['rule'][:19]:<20}{check:>6}{v['cycle']:>6}{_value(v['quantity'], v.get('value'), u):>11}  "
                      f"{_value(v['quantity'], v.get('reference_value'), u):>10}{ref_text:>8}{dev_text:>10}"
                      f"{tol_text:>8}  {unit:<7}{result:<8}", "black" if v["passed"] else RED))
    return lines


def design_lines(design: dict, u=LAB) -> list:
    """The check against the specimen's design values: the tolerances and their source, then per level its
    verdict, the design value, the mean and each test cycle of K_eff, EDC and xi_eff with its deviation."""
    if not design:
        return []
    if not design.get("levels"):
        return [(design.get("note") or "no design values", "0.35"), ""]
    t = design["tolerances"]
    lines: list = wrap_text(f"Against the specimen's design values ({design['basis']}). Tolerances: each test cycle "
                            f"+-{100 * t['k_eff']:g} % K_eff, +-{100 * t['edc']:g} % EDC, +-{100 * t['xi_eff']:g} % "
                            f"xi_eff; each level's mean +-{100 * t['mean']:g} %; {design.get('source')}.", 100)
    for lv in design["levels"]:
        colour = VERDICT_COLOURS.get(lv["verdict"], "black")
        lines.append((f"  level {lv['level']}{' (' + lv['label'] + ')' if lv.get('label') else ''}, "
                      f"{u.text('length', lv['amplitude_m'])} at {lv['frequency_hz']:g} Hz: {lv['verdict']} "
                      f"({lv['measured_cycles']} of {lv['test_cycles']} test cycles measured)", colour))
        for mc in lv["mean_checks"]:
            q = mc["quantity"]
            per = [c for c in lv["checks"] if c["quantity"] == q]
            cycles = "  ".join(f"L{lv['level']}.{c['level_cycle']} " + (f"{100 * c['deviation_fraction']:+.1f} %"
                               if c["deviation_fraction"] is not None else "no cycle")
                               + ("" if c["status"] == "pass" else " FAIL" if c["status"] == "fail" else "")
                               for c in per)
            dev = mc["deviation_fraction"]
            ok = mc["status"] == "pass" and all(c["status"] == "pass" for c in per)
            text = (f"    {mc['name']:<7} design {_value(q, mc['design'], u):>9} {_unit(q, u):<6} mean "
                    f"{_value(q, mc['value'], u):>9} " + (f"{100 * dev:+6.1f} %" if dev is not None else "      -")
                    + f"{' FAIL' if mc['status'] == 'fail' else ''}; {cycles}")
            indent = " " * 12
            wrapped = wrap_text(text, 100)
            lines.append((wrapped[0], "black" if ok else RED))
            lines.extend((indent + w, "black" if ok else RED) for w in wrap_text(" ".join(wrapped[1:]), 88)
                         if len(wrapped) > 1)
    lines.append("")
    return lines


def _span(numbers: list[int]) -> str:
    if not numbers:
        return "-"
    if numbers == list(range(numbers[0], numbers[-1] + 1)) and len(numbers) > 2:
        return f"{numbers[0]}-{numbers[-1]}"
    return ", ".join(map(str, numbers))


def event_lines(events: list[dict]) -> list:
    """Every event in words: test time (or the wall-clock time of the service), what, the message."""
    trips = sum(1 for e in events if e.get("kind") == "limit_trip")
    lines: list = [f"Events ({len(events)}; limit trips: {trips})"]
    for e in events:
        t = num(e.get("time_s"))
        when = f"t = {t:8.3f} s" if t is not None else (str(e.get("created_at") or "")[11:19] + " UTC").rjust(14)
        kind = EVENT_KINDS.get(e.get("kind"), str(e.get("kind", "")))
        head = f"  {when}  {kind:<10} "
        color = RED if e.get("kind") in ("limit_trip", "rig_fault") else "black"
        wrapped = wrap_text(e.get("text") or str(e.get("message", "")), 103 - len(head))
        lines.append((head + wrapped[0], color))
        lines.extend((" " * len(head) + w, color) for w in wrapped[1:])
    if not events:
        lines.append("  none recorded")
    return lines


LINE_PITCH = 10.5
APPROVAL_PT = 18 + 3 * 11 + 14 + 3 * 36 + 16 + 2 * 11 + 10  # heading, statement, captions, three rows, hash


def pages_verdicts_events(plt, bundle, report, protocol=None, u=LAB):
    """The protocol, rules and checks (in the lab's units ``u``), the events, and the approval block at the end:
    one Flow of pages."""
    acc = report["acceptance"]
    flow = Flow(plt, "Acceptance verdicts, events and approval", top=0.93)
    fig = flow.new_page(continued=False)
    fig.text(0.06, 0.955, "Acceptance verdicts, events and approval", fontsize=12, weight="bold")
    fig.text(0.94, 0.955, acc["verdict"], fontsize=12, weight="bold", color=VERDICT_COLOURS[acc["verdict"]],
             ha="right")
    lines = verdict_lines(acc, protocol, u)
    lines.append("")
    lines += event_lines(report["events"])
    for item in lines:
        text, color = item if isinstance(item, tuple) else (item, "black")
        if text:
            flow.text(0.05, text, pitch=LINE_PITCH, fontsize=8.0, family="monospace", color=color)
        else:
            flow.skip(LINE_PITCH)
    approval_block(flow, bundle.record, report)
    return flow.figs


def approval_block(flow: Flow, record: dict, report: dict) -> None:
    """Tested by, reviewed by, approved by: name, date and signature lines (the operator's name filled in)."""
    names = report.get("approval") or {}
    note = (wrap_text(f"Note of the approver ({names['approved_by']}): {names['note']}", 120)
            if names.get("approved_by") and names.get("note") else [])
    flow.skip(14)
    flow.room(APPROVAL_PT + 11 * len(note) + 4)  # the block with its note on one page
    fig = flow.fig
    flow.text(0.06, "Approval", pitch=18, fontsize=11, weight="bold")
    tid = record.get("id")
    statement = (f"This report covers test record {tid} only" if tid is not None else "This report covers this "
                 "record only") + ("; its results relate only to the specimen tested. Every number in it is in "
                                   "report.json" + (f" (GET /api/tests/{tid}/report.json; the whole record: "
                                                    f"/api/tests/{tid}/bundle.zip)." if tid is not None else "."))
    for line in wrap_text(statement, 125):
        flow.text(0.06, line, pitch=11, fontsize=8, color="0.3")
    flow.text(0.20, "name", pitch=14, fontsize=7.5, color="0.45")
    fig.text(0.52, flow.y, "date", fontsize=7.5, color="0.45")
    fig.text(0.68, flow.y, "signature", fontsize=7.5, color="0.45")
    for role, key in (("Tested by", "tested"), ("Reviewed by", "reviewed"), ("Approved by", "approved")):
        flow.skip(36)
        y = flow.y
        fig.text(0.06, y + flow.frac(2), role, fontsize=9, weight="bold")
        if names.get(f"{key}_by"):
            fig.text(0.20, y + flow.frac(3), str(names[f"{key}_by"]), fontsize=9)
        if names.get(f"{key}_at"):
            fig.text(0.52, y + flow.frac(3), str(names[f"{key}_at"])[:16].replace("T", " ") + " UTC", fontsize=8)
        for x0, x1 in ((0.20, 0.49), (0.52, 0.65), (0.68, 0.94)):
            rule(fig, y, x0, x1, color="0.2", lw=0.6)
    flow.skip(16)
    for line in note:
        flow.text(0.06, line, pitch=11, fontsize=8)
    if note:
        flow.skip(4)
    if names.get("record_sha256"):
        flow.text(0.06, f"Approved record, SHA-256 {names['record_sha256']}", pitch=11, fontsize=7.5,
                  family="monospace")
        check = f"GET /api/tests/{tid}/approval" if tid is not None else "the service"
        flow.text(0.06, f"Check it against the record as it is now: {check} (intact: true when they agree).",
                  pitch=11, fontsize=7.5, color="0.3")
    else:
        state = names.get("state") or "unreviewed"
        flow.text(0.06, f"Review state: {state}. An approval in the service locks the record and prints its "
                  "SHA-256 here.", pitch=11, fontsize=7.5, color="0.3")
    flow.y = max(flow.y, PAGE_BOTTOM)
