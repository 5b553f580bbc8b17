// Live view: follows /ws/live (websocket schema v1: hello, samples, status, cycle, event), keeps the recent
// samples in typed-array buffers (display units) and redraws the plots on requestAnimationFrame with a smoothly
// advancing clock. Also: large readouts with the current cycle's peak and valley, the margin left to each
// limit with its action and how often an indicating limit was exceeded, the events in words (a stop or abort
// asked from any console arrives as an event), the trip banner with the action taken, and what the console
// knows of the test (js/state.js) for the strip and the form.

import { EarthquakeLive } from "./eqlive.js";
import { LoopPlot, lowerBound, PlotStack, TimePlot } from "./plots.js";
import { actionName, actionOf, LIMITS } from "./limits.js";
import {
  changed, isCommissioning, isMove, onState, rigReadings, sourceWords, state, tablePosition, testRunning,
} from "./state.js";
import { eventLine, eventWords, fmtDuration, profileText, setStatusBadge, showAlert } from "./ui.js";
import { factorIn, fmt, fmtU, onUnits, system, toDisplay, unit } from "./units.js";

const CAP = 131072; // samples kept before the buffer is compacted
const KEEP = 65536; // samples kept on compaction
const WINDOW_S = 10; // time plots show the last 10 s of test time
const PREFILL_MAX_CYCLES = 60; // a late page fetches the stored loops of tests up to this many cycles
const READOUT_MS = 100; // readouts change at most 10 times a second (readable)
// The table velocity of the margins, as the service's detector computes it (on the measured displacement):
// (y[k] - y[k - 5]) / 5 ms over contiguous 1 kHz samples of the streamed displacement.
const VELOCITY_SPAN = 5;
const VELOCITY_SPAN_S = 0.005;
const INDICATIONS_RECORDED = 10; // the service keeps the first 10 indications of a limit as events, counts the rest
const FINAL = new Set(["completed", "stopped", "aborted", "interrupted", "failed"]);
const BAD = new Set(["aborted", "interrupted", "failed"]);

// Buffer channels, in display units: time (s), target/model/displacement and errors (length), voltage (V),
// force, load pressure, adapted parameters (their declared unit; a length in the length unit).
const CH = ["t", "r", "ym", "y", "v", "f", "pl", "ar", "ay", "as", "e_ym", "e_r"];
const QUANTITY = { r: "length", ym: "length", y: "length", e_ym: "length", e_r: "length", f: "force", pl: "pressure" };
const ADAPT_COLUMNS = [["ar_hat", "ar", "#2fbf71"], ["ay_hat", "ay", "#ff7a45"], ["as_hat", "as", "#c084fc"]];

export const metrics = {
  frames: 0, // requestAnimationFrame callbacks
  redraws: 0, // frames that redrew the plots
  drawMsTotal: 0,
  drawMsMax: 0,
  samples: 0, // samples received
  messages: 0,
  connects: 0,
  firstLiveFrameMs: null, // performance.now() at the first redraw showing live samples
  wsOpenMs: null,
  lastMessageMs: null,
};
window.__isorig = metrics;

const $ = (id) => document.getElementById(id);
const num = (v) => typeof v === "number" && Number.isFinite(v);

class Buffer {
  constructor() {
    this.a = {};
    for (const c of CH) this.a[c] = new Float64Array(CAP);
    this.len = 0;
  }

  clear() {
    this.len = 0;
  }

  /** Make room: drop the oldest samples, returns how many were dropped. */
  compact() {
    const drop = this.len - KEEP;
    for (const c of CH) this.a[c].copyWithin(0, drop, this.len);
    this.len = KEEP;
    return drop;
  }

  scale(channel, factor) {
    const x = this.a[channel];
    for (let i = 0; i < this.len; i++) x[i] *= factor;
  }

  /** Index of the first sample with t >= time (binary search). */
  lowerBound(time) {
    return lowerBound(this.a.t, this.len, time);
  }
}

function emptyExtremes(start) {
  return { start, scanned: start, yMax: -Infinity, yMin: Infinity, fMax: -Infinity, fMin: Infinity,
    vMax: -Infinity, vMin: Infinity, eAbs: 0, plAbs: 0, yAbs: 0, fAbs: 0, velAbs: 0 };
}

export class LiveView {
  constructor({ onTest, onLink } = {}) {
    this.onTest = onTest || (() => {});
    this.onLink = onLink || (() => {}); // a status message with a real rig's link figures
    this.buf = new Buffer();
    this.testId = null;
    this.test = null;
    this.status = null;
    this.lastT = -Infinity;
    this.cycleStart = 0; // buffer index where the current loop cycle began
    this.crossings = []; // buffer indices of upward zero crossings of the target not yet shown
    this.prevTarget = NaN;
    this.offset = 0; // the profile's offset, display units
    this.tDisp = 0; // displayed test time
    this.rate = 1; // test seconds per wall second (the speed factor)
    this.arrivals = []; // [wall ms, test time] of recent sample batches
    this.lastWall = performance.now();
    this.dirty = false;
    this.visible = true;
    this.ws = null;
    this.wsWanted = true;
    this.retryAt = 0;
    this.backoffMs = 250;
    this.plots = null;
    this.sys = system();
    this.adaptScale = { ar: 1, ay: 1, as: 1 };
    this.adaptQuantity = { ar: null, ay: null, as: null };
    this.adaptChannels = [];
    this.modelIsTarget = false;
    this.storedUntil = -Infinity;
    this.localLoops = [];
    this.cyc = emptyExtremes(0);
    this.readoutAt = 0;
    this.events = []; // [{key, e}] in order
    this.eq = new EarthquakeLive(); // a time-history or hybrid test: the whole record, drifts, stability
    onUnits(() => this.onUnitsChanged());
    // between tests the readouts are the rig now (where the table is, its force, the valve command), as the rig
    // (or the service) says, never the last sample of a test that ended before the service restarted
    onState((what) => { if (what === "rigState" || what === "status" || what === "conn") this.showRigNow(); });
  }

