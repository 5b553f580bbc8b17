// The live view of an earthquake test (issue 16): shown only while a time-history or hybrid test is in view.
// - The whole record: the planned target (GET /api/tests/{id}/earthquake `planned`: a history's target, a hybrid
//   test's predicted base displacement) with the command r and the measured displacement y as they arrive,
//   on one time axis over the whole test (the Displacement panel keeps the last 10 s at full rate).
// - A hybrid test: the storey drifts (the `structure` rows of each samples message, last 10 s) and the stability
//   monitor (`stability` of samples and status messages: indicator = E_err / limit, the monitor trips at 1), as a
//   large readout with its threshold and as a time plot with the threshold line; a trip (a limit_trip event of
//   the detector rths_stability) turns it red with its reason.
// Data are kept in SI and converted when drawn (a few thousand points, five times a second).

import { fetchWhenFree } from "./api.js";
import { lowerBound, resampleOnto, TimePlot } from "./plots.js";
import { fmtU, toDisplay, unit } from "./units.js";

const $ = (id) => document.getElementById(id);
const num = (v) => typeof v === "number" && Number.isFinite(v);
const OVERVIEW_POINTS = 1500;
const WINDOW_S = 10;
const DRIFT_EVERY = 5; // drifts kept at 200 Hz (storey modes of a few Hz)
const DRAW_MS = 200; // these plots are redrawn at most five times a second
const COLORS = ["#4aa3ff", "#2fbf71", "#ff7a45", "#c084fc", "#f0b429", "#ff4d4f", "#5ad1e6", "#e879f9"];

/** A growing set of channels (SI), the oldest half dropped when full. */
class Ring {
  constructor(names, cap = 40000) {
    this.names = names;
    this.cap = cap;
    this.a = Object.fromEntries(names.map((n) => [n, new Float64Array(cap)]));
    this.len = 0;
  }

  push(values) {
    if (this.len >= this.cap) {
      const keep = this.cap >> 1;
      for (const n of this.names) this.a[n].copyWithin(0, this.len - keep, this.len);
      this.len = keep;
    }
    for (const n of this.names) this.a[n][this.len] = values[n];
    this.len++;
  }

  lowerBound(time) {
    return lowerBound(this.a.t, this.len, time);
  }
}

export class EarthquakeLive {
  constructor() {
    this.kind = null; // "history" / "hybrid" / null
    this.plots = {};
    this.drawnAt = 0;
  }

  /** The test in view changed (or its record came): show the panels of its kind, start over. */
  setTest(testId, test) {
    let p = test && (test.profile || (test.scenario && test.scenario.profile));
    if (Array.isArray(p)) p = p[0];
    const kind = p && (p.kind === "history" || p.kind === "hybrid") ? p.kind : null;
    const same = testId === this.testId && kind === this.kind && kind !== null;
    this.testId = testId;
    this.kind = kind;
    this.profile = p;
    $("eq-panel").classList.toggle("hidden", !kind);
    $("hy-drift-panel").classList.toggle("hidden", kind !== "hybrid");
    $("hy-stab-panel").classList.toggle("hidden", kind !== "hybrid");
    $("stab-card").classList.toggle("hidden", kind !== "hybrid");
    $("readouts").classList.toggle("with-stability", kind === "hybrid");
    if (kind) $("l-cycle").textContent = `none (${kind === "hybrid" ? "a hybrid simulation" : "a time history"})`;
    if (!kind || same) return;
    const duration = num(p.duration_s) ? p.duration_s : test && num(test.duration_s) ? test.duration_s : 60;
    this.duration = duration;
    const n = OVERVIEW_POINTS;
    this.dtGrid = duration / (n - 1);
    this.grid = { t: Float64Array.from({ length: n }, (_, k) => k * this.dtGrid), planned: new Float64Array(n).fill(NaN),
      r: new Float64Array(n).fill(NaN), y: new Float64Array(n).fill(NaN) };
    this.filled = -1; // the last grid index with a measurement
    this.lastT = -Infinity;
    this.rowCount = 0;
    this.driftNames = [];
    this.drifts = null;
    this.stab = new Ring(["t", "ind"], 20000);
    this.stability = null;
    this.trip = null; // {reason, time_s}
    this.ended = null;
    this.createPlots();
    this.renderStability();
    $("eq-note").textContent = this.kind === "hybrid"
      ? "grey wide: the predicted base displacement (full-numerical reference); white dotted: the command the " +
        "structure computes; blue: measured"
      : "grey wide: the planned target; blue: measured";
    this.loadPlanned(testId);
  }

  /** The planned target (and for a hybrid test the prediction), rebuilt by the service from the test's spec. */
  loadPlanned(testId) {
    fetchWhenFree(`/api/tests/${testId}/earthquake?points=2000`, { wanted: () => testId === this.testId })
      .then((r) => (r.ok ? r.json() : null)).then((data) => {
        if (!data || testId !== this.testId || !data.planned) return;
        const { time_s: ts, target_m: rs } = data.planned;
        if (!Array.isArray(ts) || !Array.isArray(rs) || ts.length < 2) return;
        this.grid.planned = resampleOnto(ts, rs, this.grid.t); // linearly onto the overview's grid
        this.plannedLoaded = true;
        if (data.so_far) this.fillSoFar(data.so_far);
        else if (data.record && data.record.series) this.fillSoFar(data.record.series); // it ended before the page came
        this.drawnAt = 0;
      }).catch(() => {});
  }

