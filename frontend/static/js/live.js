// Live view: follows /ws/live (websocket schema v1: hello, samples, status, cycle, event), keeps the recent
// samples in typed-array buffers and redraws the plots on requestAnimationFrame with a smoothly advancing clock.

import { LoopPlot, TimePlot } from "./plots.js";
import { fmtDuration, fmtMetric, setStatusBadge, showAlert, eventLine } from "./ui.js";

const CAP = 131072; // samples kept before the buffer is compacted
const KEEP = 65536; // samples kept on compaction
const WINDOW_S = 10; // time plots show the last 10 s of test time
const PREFILL_MAX_CYCLES = 60; // a late page fetches the stored loops of tests up to this many cycles
const FINAL = new Set(["completed", "stopped", "aborted", "interrupted", "failed"]);
const BAD = new Set(["aborted", "interrupted", "failed"]);

// Buffer channels (display units): time, target/model/displacement in mm, voltage, force in kN,
// adapted parameters, errors in mm.
const CH = ["t", "r", "ym", "y", "v", "f", "ar", "ay", "as", "e_ym", "e_r"];

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

  /** Index of the first sample with t >= time (binary search). */
  lowerBound(time) {
    const t = this.a.t;
    let lo = 0;
    let hi = this.len;
    while (lo < hi) {
      const mid = (lo + hi) >> 1;
      if (t[mid] < time) lo = mid + 1;
      else hi = mid;
    }
    return lo;
  }
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
    this.offsetMm = 0;
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
    this.asScale = 1000;
    this.storedUntil = -Infinity;
    this.localLoops = [];
  }

  // ---------------------------------------------------------------- plots

  createPlots() {
    const mm = { y: 0.5, y2: 0.5 };
    this.plots = {
      loop: new LoopPlot(document.getElementById("plot-loop")),
      disp: new TimePlot(document.getElementById("plot-disp"), {
        minSpan: mm,
        series: [
          { label: "target r", stroke: "#8d99a6", width: 1.5 },
          { label: "model y_m", stroke: "#f0b429", width: 1.5 },
          { label: "displacement y", stroke: "#4aa3ff", width: 2 },
        ],
      }),
      volt: new TimePlot(document.getElementById("plot-volt"), {
        minSpan: { y: 0.5 },
        series: [{ label: "voltage u (V)", stroke: "#c084fc", width: 1.5 }],
      }),
      adapt: new TimePlot(document.getElementById("plot-adapt"), {
        y2: true, y2Label: "", minSpan: { y: 0.1, y2: 0.1 },
        series: [
          { label: "a_r_hat", stroke: "#2fbf71" },
          { label: "a_y_hat", stroke: "#ff7a45" },
          { label: "a_s_hat (mm, right)", stroke: "#4aa3ff", scale: "y2" },
        ],
      }),
      err: new TimePlot(document.getElementById("plot-err"), {
        minSpan: { y: 0.2 },
        series: [
          { label: "y - y_m", stroke: "#f0b429" },
          { label: "y - r", stroke: "#ff4d4f" },
        ],
      }),
    };
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
    if (!this.visible) return;
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
    p.disp.update(a.t, [a.r, a.ym, a.y], i0, i1, xMin, xMax);
    p.volt.update(a.t, [a.v], i0, i1, xMin, xMax);
    p.adapt.update(a.t, [a.ar, a.ay, a.as], i0, i1, xMin, xMax);
    p.err.update(a.t, [a.e_ym, a.e_r], i0, i1, xMin, xMax);
    p.loop.setCurrent(a.y, a.f, Math.min(this.cycleStart, i1), i1);
    p.loop.draw();
    metrics.loopCycles = p.loop.past.length;
    metrics.loopPoints = Math.max(0, i1 - Math.min(this.cycleStart, i1));
    metrics.testId = this.testId;
    const ms = performance.now() - t0;
    metrics.redraws++;
    metrics.drawMsTotal += ms;
    metrics.drawMsMax = Math.max(metrics.drawMsMax, ms);
    if (metrics.firstLiveFrameMs === null && i1 > 0) metrics.firstLiveFrameMs = performance.now();
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
      for (const c of cycles.slice(-loop.maxPast)) {
        if (!Array.isArray(c.displacement_m) || !Array.isArray(c.force_n)) continue;
        loop.addPast(Float64Array.from(c.displacement_m, (v) => (v === null ? NaN : v * 1000)),
          Float64Array.from(c.force_n, (v) => (v === null ? NaN : v / 1000)));
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
    this.test = test;
    this.lastT = -Infinity;
    this.tripMessage = "";
    this.storedUntil = -Infinity;
    this.localLoops = [];
    this.cycleStart = 0;
    this.crossings = [];
    this.prevTarget = NaN;
    this.tDisp = 0;
    this.arrivals = [];
    const speed = test && (test.speed || (test.scenario && test.scenario.speed));
    this.rate = speed > 0 ? speed : 1;
    let profile = test && (test.profile || (test.scenario && test.scenario.profile));
    if (Array.isArray(profile)) profile = profile[0];
    this.offsetMm = profile && profile.offset_m ? profile.offset_m * 1000 : 0;
    this.setController(test && test.controller);
    if (this.plots) this.plots.loop.reset();
    document.getElementById("live-events").innerHTML = "";
    ["l-keff", "l-edc", "l-xi", "l-cycle", "l-progress", "l-left"].forEach((id) => {
      document.getElementById(id).textContent = "-";
    });
    document.getElementById("l-progress-bar").style.width = "0";
    this.dirty = true;
  }

  onSamples(msg) {
    const cols = msg.columns;
    const ix = (name) => cols.indexOf(name);
    const it = ix("time_s"), ir = ix("target_m"), im = ix("model_m"), iy = ix("displacement_m");
    const iv = ix("voltage_v"), iF = ix("force_n"), iar = ix("ar_hat"), iay = ix("ay_hat"), ias = ix("as_hat");
    const num = (v) => (v === null || v === undefined ? NaN : v);
    const b = this.buf;
    const a = b.a;
    for (const row of msg.rows) {
      const t = row[it];
      if (!(t > this.lastT)) continue; // history replay after a reconnect: skip what we have
      if (b.len >= CAP) {
        const drop = b.compact();
        this.cycleStart = Math.max(0, this.cycleStart - drop);
        this.crossings = this.crossings.map((j) => j - drop).filter((j) => j > 0);
      }
      const k = b.len++;
      const r = num(row[ir]) * 1000;
      const ym = num(row[im]) * 1000;
      const y = num(row[iy]) * 1000;
      a.t[k] = t;
      a.r[k] = r;
      a.ym[k] = ym;
      a.y[k] = y;
      a.v[k] = num(row[iv]);
      a.f[k] = num(row[iF]) / 1000;
      a.ar[k] = num(row[iar]);
      a.ay[k] = num(row[iay]);
      a.as[k] = num(row[ias]) * this.asScale;
      a.e_ym[k] = y - ym;
      a.e_r[k] = y - r;
      const rr = r - this.offsetMm;
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
    const changed = msg.status !== this.status;
    this.status = msg.status;
    setStatusBadge(msg.status);
    if (msg.cycle !== undefined && msg.cycle !== null) {
      document.getElementById("l-cycle").textContent =
        msg.cycles_total ? `${msg.cycle} / ${msg.cycles_total}` : String(msg.cycle);
    }
    if (typeof msg.progress === "number") {
      const pct = Math.max(0, Math.min(1, msg.progress)) * 100;
      document.getElementById("l-progress").textContent = `${pct.toFixed(0)} %`;
      document.getElementById("l-progress-bar").style.width = `${pct}%`;
    }
    if (typeof msg.time_left_s === "number") {
      document.getElementById("l-left").textContent = fmtDuration(msg.time_left_s);
    } else if (FINAL.has(msg.status)) {
      document.getElementById("l-left").textContent = "-";
    }
    if (changed && this.testId !== null) {
      if (BAD.has(msg.status)) {
        const reason = msg.reason || this.tripMessage || "";
        showAlert(`${this.tripMessage ? "LIMIT TRIP - " : ""}Test ${this.testId} ${msg.status.toUpperCase()}` +
          `${reason ? ": " + reason : ""}`, "bad");
      } else if (FINAL.has(msg.status)) {
        showAlert(`Test ${this.testId} ${msg.status}`, "info");
      } else if (msg.status === "running") {
        showAlert(`Test ${this.testId} running`, "info");
      }
      this.onTest(this.testId, msg.status);
    }
  }

  onCycle(msg) {
    const m = msg.metrics || {};
    document.getElementById("l-keff").textContent = fmtMetric(m.k_eff_n_per_m, 1e-3, "kN/m", 4);
    document.getElementById("l-edc").textContent = fmtMetric(m.edc_j, 1, "J", 4);
    document.getElementById("l-xi").textContent = fmtMetric(m.xi_eff, 100, "%", 3);
  }

  onEvent(msg, alert = true) {
    const li = document.createElement("li");
    li.className = msg.kind || "";
    li.textContent = eventLine(msg);
    const list = document.getElementById("live-events");
    list.prepend(li);
    while (list.children.length > 200) list.lastChild.remove();
    if (msg.kind === "limit_trip") {
      this.tripMessage = msg.message || "limit trip";
      if (alert) showAlert(`LIMIT TRIP (test ${msg.test_id}): ${msg.message}`, "bad");
    }
  }

  onHello(msg) {
    const test = msg.test || null;
    const id = msg.test_id === undefined ? (test ? test.id : null) : msg.test_id;
    if (id === null) {
      // nothing runs (e.g. after a service restart): keep the last test on screen and show how it ended
      if (this.testId !== null) this.refreshEnded(this.testId);
      else setStatusBadge("idle");
      return;
    }
    const fresh = id !== this.testId;
    if (fresh) this.resetTest(id, test);
    else this.test = test || this.test;
    this.renderHead();
    if (test && test.status) this.onStatus({ status: test.status, test_id: id, reason: test.reason });
    this.loadLastCycle(id);
    if (test) this.loadStoredLoops(id, test.cycles_done);
    if (fresh) {
      for (const e of ((test && test.events) || []).slice(-50)) this.onEvent(e, false);
    }
  }

  /** The stream has no test any more: ask for the last one's record (it may have ended interrupted). */
  refreshEnded(testId) {
    fetch(`/api/tests/${testId}`).then((r) => (r.ok ? r.json() : null)).then((rec) => {
      if (!rec || this.testId !== testId) return;
      this.onStatus({ status: rec.status, test_id: testId, reason: rec.reason, progress: rec.progress });
    }).catch(() => {});
  }

  /** The latest finished cycle's metrics of a test we join late (the stream only sends new ones). */
  loadLastCycle(testId) {
    fetch(`/api/tests/${testId}/cycles`).then((r) => (r.ok ? r.json() : [])).then((cycles) => {
      if (this.testId !== testId || !Array.isArray(cycles) || !cycles.length) return;
      if (document.getElementById("l-keff").textContent !== "-") return; // a live cycle came first
      this.onCycle({ metrics: cycles[cycles.length - 1] });
    }).catch(() => {});
  }

  renderHead() {
    const t = this.test;
    document.getElementById("l-test").textContent = this.testId === null ? "none" : `#${this.testId}`;
    const iso = t && (t.isolator || (t.scenario && t.scenario.isolator && t.scenario.isolator.name));
    document.getElementById("l-isolator").textContent =
      typeof iso === "string" ? iso : iso && iso.name ? iso.name : "-";
    const load = t && (typeof t.vertical_load_n === "number" ? t.vertical_load_n
      : t.scenario && typeof t.scenario.vertical_load_n === "number" ? t.scenario.vertical_load_n : null);
    document.getElementById("l-vertical-load").textContent = load === null ? "-" : `${+(load / 1e3).toPrecision(4)} kN`;
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
   * frequency; PID: nothing). A length in m is shown in mm.
   */
  setController(name) {
    this.controllerName = name;
    const adapted = ((this.declared || {})[name] || []).filter((a) => a.column !== "model_m");
    const byColumn = Object.fromEntries(adapted.map((a) => [a.column, a]));
    const asInfo = byColumn.as_hat;
    const scale = (asInfo ? asInfo.unit === "m" : !name || name === "mrac") ? 1000 : 1;
    if (scale !== this.asScale) { // samples that came before the record: rescale them
      const as = this.buf.a.as;
      for (let i = 0; i < this.buf.len; i++) as[i] *= scale / this.asScale;
      this.asScale = scale;
    }
    const label = (col, right) => {
      const a = byColumn[col];
      if (!a) return `${col} (not used)`;
      const unit = a.unit === "m" ? "mm" : a.unit;
      return `${a.name} (${unit}${right ? ", right" : ""})`;
    };
    const note = document.getElementById("adapt-note");
    if (note) {
      note.textContent = !name ? "" : adapted.length ? `${name}: ${adapted.map((a) => a.meaning).join("; ")}`
        : `${name} adapts nothing (fixed gains)`;
    }
    if (this.plots) this.plots.adapt.setLabels([label("ar_hat"), label("ay_hat"), label("as_hat", true)]);
  }

  /** A message of a test we have no record of (started after hello): fetch its record for the header. */
  followNew(testId) {
    this.resetTest(testId, null);
    this.renderHead();
    fetch(`/api/tests/${testId}`).then((r) => (r.ok ? r.json() : null)).then((rec) => {
      if (!rec || this.testId !== testId) return;
      this.test = rec;
      if (rec.speed > 0 && this.arrivals.length < 3) this.rate = rec.speed;
      let profile = rec.profile;
      if (Array.isArray(profile)) profile = profile[0];
      this.offsetMm = profile && profile.offset_m ? profile.offset_m * 1000 : 0;
      this.setController(rec.controller);
      this.loadStoredLoops(testId, rec.cycles_done);
      this.renderHead();
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

function setConn(up) {
  const el = document.getElementById("conn");
  el.className = `conn ${up ? "conn-up" : "conn-down"}`;
  el.textContent = up ? "live" : "CONNECTION LOST - reconnecting";
  // the rig status shown is the last one known: mark it as such while the stream is down
  const badge = document.getElementById("rig-status");
  badge.classList.toggle("stale", !up);
  badge.title = up ? "what the rig does now" : "last known status: no connection to the service";
}