  /**
   * No test running: the DISPLACEMENT readout shows the table's position now (the strip's), FORCE and COMMAND
   * the service's figures of the rig now (GET /api/rig/state), each with its source; a dash says why not.
   */
  showRigNow() {
    if (testRunning()) return;
    const where = tablePosition();
    const el = $("r-y");
    if (!where) {
      el.textContent = "-";
      el.title = "the table now: no reading: no run on record and no reading of the rig";
      el.dataset.source = "none";
    } else if (where.source !== "live") {
      el.textContent = fmtU("length", where.m, { sign: true });
      el.title = `the table now: ${sourceWords(where.source)}`;
      el.dataset.source = where.source;
    }
    const now = rigReadings();
    showReading($("r-f"), "force", "the force now", now.force);
    showReading($("r-v"), "voltage", "the valve command now", now.command);
  }

  // ---------------------------------------------------------------- plots

  createPlots() {
    const L = unit("length");
    if (!this.plots) {
      this.plots = { loop: new LoopPlot($("plot-loop")), adapt: new PlotStack($("plot-adapt")) };
    } else {
      for (const k of ["disp", "volt", "err"]) this.plots[k].destroy();
    }
    const p = this.plots;
    p.loop.setLabels(`displacement y (${L})`, `force F (${unit("force")})`, 1, 1,
      [toDisplay("length", 1e-3), toDisplay("force", 1e3)]);
    p.disp = new TimePlot($("plot-disp"), {
      yLabel: `displacement (${L})`,
      minSpan: toDisplay("length", 5e-4),
      series: [
        { label: "measured y", stroke: "#4aa3ff", width: 2.5 },
        ...(this.modelIsTarget ? [] : [{ label: "reference model y_m", stroke: "#f0b429", width: 1.5, dash: [7, 4] }]),
        { label: this.modelIsTarget ? "target r = reference (on top)" : "target r (on top)", stroke: "#f4f6f8",
          width: 1, dash: [2, 3] },
      ],
    });
    $("disp-note").textContent = this.modelIsTarget
      ? "measured y thick solid, target r thin dotted on top (this controller's reference is the target)"
      : "measured y thick solid, reference model y_m dashed, target r thin dotted on top";
    p.volt = new TimePlot($("plot-volt"), {
      yLabel: "command u (V)", minSpan: 0.5,
      series: [{ label: "valve command u", stroke: "#c084fc", width: 1.5 }],
    });
    p.err = new TimePlot($("plot-err"), {
      yLabel: `error (${L})`, minSpan: toDisplay("length", 2e-4),
      series: [
        ...(this.modelIsTarget ? [] : [{ label: "y - y_m (to the reference model)", stroke: "#f0b429", width: 1.5, dash: [7, 4] }]),
        { label: "y - r (to the target)", stroke: "#ff4d4f", width: 1.5 },
      ],
    });
    this.setController(this.controllerName);
    this.drawEmpty();
    this.renderMargins(true);
    window.__isorigPlots = () => ({
      disp: p.disp.describe(), volt: p.volt.describe(), err: p.err.describe(), adapt: p.adapt.describe(),
      adaptNote: $("adapt-note").textContent, loop: { x: p.loop.xLabel, y: p.loop.yLabel },
      earthquake: this.eq.describe(),
    });
    this.dirty = true;
  }

  /** Axes (labelled, 0 to 10 s) before any sample came: an empty plot still says what it will show. */
  drawEmpty() {
    if (this.buf.len) return;
    const t = Float64Array.of(0);
    const nan = Float64Array.of(NaN);
    const p = this.plots;
    p.disp.update(t, p.disp.series.map(() => nan), 0, 1, 0, WINDOW_S);
    p.volt.update(t, [nan], 0, 1, 0, WINDOW_S);
    p.err.update(t, p.err.series.map(() => nan), 0, 1, 0, WINDOW_S);
    p.adapt.update(t, this.adaptChannels.map(() => nan), 0, 1, 0, WINDOW_S);
  }

  /** The unit choice changed: rescale the buffers and loops, relabel every axis, redraw the readouts. */
  onUnitsChanged() {
    const from = this.sys;
    const to = system();
    if (from === to) return;
    this.sys = to;
    const fx = factorIn("length", to) / factorIn("length", from);
    const ff = factorIn("force", to) / factorIn("force", from);
    for (const [ch, quantity] of Object.entries(QUANTITY)) {
      const f = factorIn(quantity, to) / factorIn(quantity, from);
      if (f !== 1) this.buf.scale(ch, f);
    }
    for (const ch of ["ar", "ay", "as"]) {
      const quantity = this.adaptQuantity[ch];
      if (quantity) {
        const f = factorIn(quantity, to) / factorIn(quantity, from);
        this.buf.scale(ch, f);
        this.adaptScale[ch] *= f;
      }
    }
    this.offset *= fx;
    for (const l of this.localLoops) {
      l.x = l.x.map((v) => v * fx);
      l.y = l.y.map((v) => v * ff);
    }
    this.plots.loop.setLabels(this.plots.loop.xLabel, this.plots.loop.yLabel, fx, ff,
      [toDisplay("length", 1e-3), toDisplay("force", 1e3)]);
    this.cyc = emptyExtremes(this.cycleStart);
    this.createPlots();
    this.eq.onUnitsChanged();
    this.renderHead();
    this.renderMargins(true);
    this.renderEvents();
    this.readoutAt = 0;
    this.showRigNow();
  }

