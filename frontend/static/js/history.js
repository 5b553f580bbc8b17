// History: the list of past tests of every rig sharing the records (filter by rig, isolator, status, date; the
// archived ones on their own), one test's page (who and what, loops, per-cycle metrics, events, downloads), and
// the record actions: delete a test of this rig that never ran, archive a test that ran (who and why), restore
// an archived one. Each asks first and says what happened.

import { NewestOnly, account, api, askLogin, refreshAccount } from "./api.js";
import { confirmDialog, summaryTable } from "./dialogs.js";
import { indicationsText, limitsText } from "./limits.js";
import { isProtocol, ProtocolAcceptance, VERDICT_CLASS } from "./acceptance.js";
import { EarthquakeRecord } from "./eqrecord.js";
import { ReviewPanel, reviewOf, reviewPill } from "./review.js";
import { verdictBlock, verdictPill as trackingPill } from "./verdict.js";
import { LoopPlot } from "./plots.js";
import { el, eventLine, fmtTime, PHASE_WORDS, profileText } from "./ui.js";
import { factorIn, fmt, fmtU, onUnits, system, unit } from "./units.js";

const $ = (id) => document.getElementById(id);
const num = (v) => typeof v === "number" && Number.isFinite(v);

function listOf(data, key) {
  if (Array.isArray(data)) return data;
  if (data && Array.isArray(data[key])) return data[key];
  if (data && Array.isArray(data.items)) return data.items;
  return [];
}


/** A protocol test's verdict as a pill after its status (the summary's acceptance), or nothing. */
function verdictPill(t) {
  const a = t.summary && t.summary.acceptance;
  if (!a || !a.verdict) return [];
  return [" ", el("span", { class: `pill verdict ${VERDICT_CLASS[a.verdict] || ""}`, text: a.verdict,
    title: `${a.failed} of ${a.verdicts} acceptance checks failed` })];
}

export function isolatorName(t) {
  const iso = t.isolator !== undefined ? t.isolator : t.scenario && t.scenario.isolator;
  if (!iso) return "-";
  return typeof iso === "string" ? iso : iso.name || "-";
}

function controllerName(t) {
  const c = t.controller !== undefined ? t.controller : t.scenario && t.scenario.controller;
  return typeof c === "string" ? c : c && (c.name || c.kind) ? c.name || c.kind : "-";
}

/** " (5 steady cycles)": what the means are taken over (the summary's steady cycles), "" when not said. */
function steadyOf(t) {
  const n = t && t.summary && t.summary.steady_cycles;
  return typeof n === "number" && n > 0 ? ` (${n} steady cycle${n === 1 ? "" : "s"})` : "";
}

/** Flat summary figures of a test record: loop-metric means over the full-amplitude cycles, tracking. */
function summaryOf(t) {
  const s = t.summary || {};
  const tr = s.tracking || {};
  const last = tr.last_two_cycles || {};
  return {
    ...(s.loop_metrics_mean || {}),
    rms_y_minus_r_m: tr.rms_y_minus_r_m,
    last_rms_y_minus_r_m: last.rms_y_minus_r_m,
    amplitude_error: last.amplitude_error,
    phase_error_deg: last.phase_error_deg,
    saturated_share: tr.saturated_share,
    peak_flow_l_per_min: tr.peak_flow_l_per_min,
  };
}

/** A commissioning's state after its status (trusted, not trusted, fitting ...), or nothing. */
function commissioningPill(t) {
  const c = t.profile && t.profile.kind === "commissioning" ? (t.summary && t.summary.commissioning) || {} : null;
  if (!c) return [];
  const s = c.state || (t.status === "running" ? "running" : "fitting");
  return [" ", el("span", { class: `pill cstate cstate-${s}`, text: s.replace("_", " "), title: c.words || "" })];
}

function statusPill(status) {
  return el("span", { class: `pill status-${status}`, text: status });
}

/** What an operator may do with a record: delete (never ran, this rig's), archive (ran), restore (archived), nothing
 * (running, another rig's that never ran, or approved: an approved record is locked). */
export function recordAction(t, thisRig = null) {
  if (reviewOf(t).state === "approved") return "";
  if (t.archived) return "restore";
  if (t.status === "ready") return thisRig && t.rig_name && t.rig_name !== thisRig ? "" : "delete"; // its rig's
  if (t.status === "running") return "";
  return "archive";
}