  /** A page that joined a running test late, or came after it ended: the stored record where the stream's rows
   * left gaps. */
  fillSoFar(soFar) {
    const g = this.grid;
    const { time_s: ts, target_m: rs, displacement_m: ys } = soFar;
    if (!Array.isArray(ts)) return;
    ts.forEach((t, k) => {
      const j = Math.round(t / this.dtGrid);
      if (!(j >= 0 && j < g.t.length) || !Number.isNaN(g.y[j])) return;
      if (ys[k] !== null) g.y[j] = ys[k];
      if (rs[k] !== null) g.r[j] = rs[k];
      this.filled = Math.max(this.filled, j);
    });
  }

  createPlots() {
    for (const p of Object.values(this.plots)) p.destroy();
    this.plots = {};
    if (!this.kind) return;
    const L = unit("length");
    const hybrid = this.kind === "hybrid";
    this.plots.overview = new TimePlot($("plot-eq"), {
      yLabel: `displacement (${L})`, minSpan: toDisplay("length", 1e-3),
      series: [
        { label: hybrid ? "predicted base displacement (reference)" : "planned target", stroke: "rgba(170, 184, 198, 0.55)", width: 5 },
        ...(hybrid ? [{ label: "command r", stroke: "#f4f6f8", width: 1, dash: [2, 3] }] : []),
        { label: "measured y", stroke: "#4aa3ff", width: 1.5 },
      ],
    });
    if (!hybrid) return;
    const names = this.driftNames.length ? this.driftNames : ["drift_1_m"];
    this.plots.drift = new TimePlot($("plot-drift"), {
      yLabel: `storey drift (${L})`, minSpan: toDisplay("length", 2e-4),
      series: names.map((n, k) => ({ label: `storey ${/\d+/.exec(n)[0]}`, stroke: COLORS[k % COLORS.length], width: 1.5 })),
    });
    this.plots.stab = new TimePlot($("plot-stab"), {
      yLabel: "E_err / limit (-)", minSpan: 1.2,
      series: [
        { label: "E_err / limit", stroke: "#2fbf71", width: 2 },
        { label: "trips at 1 (the limit)", stroke: "#ff4d4f", width: 1.5, dash: [6, 4] },
      ],
    });
  }

  onUnitsChanged() {
    if (!this.kind) return;
    this.createPlots();
    this.renderStability();
    this.drawnAt = 0;
  }

  /** A samples message: rows (after `fromT`, those not yet seen) into the overview; the structure; the monitor. */
  onSamples(msg, fromT) {
    if (!this.kind) return;
    const cols = msg.columns || [];
    const it = cols.indexOf("time_s");
    const ir = cols.indexOf("target_m");
    const iy = cols.indexOf("displacement_m");
    const g = this.grid;
    const structure = msg.structure && Array.isArray(msg.structure.rows) && msg.structure.rows.length === msg.rows.length
      ? msg.structure : null;
    if (structure && !this.drifts) {
      this.driftNames = structure.columns.filter((c) => /^drift_\d+_m$/.test(c));
      this.driftIx = this.driftNames.map((c) => structure.columns.indexOf(c));
      this.drifts = new Ring(["t", ...this.driftNames], 40000);
      this.createPlots();
    }
    msg.rows.forEach((row, k) => {
      const t = row[it];
      if (!(t > fromT) || !(t > this.lastT)) return;
      this.lastT = t;
      const j = Math.round(t / this.dtGrid);
      if (j >= 0 && j < g.t.length) {
        if (row[iy] !== null) g.y[j] = row[iy];
        if (row[ir] !== null) g.r[j] = row[ir];
        this.filled = Math.max(this.filled, j);
      }
      if (structure && this.rowCount++ % DRIFT_EVERY === 0) {
        const srow = structure.rows[k];
        const values = { t };
        this.driftNames.forEach((n, q) => { values[n] = srow[this.driftIx[q]] === null ? NaN : srow[this.driftIx[q]]; });
        this.drifts.push(values);
      }
    });
    if (msg.stability) this.onStability(msg.stability);
  }

  /** The monitor (samples or status message): its indicator over time and the readout. */
  onStability(s) {
    if (this.kind !== "hybrid" || !s) return;
    this.stability = s;
    if (num(s.indicator) && num(s.time_s) && (this.stab.len === 0 || s.time_s > this.stab.a.t[this.stab.len - 1])) {
      this.stab.push({ t: s.time_s, ind: s.indicator });
    }
    this.renderStability();
  }