  startRenderLoop() {
    const frame = (now) => {
      metrics.frames++;
      this.render(now);
      requestAnimationFrame(frame);
    };
    requestAnimationFrame(frame);
  }

  render(now) {
    const dtWall = Math.min(0.25, (now - this.lastWall) / 1000);
    this.lastWall = now;
    const b = this.buf;
    if (!this.plots || b.len === 0) return;
    const latest = b.a.t[b.len - 1];
    // advance the displayed clock smoothly at the stream's rate, about 0.1 s of wall time behind the data
    const lag = 0.12 * this.rate;
    const before = this.tDisp;
    this.tDisp += dtWall * this.rate;
    if (this.tDisp > latest || FINAL.has(this.status)) this.tDisp = latest;
    if (this.tDisp < latest - 3 * lag) this.tDisp = latest - lag;
    if (this.tDisp === before && !this.dirty) return;
    if (!this.visible) {
      this.readouts(b.len, now);
      return;
    }
    this.dirty = false;
    const t0 = performance.now();
    const i1 = Math.min(b.len, b.lowerBound(this.tDisp + 1e-9));
    const i0 = b.lowerBound(this.tDisp - WINDOW_S);
    // close loop cycles whose end the display clock has passed
    while (this.crossings.length && this.crossings[0] <= i1) {
      const j = this.crossings.shift();
      this.closeCycle(j);
    }
    const a = b.a;
    const p = this.plots;
    const xMin = Math.max(0, this.tDisp - WINDOW_S);
    const xMax = Math.max(this.tDisp, WINDOW_S);
    p.disp.update(a.t, this.modelIsTarget ? [a.y, a.r] : [a.y, a.ym, a.r], i0, i1, xMin, xMax);
    p.volt.update(a.t, [a.v], i0, i1, xMin, xMax);
    p.adapt.update(a.t, this.adaptChannels.map((c) => a[c]), i0, i1, xMin, xMax);
    p.err.update(a.t, this.modelIsTarget ? [a.e_r] : [a.e_ym, a.e_r], i0, i1, xMin, xMax);
    p.loop.setCurrent(a.y, a.f, Math.min(this.cycleStart, i1), i1);
    p.loop.draw();
    this.eq.render(this.tDisp, now, FINAL.has(this.status));
    this.readouts(i1, now);
    metrics.loopCycles = p.loop.past.length;
    metrics.loopPoints = Math.max(0, i1 - Math.min(this.cycleStart, i1));
    metrics.testId = this.testId;
    const ms = performance.now() - t0;
    metrics.redraws++;
    metrics.drawMsTotal += ms;
    metrics.drawMsMax = Math.max(metrics.drawMsMax, ms);
    if (metrics.firstLiveFrameMs === null && i1 > 0) metrics.firstLiveFrameMs = performance.now();
  }

  /** Peak and valley of the current cycle (incremental), the readouts and the margins to the limits. */
  readouts(i1, now) {
    const a = this.buf.a;
    const start = Math.min(this.cycleStart, i1);
    if (this.cyc.start !== start || this.cyc.scanned > i1) this.cyc = emptyExtremes(start);
    const c = this.cyc;
    for (let i = Math.max(c.scanned, start); i < i1; i++) {
      const y = a.y[i];
      const f = a.f[i];
      const v = a.v[i];
      if (y > c.yMax) c.yMax = y;
      if (y < c.yMin) c.yMin = y;
      if (f > c.fMax) c.fMax = f;
      if (f < c.fMin) c.fMin = f;
      if (v > c.vMax) c.vMax = v;
      if (v < c.vMin) c.vMin = v;
      const e = Math.abs(a.e_r[i]);
      if (e > c.eAbs) c.eAbs = e;
      const pl = Math.abs(a.pl[i]);
      if (pl > c.plAbs) c.plAbs = pl;
      if (i >= VELOCITY_SPAN && Math.abs(a.t[i] - a.t[i - VELOCITY_SPAN] - VELOCITY_SPAN_S) < 5e-4) {
        const vel = Math.abs(a.y[i] - a.y[i - VELOCITY_SPAN]) / VELOCITY_SPAN_S; // display length unit per s
        if (vel > c.velAbs) c.velAbs = vel;
      }
    }
    c.scanned = i1;
    c.yAbs = Math.max(Math.abs(c.yMax), Math.abs(c.yMin));
    c.fAbs = Math.max(Math.abs(c.fMax), Math.abs(c.fMin));
    if (i1 === 0) return;
    if (now - this.readoutAt < READOUT_MS) {
      this.dirty = true; // the last samples of a run are shown too, once the 100 ms have passed
      return;
    }
    this.readoutAt = now;
    const k = i1 - 1;
    const L = "length";
    const si = (quantity, shown) => shown / factorIn(quantity, this.sys);
    const put = (id, quantity, shown) => {
      $(id).textContent = num(shown) ? fmtU(quantity, si(quantity, shown), { sign: true }) : "-";
    };
    put("r-y", L, a.y[k]);
    put("r-f", "force", a.f[k]);
    put("r-v", "voltage", a.v[k]);
    for (const id of ["r-y", "r-f", "r-v"]) { // the running test's latest sample (showRigNow below, between tests)
      delete $(id).dataset.source;
      $(id).title = "";
    }
    put("r-y-max", L, c.yMax);
    put("r-y-min", L, c.yMin);
    put("r-f-max", "force", c.fMax);
    put("r-f-min", "force", c.fMin);
    put("r-v-max", "voltage", c.vMax);
    put("r-v-min", "voltage", c.vMin);
    const live = this.status === "running";
    state.position = { m: si(L, a.y[k]), testId: this.testId, t: a.t[k], live };
    changed("position");
    this.renderMargins(false);
    this.showRigNow();
  }