export class History {
  constructor() {
    this.loopPlot = null;
    this.eqRecord = new EarthquakeRecord(); // an earthquake test's J criteria and reference (js/eqrecord.js)
    this.acceptance = new ProtocolAcceptance(); // a protocol test's verdict and levels (js/acceptance.js)
    this.current = null; // the test page's record, once loaded
    this.shownId = null; // the test the page shows (its hash), set at once: a late answer for another is dropped
    this.lists = new NewestOnly(); // History's list and a test's page: only the newest answer is drawn
    this.pages = new NewestOnly();
    this.thisRig = null; // the rig this service drives (GET /api/rigs): another rig's tests are its service's
    this.review = new ReviewPanel(() => this.showTest(this.shownId, true)); // approve / reject (js/review.js)
    $("history-filter").addEventListener("submit", (ev) => {
      ev.preventDefault();
      this.showList();
    });
    $("h-archived").addEventListener("change", () => this.showList());
    onUnits(() => this.refresh());
  }

  refresh() {
    if (!$("view-history").classList.contains("hidden")) this.showList();
    if (!$("view-test").classList.contains("hidden") && this.shownId !== null) this.showTest(this.shownId, true);
  }

  message(id, text, kind = "") {
    $(id).textContent = text;
    $(id).className = `message ${kind}`;
  }

  /** The rig filter's choices: every rig on record, this service's marked; the choice kept. */
  async loadRigs() {
    let rigs;
    try {
      rigs = await api.get("/api/rigs");
    } catch (e) {
      return; // the list still loads, unfiltered by rig
    }
    this.thisRig = rigs.this;
    const sel = $("h-rig");
    const keep = sel.value;
    sel.innerHTML = "";
    sel.append(el("option", { value: "", text: "any" }));
    for (const name of rigs.on_record || []) {
      sel.append(el("option", { value: name, text: name === rigs.this ? `${name} (this console's)` : name }));
    }
    sel.value = (rigs.on_record || []).includes(keep) ? keep : "";
  }

  /** Show the tests the filter asks for. A list asked for later wins: an earlier answer that arrives after it is
   * dropped, so the table never shows an unfiltered list under a filter. The table's data-query names the
   * query its rows answer. */
  async showList() {
    const superseded = this.lists.ask();
    await this.loadRigs();
    if (superseded()) return;
    const q = new URLSearchParams();
    if ($("h-rig").value) q.set("rig_name", $("h-rig").value);
    if ($("h-isolator").value) q.set("isolator", $("h-isolator").value);
    if ($("h-status").value) q.set("status", $("h-status").value);
    if ($("h-review").value) q.set("review", $("h-review").value);
    // the dates are the operator's local days; the service keeps UTC
    if ($("h-since").value) q.set("since", new Date(`${$("h-since").value}T00:00:00`).toISOString());
    if ($("h-until").value) q.set("until", new Date(`${$("h-until").value}T23:59:59.999`).toISOString());
    const archived = $("h-archived").checked;
    if (archived) q.set("archived", "true");
    const table = $("history-table");
    const tbody = table.querySelector("tbody");
    let tests = [];
    try {
      tests = listOf(await api.get(`/api/tests?${q}`), "tests");
    } catch (e) {
      if (superseded()) return;
      tbody.innerHTML = "";
      tbody.append(el("tr", {}, el("td", { text: `could not load: ${e.message}`, colspan: "13" })));
      table.dataset.query = q.toString();
      table.dataset.archived = archived ? "1" : "0";
      return;
    }
    if (superseded()) return;
    tbody.innerHTML = "";
    table.dataset.query = q.toString();
    table.dataset.archived = archived ? "1" : "0";
    for (const t of tests) {
      const s = summaryOf(t);
      const action = recordAction(t, this.thisRig);
      const actions = el("td", { class: "actions" });
      if (action) {
        const b = el("button", { type: "button", class: `ghost small act-${action}`, "data-action": action,
          text: { delete: "delete", archive: "archive", restore: "restore" }[action] });
        b.title = { delete: "this test never ran: delete it", archive: "hide it from the list, kept and restorable",
          restore: "bring it back into the list" }[action];
        b.addEventListener("click", (ev) => {
          ev.stopPropagation();
          this.act(t, action, "history-message");
        });
        actions.append(b);
      }
      const tr = el("tr", { class: "link", "data-id": String(t.id), "data-status": t.status },
        el("td", {}, el("a", { class: "test-link", href: `#/tests/${t.id}`, title: `open test #${t.id}`, text: `#${t.id}` })),
        el("td", { class: `rig${t.rig_name === this.thisRig ? " this-rig" : ""}`, text: t.rig_name || "-" }),
        el("td", { text: fmtTime(t.created_at || t.started_at) }),
        el("td", { class: "who", text: t.specimen_id || "-" }),
        el("td", { class: "who", text: t.operator_name || "-" }),
        el("td", { text: isolatorName(t) }),
        el("td", { text: profileText(t) }),
        el("td", { text: controllerName(t) }),
        el("td", { text: num(t.vertical_load_n) ? fmtU("force", t.vertical_load_n, { sig: 4 }) : "-" }),
        el("td", {}, statusPill(t.status), ...reviewPill(t), ...verdictPill(t), ...trackingPill(t), ...commissioningPill(t),
          ...(t.archived ? [el("small", { class: "muted", text: ` archived by ${t.archived.by}: ${t.archived.reason}` })] : [])),
        ...(isProtocol(t) ? [el("td", { class: "muted", colspan: "2", text: "by level (test page)" })]
          : [el("td", { text: fmtU("stiffness", s.k_eff_n_per_m) }), el("td", { text: fmtU("energy", s.edc_j) })]),
        actions);
      // the id is a link (a new tab, the keyboard, a copied address); a click anywhere else on the row opens it too
      tr.addEventListener("click", (ev) => {
        if (ev.target.closest("a, button") || String(window.getSelection() || "")) return;
        location.hash = `#/tests/${t.id}`;
      });
      tbody.append(tr);
    }
    $("history-empty").textContent = archived ? "No archived test matches." : "No test matches.";
    $("history-empty").classList.toggle("hidden", tests.length > 0);
  }

