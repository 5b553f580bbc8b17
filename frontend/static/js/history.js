// History: the list of past tests (filter by isolator, status, date) and one test's page
// (loops, per-cycle metrics, events, downloads).

import { api } from "./api.js";
import { LoopPlot } from "./plots.js";
import { el, eventLine, fmtMetric, fmtTime } from "./ui.js";

const $ = (id) => document.getElementById(id);

function listOf(data, key) {
  if (Array.isArray(data)) return data;
  if (data && Array.isArray(data[key])) return data[key];
  if (data && Array.isArray(data.items)) return data.items;
  return [];
}

export function isolatorName(t) {
  const iso = t.isolator !== undefined ? t.isolator : t.scenario && t.scenario.isolator;
  if (!iso) return "-";
  return typeof iso === "string" ? iso : iso.name || "-";
}

export function profileText(t) {
  let p = t.profile || (t.scenario && t.scenario.profile) || (t.request && t.request.profile);
  if (Array.isArray(p)) p = p.length === 1 ? p[0] : { kind: `${p.length} sine blocks` };
  if (!p) return "-";
  if (p.kind === "sine" || p.amplitude_m !== undefined) {
    return `${(p.amplitude_m * 1000).toPrecision(3)} mm, ${p.frequency_hz} Hz x ${p.cycles}`;
  }
  if (p.kind === "protocol") return `protocol ${p.name || "(inline)"}`;
  return p.kind || "-";
}