  /**
   * Each limit of the test: the largest value of the current cycle against it, the margin left, the action
   * when it is exceeded, and for an indicating limit how often it was exceeded so far.
   */
  renderMargins(force) {
    const box = $("margins");
    const lim = (this.test && this.test.limits) || null;
    if (!lim) {
      if (force || box.dataset.empty !== "1") {
        box.innerHTML = "<p class=\"muted\">no test in view</p>";
        box.dataset.empty = "1";
      }
      return;
    }
    box.dataset.empty = "0";
    const c = this.cyc;
    const si = (quantity, shown) => shown / factorIn(quantity, this.sys);
    const peaks = { displacement_m: si("length", c.yAbs), force_n: si("force", c.fAbs),
      velocity_m_per_s: si("length", c.velAbs), load_pressure_pa: si("pressure", c.plAbs),
      tracking_error_m: si("length", c.eAbs) };
    if (!box.querySelector(".margin") || force) {
      box.innerHTML = "";
      for (const l of LIMITS) {
        box.insertAdjacentHTML("beforeend", `<div class="margin" data-limit="${l.key}"><span class="ml">${l.short}</span>` +
          "<span class=\"bar\"><i></i></span><span class=\"mv\"></span><span class=\"ma\"></span></div>");
      }
    }
    const counts = this.indications();
    for (const l of LIMITS) {
      const row = box.querySelector(`.margin[data-limit="${l.key}"]`);
      if (!row) continue;
      const limitSI = lim[l.key];
      const peak = num(peaks[l.key]) && peaks[l.key] > 0 ? peaks[l.key] : 0;
      const used = num(limitSI) && limitSI > 0 ? Math.min(1, peak / limitSI) : 0;
      const action = actionOf(lim, l.key);
      row.querySelector(".bar i").style.width = `${(used * 100).toFixed(1)}%`;
      row.dataset.level = used > 0.95 ? "bad" : used > 0.8 ? "warn" : "ok";
      row.dataset.action = action;
      row.querySelector(".mv").textContent = num(limitSI) ? `${fmtU(l.quantity, Math.max(0, limitSI - peak))} left`
        : "no limit";
      const ma = row.querySelector(".ma");
      const n = counts[l.key];
      if (action === "indicate") {
        ma.textContent = n ? `indicated ${n.text}` : "indicate";
        ma.dataset.count = n ? String(n.count) : "0";
      } else {
        ma.textContent = { valve_close: "valve close", controlled_stop: "ctrl stop" }[action] || actionName(action);
        delete ma.dataset.count;
      }
      row.title = num(limitSI) ? `largest ${l.name} this cycle ${fmtU(l.quantity, peak)} of the limit ` +
        `${fmtU(l.quantity, limitSI, { sig: 4 })} (${(used * 100).toFixed(0)} %); when exceeded: ${actionName(action)}` +
        (l.key === "velocity_m_per_s" ? "; velocity: the streamed displacement's change over 5 ms (the service's " +
          "detector uses the measured displacement the same way)" : "") +
        (action === "indicate" ? `; exceeded ${n ? n.text : "0 times"} in this test` : "") : "";
      row.dataset.peak = fmt(l.quantity, peak);
      row.dataset.max = num(limitSI) ? fmt(l.quantity, limitSI, { sig: 4 }) : "";
    }
  }

  /**
   * How often each indicating limit was exceeded: the record's summary once the test has ended (every
   * excursion), else from the indication events (the service keeps the first 10 per limit as events: "10+").
   */
  indications() {
    const out = {};
    const summary = this.test && this.test.summary && this.test.summary.limit_indications;
    if (summary && FINAL.has(this.status)) {
      for (const [key, count] of Object.entries(summary)) out[key] = { count, text: `${count}\u00d7` };
      return out;
    }
    for (const { e } of this.events) {
      if (e.kind !== "limit_indicate" || !e.values) continue;
      const key = e.values.limit_name;
      const k = typeof e.values.indication === "number" ? e.values.indication : ((out[key] && out[key].count) || 0) + 1;
      if (!out[key] || k > out[key].count) out[key] = { count: k, text: k >= INDICATIONS_RECORDED ? `${k}+\u00d7` : `${k}\u00d7` };
    }
    return out;
  }

  closeCycle(j) {
    const a = this.buf.a;
    const tEnd = a.t[j];
    if (j - this.cycleStart > 10 && !(tEnd <= this.storedUntil + 0.05)) {
      let x = a.y.slice(this.cycleStart, j + 1);
      let y = a.f.slice(this.cycleStart, j + 1);
      const stride = Math.ceil(x.length / 4000);
      if (stride > 1) {
        x = x.filter((_, i) => i % stride === 0);
        y = y.filter((_, i) => i % stride === 0);
      }
      this.plots.loop.addPast(x, y);
      this.localLoops.push({ tEnd, x, y });
      if (this.localLoops.length > this.plots.loop.maxPast) this.localLoops.shift();
    }
    this.cycleStart = j;
  }

  /**
   * A page that joins a running test late (or reconnects) gets only the last seconds of samples: draw the
   * test's earlier loops from storage (GET /api/tests/{id}/cycles?arrays=true), then the ones closed here.
   */
  loadStoredLoops(testId, cyclesDone) {
    if (!(cyclesDone > 0) || cyclesDone > PREFILL_MAX_CYCLES) return;
    fetch(`/api/tests/${testId}/cycles?arrays=true`).then((r) => (r.ok ? r.json() : [])).then((cycles) => {
      if (this.testId !== testId || !Array.isArray(cycles) || !cycles.length || !this.plots) return;
      const loop = this.plots.loop;
      loop.past = [];
      loop.cacheDirty = true;
      let until = -Infinity;
      const fx = factorIn("length", this.sys);
      const ff = factorIn("force", this.sys);
      for (const c of cycles.slice(-loop.maxPast)) {
        if (!Array.isArray(c.displacement_m) || !Array.isArray(c.force_n)) continue;
        loop.addPast(Float64Array.from(c.displacement_m, (v) => (v === null ? NaN : v * fx)),
          Float64Array.from(c.force_n, (v) => (v === null ? NaN : v * ff)));
        if (typeof c.t_end_s === "number") until = Math.max(until, c.t_end_s);
      }
      this.storedUntil = until;
      for (const l of this.localLoops) if (!(l.tEnd <= until + 0.05)) loop.addPast(l.x, l.y);
      this.dirty = true;
    }).catch(() => {});
  }