  /** Delete, archive or restore a record: ask (with who and why where the record keeps them), then say. */
  async act(t, action, messageId) {
    const rows = summaryTable([
      ["test", `#${t.id}`, `${t.status}, created ${fmtTime(t.created_at)}`],
      ["specimen / operator", `${t.specimen_id || "-"} / ${t.operator_name || "-"}`],
      ["isolator / motion", `${isolatorName(t)} / ${profileText(t)}`],
    ]);
    let answer;
    if (action === "delete") {
      answer = await confirmDialog({ title: `Delete test #${t.id}? It never ran.`, body: rows, ok: "Delete test", danger: true });
    } else if (action === "archive") {
      const note = el("div", {}, rows, el("p", { text: "An archived test is hidden from the list, kept with its " +
        "samples, and can be restored. The service logs who archived it and why." }));
      answer = await confirmDialog({ title: `Archive test #${t.id}?`, body: note, ok: "Archive test",
        fields: [{ name: "reason", label: "why (at least 3 characters)", minLength: 3, maxLength: 400, multiline: true }] });
    } else {
      answer = await confirmDialog({ title: `Restore test #${t.id} into the list?`, body: rows, ok: "Restore test",
        fields: [{ name: "reason", label: "why (at least 3 characters)", minLength: 3, maxLength: 400, multiline: true }] });
    }
    if (!answer) {
      this.message(messageId, `Test #${t.id}: nothing changed.`);
      return false;
    }
    if (!account.name && !(await refreshAccount()).name) {
      if (!(await askLogin(""))) {
        this.message(messageId, `Test #${t.id}: nothing changed (not logged in).`, "error");
        return false;
      }
    }
    try {
      if (action === "delete") {
        await api.del(`/api/tests/${t.id}`);
        this.message(messageId, `Test #${t.id} deleted.`, "ok");
      } else {
        const done = await api.post(`/api/tests/${t.id}/${action}`, { reason: answer.values.reason });
        const by = done.archived ? done.archived.by : account.name;
        this.message(messageId, `Test #${t.id} ${action === "archive" ? `archived by ${by}` : `restored by ${account.name}`}: ${answer.values.reason}`, "ok");
      }
    } catch (e) {
      this.message(messageId, `Test #${t.id} not ${action === "delete" ? "deleted" : action + "d"}: ${e.message}`, "error");
      return false;
    }
    if (messageId === "history-message") await this.showList();
    return true;
  }