  /** An event: the stability monitor's trip, with its reason. */
  onEvent(e) {
    const v = (e && e.values) || {};
    if (this.kind !== "hybrid" || e.kind !== "limit_trip" || v.detector !== "rths_stability") return;
    this.trip = { reason: v.reason || e.message || "the stability monitor tripped", time_s: num(v.trip_time_s) ? v.trip_time_s : e.time_s,
      indicator: v.indicator };
    if (num(v.indicator)) this.stability = { ...(this.stability || {}), ...v };
    this.renderStability();
  }

  /** The test ended: a record's summary may say how the monitor ended (a page that joined after the trip). */
  onRecord(rec) {
    if (this.kind !== "hybrid" || !rec) return;
    const s = rec.summary && rec.summary.stability;
    if (s && s.tripped && !this.trip) this.trip = { reason: s.reason, time_s: s.trip_time_s, indicator: s.indicator };
    for (const e of rec.events || []) this.onEvent(e);
    this.renderStability();
  }

  renderStability() {
    const card = $("stab-card");
    if (this.kind !== "hybrid") return;
    const s = this.stability || {};
    const ind = num(s.indicator) ? s.indicator : null;
    const tripped = Boolean(this.trip || s.tripped);
    const level = tripped ? "tripped" : ind === null ? "none" : ind >= 0.8 ? "bad" : ind >= 0.5 ? "warn" : "ok";
    card.dataset.level = level;
    $("stab-value").textContent = tripped ? "TRIPPED" : ind === null ? "-" : `${(ind * 100).toFixed(ind < 0.1 ? 1 : 0)} %`;
    const shown = Math.max(0, Math.min(1.25, ind || 0));
    $("stab-fill").style.width = `${(tripped ? 100 : (shown / 1.25) * 100).toFixed(1)}%`;
    const limit = num(s.limit_j) ? fmtU("energy", s.limit_j) : "-";
    const added = num(s.added_energy_j) ? fmtU("energy", s.added_energy_j) : "-";
    const ref = num(s.reference_energy_j) ? `; input energy ${fmtU("energy", s.reference_energy_j)}` : "";
    const detail = $("stab-detail");
    if (tripped) {
      const t = this.trip && num(this.trip.time_s) ? ` at t = ${this.trip.time_s.toFixed(2)} s` : "";
      detail.textContent = `Tripped${t}: ${(this.trip && this.trip.reason) || "the energy added exceeded the limit"}. ` +
        "The valve closed (0 V in 0.1 s); the test ends aborted.";
      detail.title = detail.textContent;
    } else {
      detail.textContent = `E_err ${added} of the limit ${limit}${ref}; trips at 100 %`;
    }
    card.title = "RTHS stability monitor: E_err, the energy the tracking error adds to the loop (work on the specimen " +
      "minus the work the model counts on the commanded path), against max(energy floor, share of the input energy). " +
      "At 100 % the monitor trips: the valve closes and the test ends aborted.";
  }

  /** Redraw the earthquake plots (at most five times a second). tDisp: the live view's display clock. */
  render(tDisp, now, force = false) {
    if (!this.kind || !this.plots.overview) return;
    if (!force && now - this.drawnAt < DRAW_MS) return;
    this.drawnAt = now;
    const g = this.grid;
    const f = toDisplay("length", 1);
    const conv = (arr) => Float64Array.from(arr, (v) => v * f);
    const ys = this.kind === "hybrid" ? [conv(g.planned), conv(g.r), conv(g.y)] : [conv(g.planned), conv(g.y)];
    this.plots.overview.update(g.t, ys, 0, g.t.length, 0, this.duration);
    if (this.kind !== "hybrid") return;
    const xMin = Math.max(0, tDisp - WINDOW_S);
    const xMax = Math.max(tDisp, WINDOW_S);
    if (this.drifts && this.plots.drift) {
      const d = this.drifts;
      const i0 = d.lowerBound(xMin);
      const i1 = Math.max(i0, d.lowerBound(tDisp + 1e-9));
      const t = d.a.t.subarray(i0, i1);
      const series = this.driftNames.map((n) => Float64Array.from(d.a[n].subarray(i0, i1), (v) => v * f));
      this.plots.drift.update(t, series, 0, t.length, xMin, xMax);
    }
    if (this.plots.stab) {
      const s = this.stab;
      const t = s.a.t.subarray(0, s.len);
      const ones = new Float64Array(s.len).fill(1);
      this.plots.stab.update(t, [s.a.ind.subarray(0, s.len), ones], 0, s.len, 0, Math.max(this.duration, tDisp));
    }
  }

  describe() {
    const out = {};
    for (const [k, p] of Object.entries(this.plots)) out[k] = p.describe();
    const g = this.grid;
    const measured = g ? g.y.findIndex((v) => !Number.isNaN(v)) : -1;
    return { kind: this.kind, plots: out, filled: this.filled, points: g ? g.t.length : 0,
      firstMeasuredS: measured >= 0 ? g.t[measured] : null,
      plannedLoaded: Boolean(this.plannedLoaded), drifts: this.drifts ? this.drifts.len : 0, driftNames: this.driftNames,
      stabilityPoints: this.stab ? this.stab.len : 0 };
  }
}