  // ---------------------------------------------------------------- data

  resetTest(testId, test) {
    this.buf.clear();
    this.testId = testId;
    metrics.testId = testId; // the test in view, also before its first sample is drawn
    this.test = test;
    this.lastT = -Infinity;
    this.trips = []; // the limit trips of this test in words (a second one: a valve close during a controlled stop)
    this.storedUntil = -Infinity;
    this.localLoops = [];
    this.cycleStart = 0;
    this.cyc = emptyExtremes(0);
    this.crossings = [];
    this.prevTarget = NaN;
    this.tDisp = 0;
    this.arrivals = [];
    this.events = [];
    this.lastCycleMetrics = null;
    const speed = test && (test.speed || (test.scenario && test.scenario.speed));
    this.rate = speed > 0 ? speed : 1;
    this.setProfile(test);
    this.setController(test && test.controller);
    if (this.plots) this.plots.loop.reset();
    this.renderEvents();
    ["l-keff", "l-edc", "l-xi", "l-cycle", "l-progress", "l-left", "r-y", "r-y-max", "r-y-min", "r-f", "r-f-max",
      "r-f-min", "r-v", "r-v-max", "r-v-min"].forEach((id) => { $(id).textContent = "-"; });
    $("l-progress-bar").style.width = "0";
    state.testId = testId;
    state.test = test;
    state.stopping = false;
    state.stoppingReason = "";
    state.faulted = "";
    this.renderMargins(true);
    this.dirty = true;
  }

  setProfile(test) {
    this.eq.setTest(this.testId, test);
    let profile = test && (test.profile || (test.scenario && test.scenario.profile));
    if (Array.isArray(profile)) profile = profile[0];
    this.offset = profile && profile.offset_m ? toDisplay("length", profile.offset_m) : 0;
  }

  onSamples(msg) {
    const cols = msg.columns;
    const ix = (name) => cols.indexOf(name);
    const it = ix("time_s"), ir = ix("target_m"), im = ix("model_m"), iy = ix("displacement_m");
    const iv = ix("voltage_v"), iF = ix("force_n"), ipl = ix("load_pressure_pa");
    const iar = ix("ar_hat"), iay = ix("ay_hat"), ias = ix("as_hat");
    const val = (v) => (v === null || v === undefined ? NaN : v);
    const b = this.buf;
    const a = b.a;
    const fx = factorIn("length", this.sys);
    const ff = factorIn("force", this.sys);
    const fp = factorIn("pressure", this.sys);
    const sc = this.adaptScale;
    this.eq.onSamples(msg, this.lastT);
    for (const row of msg.rows) {
      const t = row[it];
      if (!(t > this.lastT)) continue; // history replay after a reconnect: skip what we have
      if (b.len >= CAP) {
        const drop = b.compact();
        this.cycleStart = Math.max(0, this.cycleStart - drop);
        this.cyc = emptyExtremes(this.cycleStart);
        this.crossings = this.crossings.map((j) => j - drop).filter((j) => j > 0);
      }
      const k = b.len++;
      const r = val(row[ir]) * fx;
      const ym = val(row[im]) * fx;
      const y = val(row[iy]) * fx;
      a.t[k] = t;
      a.r[k] = r;
      a.ym[k] = ym;
      a.y[k] = y;
      a.v[k] = val(row[iv]);
      a.f[k] = val(row[iF]) * ff;
      a.pl[k] = ipl >= 0 ? val(row[ipl]) * fp : NaN;
      a.ar[k] = val(row[iar]) * sc.ar;
      a.ay[k] = val(row[iay]) * sc.ay;
      a.as[k] = val(row[ias]) * sc.as;
      a.e_ym[k] = y - ym;
      a.e_r[k] = y - r;
      const rr = r - this.offset;
      if (this.prevTarget <= 0 && rr > 0 && k > 0) this.crossings.push(k);
      this.prevTarget = rr;
      this.lastT = t;
    }
    metrics.samples += msg.rows.length;
    const now = performance.now();
    if (b.len) {
      this.arrivals.push([now, b.a.t[b.len - 1]]);
      while (this.arrivals.length > 2 && now - this.arrivals[0][0] > 2000) this.arrivals.shift();
      const [w0, s0] = this.arrivals[0];
      if (now - w0 > 400) {
        const est = (b.a.t[b.len - 1] - s0) / ((now - w0) / 1000);
        if (est > 0.05) this.rate = 0.7 * this.rate + 0.3 * est;
      }
    }
    this.dirty = true;
  }