function controllerName(t) {
  const c = t.controller !== undefined ? t.controller : t.scenario && t.scenario.controller;
  return typeof c === "string" ? c : c && (c.name || c.kind) ? c.name || c.kind : "-";
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

function statusPill(status) {
  return el("span", { class: `pill status-${status}`, text: status });
}

export class History {
  constructor() {
    this.loopPlot = null;
    $("history-filter").addEventListener("submit", (ev) => {
      ev.preventDefault();
      this.showList();
    });
  }

  async showList() {
    const q = new URLSearchParams();
    if ($("h-isolator").value) q.set("isolator", $("h-isolator").value);
    if ($("h-status").value) q.set("status", $("h-status").value);
    // the dates are the operator's local days; the service keeps UTC
    if ($("h-since").value) q.set("since", new Date(`${$("h-since").value}T00:00:00`).toISOString());
    if ($("h-until").value) q.set("until", new Date(`${$("h-until").value}T23:59:59.999`).toISOString());
    const tbody = $("history-table").querySelector("tbody");
    let tests = [];
    try {
      tests = listOf(await api.get(`/api/tests?${q}`), "tests");
    } catch (e) {
      tbody.innerHTML = "";
      tbody.append(el("tr", {}, el("td", { text: `could not load: ${e.message}`, colspan: "8" })));
      return;
    }
    tbody.innerHTML = "";
    for (const t of tests) {
      const s = summaryOf(t);
      const tr = el("tr", { class: "link", "data-id": String(t.id) },
        el("td", { text: `#${t.id}` }),
        el("td", { text: fmtTime(t.created_at || t.started_at) }),
        el("td", { text: isolatorName(t) }),
        el("td", { text: profileText(t) }),
        el("td", { text: controllerName(t) }),
        el("td", {}, statusPill(t.status)),
        el("td", { text: fmtMetric(s.k_eff_n_per_m, 1e-3, "kN/m", 4) }),
        el("td", { text: fmtMetric(s.edc_j, 1, "J", 4) }));
      tr.addEventListener("click", () => { location.hash = `#/tests/${t.id}`; });
      tbody.append(tr);
    }
    $("history-empty").classList.toggle("hidden", tests.length > 0);
  }

  async showTest(id) {
    $("t-title").textContent = `Test #${id}`;
    const summary = $("t-summary");
    summary.innerHTML = "";
    let t;
    try {
      t = await api.get(`/api/tests/${id}`);
    } catch (e) {
      summary.append(el("div", { class: "field-error", text: `could not load test ${id}: ${e.message}` }));
      return;
    }
    const s = summaryOf(t);
    const kv = (k, v) => el("div", { class: "kv" }, el("span", { text: k }), el("b", { text: v }));
    summary.append(
      kv("status", t.status + (t.reason ? ` (${t.reason})` : "")),
      kv("isolator", isolatorName(t)),
      kv("profile", profileText(t)),
      kv("controller", controllerName(t)),
      kv("created", fmtTime(t.created_at)),
      kv("supply", typeof t.supply_bar === "number" ? `${t.supply_bar} bar` : "-"),
      kv("vertical load", typeof t.vertical_load_n === "number" ? `${+(t.vertical_load_n / 1e3).toPrecision(4)} kN`
        : "- (recorded before it was a condition: 125 kN)"),
      kv("speed", typeof t.speed === "number" ? `${t.speed}x` : "-"),
    );
    for (const [key, label, scale, unit] of [
      ["k_eff_n_per_m", "mean K_eff", 1e-3, "kN/m"], ["edc_j", "mean EDC", 1, "J"],
      ["xi_eff", "mean xi_eff", 100, "%"], ["qd_n", "mean Q_d", 1e-3, "kN"],
      ["rms_y_minus_r_m", "RMS y-r (test)", 1000, "mm"], ["last_rms_y_minus_r_m", "RMS y-r (last 2 cycles)", 1000, "mm"],
      ["amplitude_error", "amplitude error", 100, "%"], ["phase_error_deg", "phase error", 1, "deg"],
      ["saturated_share", "command saturated", 100, "%"], ["peak_flow_l_per_min", "peak flow", 1, "l/min"],
    ]) {
      if (typeof s[key] === "number") summary.append(kv(label, fmtMetric(s[key], scale, unit, 4)));
    }
    const csv = $("t-csv");
    csv.href = `/api/tests/${id}/data.csv`;
    csv.setAttribute("download", `isorig-test-${id}.csv`);
    this.checkPdf(id, t.status);
    this.renderEvents(t.events || []);
    let cycles = [];
    try {
      cycles = listOf(await api.get(`/api/tests/${id}/cycles?arrays=true`), "cycles");
    } catch { /* no cycles yet */ }
    this.renderCycles(cycles);
    this.renderLoops(cycles);
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
    const cols = [
      ["cycle", "cycle", null, ""], ["d_max_m", "d+ (mm)", 1000], ["d_min_m", "d- (mm)", 1000],
      ["f_max_n", "F+ (kN)", 1e-3], ["f_min_n", "F- (kN)", 1e-3], ["k_eff_n_per_m", "K_eff (kN/m)", 1e-3],
      ["edc_j", "EDC (J)", 1], ["xi_eff", "xi_eff (%)", 100], ["qd_n", "Q_d (kN)", 1e-3],
      ["kd_n_per_m", "K_d (kN/m)", 1e-3],
    ];
    table.querySelector("thead").innerHTML = "";
    table.querySelector("thead").append(el("tr", {}, ...cols.map(([, label]) => el("th", { text: label }))));
    const tbody = table.querySelector("tbody");
    tbody.innerHTML = "";
    for (const c of cycles) {
      const m = c.metrics ? { ...c.metrics, cycle: c.cycle } : c;
      tbody.append(el("tr", {}, ...cols.map(([key, , scale]) => {
        const v = m[key];
        const text = typeof v !== "number" ? "-" : scale === null ? String(v) : (v * scale).toPrecision(4);
        return el("td", { text });
      })));
    }
  }

  renderLoops(cycles) {
    if (!this.loopPlot) this.loopPlot = new LoopPlot($("t-loops"));
    const plot = this.loopPlot;
    plot.reset();
    const loops = cycles
      .map((c) => c.loop || c)
      .filter((l) => Array.isArray(l.displacement_m) && Array.isArray(l.force_n));
    loops.forEach((l, k) => {
      const x = Float64Array.from(l.displacement_m, (v) => (v === null ? NaN : v * 1000));
      const y = Float64Array.from(l.force_n, (v) => (v === null ? NaN : v / 1000));
      if (k < loops.length - 1) plot.addPast(x, y);
      else plot.setCurrent(x, y, 0, x.length);
    });
    plot.draw();
  }
}