  /** Show test `id`'s page. The page asked for last wins: every await is followed by a check that no other
   * showTest began meanwhile, so a late answer for test A never lands on test B's page (nor binds its buttons). */
  async showTest(id, keepMessage = false) {
    const superseded = this.pages.ask();
    const other = this.shownId !== id;
    this.shownId = id;
    $("t-title").textContent = `Test #${id}`;
    const summary = $("t-summary");
    summary.innerHTML = "";
    if (other) { // another test: nothing of the previous one stays under this title
      this.current = null;
      $("t-events").innerHTML = "";
      $("t-cycles").querySelector("tbody").innerHTML = "";
      this.renderLoops([]);
      delete $("t-loops").dataset.boldCycle; // set again once this test's cycles are drawn
      delete $("t-loops").dataset.boldPhase;
      this.acceptance.hide();
      this.review.clear();
      $("t-action").classList.add("hidden");
    }
    if (!keepMessage) this.message("t-message", "");
    // the downloads name this test from the start (they need only its id)
    this.showBundle(id);
    const csv = $("t-csv");
    csv.href = `/api/tests/${id}/data.csv`;
    csv.setAttribute("download", `isorig-test-${id}.csv`);
    this.checkPdf(id);
    if (other) summary.append(el("div", { class: "muted", text: `loading test #${id}...` }));
    if (this.thisRig === null) await this.loadRigs(); // whose the test is decides what may be done with it
    if (superseded()) return;
    let t;
    try {
      t = await api.get(`/api/tests/${id}`);
    } catch (e) {
      if (superseded()) return;
      summary.innerHTML = "";
      summary.append(el("div", { class: "field-error", text: `could not load test ${id}: ${e.message}` }));
      $("t-action").classList.add("hidden");
      return;
    }
    if (superseded()) return;
    summary.innerHTML = "";
    this.current = t;
    const s = summaryOf(t);
    const kv = (k, v, cls = "") => el("div", { class: `kv ${cls}` }, el("span", { text: k }), el("b", { text: v }));
    summary.append(
      kv("status", t.status + (t.reason ? ` (${t.reason})` : ""), "wide"),
      kv("rig", t.rig_name || "-"),
      kv("specimen", t.specimen_id || "-"),
      kv("operator", t.operator_name || "-"),
      kv("isolator", isolatorName(t)),
      kv("profile", profileText(t)),
      kv("controller", controllerName(t)),
      kv("created", fmtTime(t.created_at)),
      kv("supply", num(t.supply_bar) ? fmtU("pressure", t.supply_bar * 1e5) : "-"),
      kv("vertical load", num(t.vertical_load_n) ? fmtU("force", t.vertical_load_n, { sig: 4 })
        : `- (recorded before it was a condition: ${fmtU("force", 125e3)})`),
      kv("speed", num(t.speed) ? `${t.speed}x` : "-"),
      kv("limits (action when exceeded)", limitsText(t.limits), "wide"),
    );
    const tracking = verdictBlock(t);
    if (tracking) summary.append(tracking);
    if (t.profile && t.profile.kind === "commissioning") {
      const c = (t.summary && t.summary.commissioning) || {};
      summary.append(el("div", { class: "kv wide" }, el("span", { text: "commissioning" }),
        el("b", {}, `${c.state || "-"} `, el("a", { href: `#/commission/${t.id}`, text: "its result on the Commissioning page" }))));
    }
    const indicated = indicationsText(t.summary && t.summary.limit_indications);
    if (indicated) summary.append(kv("limits indicated", indicated, "wide"));
    if (t.label) summary.append(kv("label", t.label));
    if (t.notes) summary.append(kv("notes", t.notes, "wide notes"));
    const protocol = isProtocol(t); // a mean over a protocol's levels mixes amplitudes: the levels are below
    const verdict = t.summary && t.summary.acceptance;
    if (verdict) summary.append(kv("acceptance", `${verdict.verdict} (${verdict.failed} of ${verdict.verdicts} checks failed)`));
    for (const [key, label, quantity, opts] of [
      ...(protocol ? [] : [["k_eff_n_per_m", `mean K_eff${steadyOf(t)}`, "stiffness"], ["edc_j", "mean EDC", "energy"],
        ["xi_eff", "mean xi_eff", "percent"], ["qd_n", "mean Q_d", "force", { sig: 4 }]]),
      ["rms_y_minus_r_m", "raw RMS |y - r| (whole test, same-instant target: incl. latency and taper)", "length"],
      ["last_rms_y_minus_r_m", "raw RMS |y - r| (last 2 cycles, same-instant target: incl. latency and taper)", "length"],
      ["amplitude_error", "amplitude error", "percent"], ["phase_error_deg", "phase error", "angle"],
      ["saturated_share", "command saturated", "percent"], ["peak_flow_l_per_min", "peak flow", null],
    ]) {
      if (!num(s[key])) continue;
      const text = quantity === null ? fmtU("flow", s[key] / 6e4, { sig: 3 }) : fmtU(quantity, s[key], opts || {});
      summary.append(kv(label, text));
    }
    const arch = $("t-archived");
    arch.classList.toggle("hidden", !t.archived);
    arch.textContent = t.archived ? `Archived by ${t.archived.by} on ${fmtTime(t.archived.at)}: ${t.archived.reason}` : "";
    this.review.show(t);
    const action = recordAction(t, this.thisRig);
    const button = $("t-action");
    button.classList.toggle("hidden", !action);
    button.dataset.action = action;
    button.textContent = { delete: "Delete this test (never ran)", archive: "Archive this test...", restore: "Restore this test..." }[action] || "";
    button.onclick = async () => {
      const done = await this.act(t, action, "t-message");
      if (done && action === "delete") {
        location.hash = "#/history";
      } else if (done) {
        this.showTest(id, true);
      }
    };
    this.renderEvents(t.events || []);
    let cycles = [];
    try {
      cycles = listOf(await api.get(`/api/tests/${id}/cycles?arrays=true`), "cycles");
    } catch { /* no cycles yet */ }
    if (superseded()) return;
    this.renderCycles(cycles);
    this.renderLoops(cycles);
    this.acceptance.show(t);
    const eqSeries = await this.eqRecord.show(t);
    if (superseded()) return;
    if (eqSeries && !cycles.length) { // an earthquake test has no cycles: its whole F-d history, thinned
      this.renderLoops([{ displacement_m: eqSeries.displacement_m, force_n: eqSeries.force_n }]);
      $("t-cycles").querySelector("tbody").append(el("tr", {}, el("td", { colspan: "10", class: "muted",
        text: "no cycles: an earthquake test is judged by its J criteria (above); the loop plot shows its whole force-displacement history" })));
    }
  }