  onStatus(msg) {
    const changedStatus = msg.status !== this.status;
    const firstLook = this.status === null; // this page's first status: how a test ended before it looked is no news
    this.status = msg.status;
    state.status = msg.status;
    state.reason = msg.reason || "";
    if (msg.status === "running") state.faulted = "";
    if (FINAL.has(msg.status)) {
      state.stopping = false;
      state.stoppingReason = "";
    }
    if (msg.status === "failed") state.faulted = msg.reason || "the test failed";
    setStatusBadge(state.stopping && msg.status === "running" ? "stopping" : msg.status);
    if (msg.stability) this.eq.onStability(msg.stability);
    if (this.eq.kind) {
      $("l-cycle").textContent = `none (${this.eq.kind === "hybrid" ? "a hybrid simulation" : "a time history"})`;
    } else if (isMove(this.test) || isCommissioning(this.test)) {
      $("l-cycle").textContent = `none (a ${isMove(this.test) ? "manual move" : "commissioning"})`;
    } else if (msg.cycle !== undefined && msg.cycle !== null) {
      $("l-cycle").textContent = msg.cycles_total ? `${msg.cycle} / ${msg.cycles_total}` : String(msg.cycle);
    }
    if (typeof msg.progress === "number") {
      const pct = Math.max(0, Math.min(1, msg.progress)) * 100;
      $("l-progress").textContent = `${pct.toFixed(0)} %`;
      $("l-progress-bar").style.width = `${pct}%`;
    }
    if (typeof msg.time_left_s === "number" && !FINAL.has(msg.status)) {
      $("l-left").textContent = fmtDuration(msg.time_left_s);
    } else if (FINAL.has(msg.status)) {
      $("l-left").textContent = "-";
    }
    if (changedStatus && this.testId !== null) {
      // a move of the table (POST /api/rig/move, /zero), the rig's commissioning (POST /api/commissioning), a test
      const what = isMove(this.test) ? "Manual move" : isCommissioning(this.test) ? "Commissioning" : "Test";
      if (firstLook) {
        // no banner: the strip's last event and the status badge say how the last test ended
      } else if (BAD.has(msg.status)) {
        const trip = this.tripText();
        const reason = trip || msg.reason || ""; // the trip in words with its action, not the detector's internals
        showAlert(`${trip ? "LIMIT TRIP - " : ""}${what} ${this.testId} ${msg.status.toUpperCase()}` +
          `${reason ? ": " + reason : ""}`, "bad");
      } else if (FINAL.has(msg.status)) {
        showAlert(`${what} ${this.testId} ${msg.status}`, "info");
      }
      this.onTest(this.testId, msg.status);
      if (FINAL.has(msg.status)) this.refreshEvents(this.testId);
    }
    changed("status");
  }

  onCycle(msg) {
    const m = msg.metrics || {};
    $("l-keff").textContent = fmtU("stiffness", m.k_eff_n_per_m);
    $("l-edc").textContent = fmtU("energy", m.edc_j);
    $("l-xi").textContent = fmtU("percent", m.xi_eff);
    this.lastCycleMetrics = m;
  }

  // ---------------------------------------------------------------- events

  static eventKey(e) {
    const t = typeof e.time_s === "number" ? e.time_s.toFixed(3) : "";
    return `${e.kind}|${e.message}|${t}`;
  }

  /** An event of the stream (live, no id) or of the record; shown once, in the order they happened. */
  onEvent(msg, alert = true) {
    const e = { ...msg };
    if (!e.created_at && !e.receivedAt) e.receivedAt = Date.now();
    const key = LiveView.eventKey(e);
    if (this.events.some((x) => x.key === key)) return;
    this.events.push({ key, e });
    if (this.events.length > 300) this.events.shift();
    this.noteEnding(e);
    if (e.kind === "rig_fault") state.faulted = e.message || "rig fault";
    this.eq.onEvent(e);
    this.renderEvents();
    if (e.kind === "limit_indicate") this.renderMargins(false);
    if (e.kind === "limit_trip" && alert) showAlert(`LIMIT TRIP (test ${e.test_id ?? this.testId}): ${this.tripText()}`, "bad");
  }

  /**
   * An event that ends the running test early: a stop or abort asked from any console (streamed at once), a
   * limit trip (its action). The strip says STOPPING with the reason until the test ends.
   */
  noteEnding(e) {
    const v = e.values || {};
    this.noteTrip(e);
    const operator = e.kind === "operator" && (v.action === "stop" || v.action === "abort");
    if (!(operator || e.kind === "limit_trip") || this.status !== "running") return;
    state.stopping = true;
    if (e.kind === "limit_trip") {
      const l = LIMITS.find((x) => x.key === v.limit_name);
      state.stoppingReason = `limit trip${l ? ` (${l.name})` : ""}: ${actionName(v.escalation ? "valve_close" : v.action)}`;
    } else if (/requested by/.test(e.message || "")) { // the request, from this or another console
      state.stoppingReason = e.message;
    } else if (!state.stoppingReason) { // the worker's own note of the ramp-out or abort
      state.stoppingReason = v.action === "stop" ? "ramping out" : "aborting";
    }
    setStatusBadge("stopping");
    changed("stopping");
  }

  /** A limit trip, kept in words with the action taken for the banner (each once). */
  noteTrip(e) {
    if (e.kind !== "limit_trip") return;
    const key = LiveView.eventKey(e);
    if (this.trips.some((t) => t.key === key)) return;
    const words = eventWords(e).text.replace(/^LIMIT TRIP( during the controlled stop)?: /, "");
    this.trips.push({ key, words: e.values && e.values.escalation ? `then, during the controlled stop: ${words}` : words });
  }

  /** The limit trips of this test in words, with the action taken ("" when none tripped). */
  tripText() {
    return this.trips.map((t) => t.words).join("; ");
  }

  /** The record's events (ordered by the service): they replace what the stream gave, the rest follows. */
  mergeEvents(list) {
    const fromRecord = (list || []).map((e) => ({ key: LiveView.eventKey(e), e }));
    const keys = new Set(fromRecord.map((x) => x.key));
    const live = this.events.filter((x) => !keys.has(x.key));
    this.events = [...fromRecord, ...live].slice(-300);
    for (const { e } of fromRecord) {
      this.noteEnding(e);
      this.eq.onEvent(e);
    }
    this.renderEvents();
    this.renderMargins(false);
  }

