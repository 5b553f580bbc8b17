// The live view's plots: displacement, command, error and adapted parameters against a smoothly advancing clock
// (redrawn on requestAnimationFrame), the force-displacement loop with its past cycles (those of before this page
// joined from storage), and the relabelling when the units or the controller change.

import { emptyExtremes, FINAL, QUANTITY } from "./livebuffer.js";
import { metrics } from "./livemetrics.js";
import { LoopPlot, PlotStack, TimePlot } from "./plots.js";
import { factorIn, system, toDisplay, unit } from "./units.js";

const $ = (id) => document.getElementById(id);

const WINDOW_S = 10; // time plots show the last 10 s of test time
const LIVE_MAX_FPS = 30; // redraws a second at most (docs/dashboard.md: at least 25)
const FRAME_SLACK_MS = 2; // a display frame this early still counts as due
const PREFILL_MAX_CYCLES = 60; // a late page fetches the stored loops of tests up to this many cycles
const ADAPT_COLUMNS = [["ar_hat", "ar", "#2fbf71"], ["ay_hat", "ay", "#ff7a45"], ["as_hat", "as", "#c084fc"]];

export class PlotsPart {
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
    for (const l of [...this.localLoops, ...(this.endedLoop ? [this.endedLoop] : [])]) {
      l.x = l.x.map((v) => v * fx);
      l.y = l.y.map((v) => v * ff);
    }
    this.plots.loop.setLabels(this.plots.loop.xLabel, this.plots.loop.yLabel, fx, ff,
      [toDisplay("length", 1e-3), toDisplay("force", 1e3)]);
    this.lastCyc = null;
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
    // at most LIVE_MAX_FPS redraws a second: the samples arrive 50 times a second (a chunk of 20 ms), and a redraw
    // of every plot at the display's 60 Hz cost headless chromium (software rendering) 82 % of a CPU while a test
    // ran, twice what 30 redraws cost, for a clock that moves no smoother to the eye
    const period = 1000 / LIVE_MAX_FPS;
    let next = 0;
    const frame = (now) => {
      metrics.frames++;
      if (now + FRAME_SLACK_MS >= next) {
        next = Math.max(next + period, now);
        this.render(now);
      }
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
    const ended = this.endedLoop; // after a test: its last steady loop (js/liveheadline.js)
    if (ended) p.loop.setCurrent(ended.x, ended.y, 0, ended.x.length);
    else p.loop.setCurrent(a.y, a.f, Math.min(this.cycleStart, i1), i1);
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
    const stale = this.loopRequests.ask(); // two reconnects: the later answer has more cycles
    fetch(`/api/tests/${testId}/cycles?arrays=true`).then((r) => (r.ok ? r.json() : [])).then((cycles) => {
      if (stale() || this.testId !== testId) return;
      if (!Array.isArray(cycles) || !cycles.length || !this.plots) return;
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
}