  /** The whole test as one zip, where the service offers it (GET /api/tests/{id}/bundle.zip). */
  async showBundle(id) {
    if (this.paths === undefined) {
      try {
        const spec = await api.get("/openapi.json");
        this.paths = (spec && spec.paths) || {};
      } catch {
        this.paths = {};
      }
      if (this.shownId !== id) return; // the page moved on to another test meanwhile
    }
    const a = $("t-bundle");
    const has = Boolean(this.paths["/api/tests/{test_id}/bundle.zip"]);
    a.classList.toggle("hidden", !has);
    if (has) {
      a.href = `/api/tests/${id}/bundle.zip`;
      a.setAttribute("download", `isorig-test-${id}-bundle.zip`);
    }
  }

  /** The PDF is made on request: fetch it on click, save it, or say why there is none. */
  checkPdf(id) {
    const a = $("t-pdf");
    const none = $("t-pdf-none");
    a.classList.remove("hidden");
    none.classList.add("hidden");
    a.href = `/api/tests/${id}/report.pdf`;
    a.setAttribute("download", `isorig-test-${id}-report.pdf`);
    a.onclick = async (ev) => {
      ev.preventDefault();
      a.textContent = "PDF report (making...)";
      try {
        const res = await fetch(a.href);
        if (!res.ok) {
          let why = `HTTP ${res.status}`;
          try { why = (await res.json()).detail || why; } catch { /* not JSON */ }
          none.textContent = `no PDF report: ${why}`;
          none.classList.remove("hidden");
          return;
        }
        const url = URL.createObjectURL(await res.blob());
        const tmp = el("a", { href: url, download: `isorig-test-${id}-report.pdf` });
        document.body.append(tmp);
        tmp.click();
        tmp.remove();
        setTimeout(() => URL.revokeObjectURL(url), 10000);
      } finally {
        a.textContent = "PDF report";
      }
    };
  }