  renderEvents() {
    const list = $("live-events");
    const atEnd = list.scrollTop + list.clientHeight >= list.scrollHeight - 4;
    list.innerHTML = "";
    for (const { e } of this.events) {
      const li = document.createElement("li");
      li.className = e.kind || "";
      li.dataset.source = e.created_at ? "record" : "stream"; // a streamed event arrived live, before any record
      li.textContent = eventLine(e);
      list.append(li);
    }
    if (!this.events.length) list.append(Object.assign(document.createElement("li"), { className: "muted", textContent: "no events yet" }));
    if (atEnd || this.events.length < 8) list.scrollTop = list.scrollHeight;
    const last = this.events.length ? this.events[this.events.length - 1].e : null;
    const lastText = last ? eventLine(last) : "";
    if (!state.lastEvent || state.lastEvent.text !== lastText) {
      state.lastEvent = last ? { text: lastText, kind: last.kind } : null;
      changed("event");
    }
  }

  /** Fetch the test's record: its events (those of before this page joined) and its figures (the summary). */
  refreshEvents(testId) {
    return fetch(`/api/tests/${testId}`).then((r) => (r.ok ? r.json() : null)).then((rec) => {
      if (!rec || this.testId !== testId) return;
      this.test = { ...this.test, ...rec };
      state.test = this.test;
      this.eq.onRecord(rec);
      this.mergeEvents(rec.events);
      this.renderHead();
      changed("test");
    }).catch(() => {});
  }

  // ---------------------------------------------------------------- the test

  onHello(msg) {
    state.helloSeen = true;
    const test = msg.test || null;
    const id = msg.test_id === undefined ? (test ? test.id : null) : msg.test_id;
    if (id === null) {
      // nothing runs (e.g. after a service restart): keep the last test on screen and show how it ended
      if (this.testId !== null) this.refreshEnded(this.testId);
      else {
        setStatusBadge("idle");
        state.status = null;
        changed("status");
      }
      return;
    }
    const fresh = id !== this.testId;
    if (fresh) this.resetTest(id, test);
    else this.test = test || this.test;
    state.test = this.test;
    this.renderHead();
    for (const e of (test && test.events) || []) this.noteTrip(e); // the banner below says the trip in words
    if (test && test.status) this.onStatus({ status: test.status, test_id: id, reason: test.reason });
    this.loadLastCycle(id);
    if (test) this.loadStoredLoops(id, test.cycles_done);
    if (test) this.mergeEvents(test.events);
    changed("test");
  }

  /** The stream has no test any more: ask for the last one's record (it may have ended interrupted). */
  refreshEnded(testId) {
    fetch(`/api/tests/${testId}`).then((r) => (r.ok ? r.json() : null)).then((rec) => {
      if (!rec || this.testId !== testId) return;
      this.test = rec;
      state.test = rec;
      this.mergeEvents(rec.events);
      this.onStatus({ status: rec.status, test_id: testId, reason: rec.reason, progress: rec.progress });
      changed("test");
    }).catch(() => {});
  }

  /** The latest finished cycle's metrics of a test we join late (the stream only sends new ones). */
  loadLastCycle(testId) {
    fetch(`/api/tests/${testId}/cycles`).then((r) => (r.ok ? r.json() : [])).then((cycles) => {
      if (this.testId !== testId || !Array.isArray(cycles) || !cycles.length) return;
      if ($("l-keff").textContent !== "-") return; // a live cycle came first
      this.onCycle({ metrics: cycles[cycles.length - 1] });
    }).catch(() => {});
  }

  renderHead() {
    const t = this.test;
    $("l-test").textContent = this.testId === null ? "none" : `#${this.testId}`;
    const iso = t && (t.isolator || (t.scenario && t.scenario.isolator && t.scenario.isolator.name));
    $("l-isolator").textContent = typeof iso === "string" ? iso : iso && iso.name ? iso.name : "-";
    const load = t && (num(t.vertical_load_n) ? t.vertical_load_n
      : t.scenario && num(t.scenario.vertical_load_n) ? t.scenario.vertical_load_n : null);
    $("l-vertical-load").textContent = load === null ? "-" : fmtU("force", load, { sig: 4 });
    $("l-specimen").textContent = (t && t.specimen_id) || "-";
    $("l-operator").textContent = (t && t.operator_name) || "-";
    $("l-profile").textContent = t ? profileText(t) : "-";
    const notes = (t && t.notes) || "";
    $("l-notes").textContent = notes || "-";
    $("l-notes").title = notes;
    if (this.lastCycleMetrics) this.onCycle({ metrics: this.lastCycleMetrics });
  }

  /** What each controller declares it adapts (GET /api/rig: controllers[].adapted): name, unit, meaning. */
  setControllers(list) {
    this.declared = {};
    for (const c of list || []) if (c && c.name) this.declared[c.name] = c.adapted || [];
    if (this.controllerName !== undefined) this.setController(this.controllerName);
  }