  renderEvents(events) {
    const list = $("t-events");
    list.innerHTML = "";
    for (const e of events) list.append(el("li", { class: e.kind || "", text: eventLine(e) }));
    if (!events.length) list.append(el("li", { class: "muted", text: "no events" }));
  }

  renderCycles(cycles) {
    const table = $("t-cycles");
    const L = unit("length");
    const F = unit("force");
    const cols = [
      ["cycle", "cycle", null], ["d_max_m", `d+ (${L})`, "length"], ["d_min_m", `d- (${L})`, "length"],
      ["f_max_n", `F+ (${F})`, "force"], ["f_min_n", `F- (${F})`, "force"],
      ["k_eff_n_per_m", `K_eff (${unit("stiffness")})`, "stiffness"], ["edc_j", "EDC (J)", "energy"],
      ["xi_eff", "xi_eff (%)", "percent"], ["qd_n", `Q_d (${F})`, "force"], ["kd_n_per_m", `K_d (${unit("stiffness")})`, "stiffness"],
    ];
    table.querySelector("thead").innerHTML = "";
    table.querySelector("thead").append(el("tr", {}, ...cols.map(([, label]) => el("th", { text: label }))));
    const tbody = table.querySelector("tbody");
    tbody.innerHTML = "";
    for (const c of cycles) {
      const m = c.metrics ? { ...c.metrics, cycle: c.cycle } : c;
      const ramp = PHASE_WORDS[c.phase]; // a ramp cycle: shown, marked, left out of the headline figures
      tbody.append(el("tr", ramp ? { class: "ramp-cycle", title: "a ramp cycle: not in the headline figures" } : {},
        ...cols.map(([key, , quantity]) => {
          const v = m[key];
          const text = !num(v) ? "-" : quantity === null ? `${v}${key === "cycle" && ramp ? ` (${ramp})` : ""}` : fmt(quantity, v);
          return el("td", { text });
        })));
    }
  }

  /**
   * The test's loops: the last steady cycle bold (never a ramp-out that came last), the ramp cycles dashed, the
   * others grey. `cycles` without a phase (an earthquake test's whole history): the last one bold.
   */
  renderLoops(cycles) {
    if (!this.loopPlot) this.loopPlot = new LoopPlot($("t-loops"));
    const plot = this.loopPlot;
    plot.reset();
    plot.setLabels(`displacement y (${unit("length")})`, `force F (${unit("force")})`);
    const fx = factorIn("length", system());
    const ff = factorIn("force", system());
    const loops = cycles.filter((c) => {
      const l = c.loop || c;
      return Array.isArray(l.displacement_m) && Array.isArray(l.force_n);
    });
    let bold = loops.length - 1;
    while (bold > 0 && PHASE_WORDS[loops[bold].phase]) bold--;
    if (PHASE_WORDS[loops[bold] && loops[bold].phase]) bold = loops.length - 1; // no steady cycle at all
    loops.forEach((c, k) => {
      const l = c.loop || c;
      const x = Float64Array.from(l.displacement_m, (v) => (v === null ? NaN : v * fx));
      const y = Float64Array.from(l.force_n, (v) => (v === null ? NaN : v * ff));
      if (k !== bold) plot.addPast(x, y, { ramp: Boolean(PHASE_WORDS[c.phase]) });
    });
    if (loops.length) {
      const c = loops[bold];
      const l = c.loop || c;
      plot.setCurrent(Float64Array.from(l.displacement_m, (v) => (v === null ? NaN : v * fx)),
        Float64Array.from(l.force_n, (v) => (v === null ? NaN : v * ff)), 0, l.displacement_m.length);
    }
    plot.draw();
    const box = $("t-loops");
    const c = loops[bold];
    const ramp = c && PHASE_WORDS[c.phase];
    box.dataset.boldCycle = c && c.cycle !== undefined ? String(c.cycle) : "";
    box.dataset.boldPhase = c ? c.phase || "steady" : "";
    const ramps = loops.filter((x) => PHASE_WORDS[x.phase]).length;
    $("t-loops-note").textContent = !c || c.cycle === undefined ? ""
      : ramp ? `cycle ${c.cycle} bold (${ramp}: no steady cycle); the others grey`
        : `cycle ${c.cycle} bold: the last steady cycle; ${ramps ? "ramp cycles dashed, " : ""}the others grey`;
  }
}