  /**
   * The columns ar_hat, ay_hat, as_hat hold what the running controller adapts, under the names and units it
   * declares (the MRAC: a_r_hat, a_y_hat, a_s_hat of eqs. 18-20; the servo: flow gain ratio, dead zone, learned
   * frequency; PID: nothing). One small plot each, its own axis; a length in the console's length unit.
   */
  setController(name) {
    this.controllerName = name;
    const declared = (this.declared || {})[name] || [];
    const model = declared.find((a) => a.column === "model_m");
    const modelIsTarget = Boolean(model && /target/i.test(model.name));
    const adapted = declared.filter((a) => a.column !== "model_m");
    const byColumn = Object.fromEntries(adapted.map((a) => [a.column, a]));
    // samples that came before the record: rescale them to the declared unit
    for (const [column, ch] of ADAPT_COLUMNS) {
      const a = byColumn[column];
      const quantity = a && a.unit === "m" ? "length" : null;
      const scale = quantity ? factorIn("length", this.sys) : 1;
      if (scale !== this.adaptScale[ch]) this.buf.scale(ch, scale / this.adaptScale[ch]);
      this.adaptScale[ch] = scale;
      this.adaptQuantity[ch] = quantity;
    }
    const note = $("adapt-note");
    if (note) {
      note.textContent = !name ? "" : adapted.length ? `what ${name} adapts, one axis each`
        : `${name} adapts nothing (fixed gains)`;
    }
    if (!this.plots) return;
    if (modelIsTarget !== this.modelIsTarget) {
      this.modelIsTarget = modelIsTarget;
      this.createPlots();
      return;
    }
    const items = [];
    this.adaptChannels = [];
    for (const [column, ch, stroke] of ADAPT_COLUMNS) {
      const a = byColumn[column];
      if (!a) continue;
      const u = a.unit === "m" ? unit("length") : a.unit;
      const shown = u && u !== "-" ? `${a.name} (${u})` : `${a.name} (-)`;
      items.push({ label: `${shown}: ${a.meaning}`, axis: `(${u || "-"})`, stroke,
        minSpan: a.unit === "m" ? toDisplay("length", 1e-4) : 1e-3 });
      this.adaptChannels.push(ch);
    }
    const key = `${name}|${this.sys}|${items.map((i) => i.label).join(",")}`;
    if (key !== this.adaptKey) {
      this.adaptKey = key;
      this.plots.adapt.set(items, name ? `${name} adapts nothing: fixed gains, no adapted parameter to plot` : "no test in view");
    }
    this.dirty = true;
  }

  /** A message of a test we have no record of (started after hello): fetch its record for the header. */
  followNew(testId) {
    this.resetTest(testId, null);
    this.renderHead();
    changed("test");
    fetch(`/api/tests/${testId}`).then((r) => (r.ok ? r.json() : null)).then((rec) => {
      if (!rec || this.testId !== testId) return;
      this.test = rec;
      state.test = rec;
      if (rec.speed > 0 && this.arrivals.length < 3) this.rate = rec.speed;
      this.setProfile(rec);
      this.setController(rec.controller);
      this.loadStoredLoops(testId, rec.cycles_done);
      this.mergeEvents(rec.events);
      this.renderHead();
      this.renderMargins(true);
      changed("test");
    }).catch(() => {});
  }

  handle(msg) {
    metrics.messages++;
    metrics.lastMessageMs = performance.now();
    switch (msg.type) {
      case "hello": this.onHello(msg); break;
      case "samples":
        if (msg.test_id !== undefined && msg.test_id !== this.testId) this.followNew(msg.test_id);
        this.onSamples(msg);
        break;
      case "status":
        if (msg.test_id !== undefined && msg.test_id !== this.testId) this.followNew(msg.test_id);
        this.onStatus(msg);
        if (msg.link) this.onLink(msg);
        break;
      case "cycle": if (msg.test_id === this.testId) this.onCycle(msg); break;
      case "event": if (msg.test_id === this.testId || msg.test_id === null || msg.test_id === undefined) this.onEvent(msg); break;
      default: break; // unknown types are ignored (schema v1 may grow)
    }
  }

  // ---------------------------------------------------------------- connection

  connect() {
    if (this.ws && (this.ws.readyState === WebSocket.OPEN || this.ws.readyState === WebSocket.CONNECTING)) return;
    const url = `${location.protocol === "https:" ? "wss" : "ws"}://${location.host}/ws/live`;
    let ws;
    try {
      ws = new WebSocket(url);
    } catch {
      this.scheduleRetry();
      return;
    }
    this.ws = ws;
    ws.onopen = () => {
      metrics.connects++;
      if (metrics.wsOpenMs === null) metrics.wsOpenMs = performance.now();
      this.backoffMs = 250;
      setConn(true);
    };
    ws.onmessage = (ev) => {
      let msg;
      try { msg = JSON.parse(ev.data); } catch { return; }
      this.handle(msg);
    };
    ws.onclose = () => {
      setConn(false);
      this.ws = null;
      this.scheduleRetry();
    };
    ws.onerror = () => { /* onclose follows */ };
  }

  scheduleRetry() {
    this.retryAt = Date.now() + this.backoffMs;
    this.backoffMs = Math.min(2000, this.backoffMs * 2);
  }

  /** Called by the worker tick (and on focus/visibility/online): reconnect when due. */
  tick() {
    if (!this.wsWanted) return;
    if (!this.ws && Date.now() >= this.retryAt) this.connect();
  }

  reconnectNow() {
    this.retryAt = 0;
    this.tick();
  }
}

/** A readout of the rig now (between tests): the figure with its source in the tooltip, or a dash saying why not. */
function showReading(el, quantity, what, reading) {
  if (reading.value === null) {
    el.textContent = "-";
    el.title = `${what}: ${reading.why}`;
    el.dataset.source = "none";
    return;
  }
  el.textContent = fmtU(quantity, reading.value, { sign: true });
  el.title = `${what}: ${sourceWords(reading.source)}`;
  el.dataset.source = reading.source;
}

function setConn(up) {
  const el = $("conn");
  el.className = `conn ${up ? "conn-up" : "conn-down"}`;
  el.textContent = up ? "live" : "CONNECTION LOST - reconnecting";
  // the rig status shown is the last one known: mark it as such while the stream is down
  const badge = $("rig-status");
  badge.classList.toggle("stale", !up);
  badge.title = up ? "what the rig does now" : "last known status: no connection to the service";
  state.conn = up;
  if (up) state.everConnected = true;
  else state.helloSeen = false;
  changed("conn");
}
