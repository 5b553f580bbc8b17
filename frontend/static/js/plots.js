// Plots: time plots on uPlot (vendored) and a true x-y force-displacement loop on a plain canvas.

import uPlot from "../vendor/uplot/uPlot.esm.js";

const AXIS = "#8d99a6";
const GRID = "#2a323b";

/** Index of the first of the first len sorted times t that is >= time (binary search). */
export function lowerBound(t, len, time) {
  let lo = 0;
  let hi = len;
  while (lo < hi) {
    const mid = (lo + hi) >> 1;
    if (t[mid] < time) lo = mid + 1;
    else hi = mid;
  }
  return lo;
}

/**
 * ys (sampled at xs, increasing) at the times `at` (increasing), linearly; NaN outside xs and where a neighbour is
 * missing (null or NaN, as a JSON series gives them). For plotting series of different steps on one time axis.
 */
export function resampleOnto(xs, ys, at) {
  const out = new Float64Array(at.length).fill(NaN);
  const last = xs.length - 1;
  let j = 0;
  for (let i = 0; i < at.length; i++) {
    const t = at[i];
    if (!(last >= 1 && t >= xs[0] && t <= xs[last])) continue;
    while (j < last - 1 && xs[j + 1] < t) j++;
    const a = ys[j];
    const b = ys[j + 1];
    if (a === null || b === null) continue;
    const span = xs[j + 1] - xs[j];
    const w = span > 0 ? Math.min(1, Math.max(0, (t - xs[j]) / span)) : 0;
    out[i] = a + w * (b - a);
  }
  return out;
}

/** "Nice" tick values covering [lo, hi] (about n ticks). */
export function niceTicks(lo, hi, n = 6) {
  if (!(hi > lo)) return [lo];
  const raw = (hi - lo) / n;
  const mag = Math.pow(10, Math.floor(Math.log10(raw)));
  const norm = raw / mag;
  const step = (norm < 1.5 ? 1 : norm < 3 ? 2 : norm < 7 ? 5 : 10) * mag;
  const out = [];
  for (let v = Math.ceil(lo / step) * step; v <= hi + step * 1e-9; v += step) out.push(Math.abs(v) < step * 1e-9 ? 0 : v);
  return out;
}

/** min and max of arr[i0:i1] ignoring NaN; null when every value is NaN. */
function finiteRange(arr, i0, i1) {
  let lo = Infinity;
  let hi = -Infinity;
  for (let i = i0; i < i1; i++) {
    const v = arr[i];
    if (v < lo) lo = v;
    if (v > hi) hi = v;
  }
  return lo <= hi ? [lo, hi] : null;
}

function padRange(r, minSpan) {
  let [lo, hi] = r;
  const span = Math.max(hi - lo, minSpan);
  const mid = 0.5 * (lo + hi);
  lo = mid - 0.55 * span;
  hi = mid + 0.55 * span;
  return [lo, hi];
}

const LABEL_FONT = "12px system-ui, sans-serif";

/**
 * Tick labels with the digits their spacing needs: uPlot's own keep at most 3 decimals, so an axis in metres
 * (SI units) with ticks 0.0001 apart read "0", "-0", "0" ... Never "-0".
 */
export function tickLabels(splits, incr) {
  const step = Math.abs(incr) || 1;
  const plain = String(+step.toPrecision(3)); // "0.0001", "0.00025", "2", "1e-7"
  const decimals = plain.includes("e-") ? Math.min(12, -Math.floor(Math.log10(step)) + 2)
    : (plain.split(".")[1] || "").length;
  return splits.map((v) => (Math.abs(v) < step * 1e-6 ? "0" : v.toFixed(decimals)));
}

/**
 * A scrolling time plot with labelled axes. series: [{label, stroke, width, dash, show}]; the data are typed
 * arrays (NaN = no value) shared with the live buffer, already in display units. Later series are drawn on
 * top (the target, thin and dashed, goes last so it is never hidden under the measured trace).
 */
export class TimePlot {
  constructor(el, { series, minSpan = 1e-3, yLabel = "", xLabel = "test time (s)", xAxis = true, height = null }) {
    this.el = el;
    this.series = series;
    this.minSpan = minSpan;
    this.fixedHeight = height;
    const axes = [
      { stroke: AXIS, grid: { stroke: GRID, width: 1 }, ticks: { stroke: GRID }, size: xAxis ? 30 : 6,
        show: xAxis, label: xAxis ? xLabel : undefined, labelSize: 16, labelFont: LABEL_FONT, labelGap: 0 },
      { scale: "y", stroke: AXIS, grid: { stroke: GRID, width: 1 }, ticks: { stroke: GRID }, size: 52,
        values: (u, splits, axis, space, incr) => (this.yTicks = tickLabels(splits, incr)),
        size: (u, values) => Math.max(52, 14 + 7 * Math.max(0, ...(values || []).map((v) => String(v).length))),
        label: yLabel, labelSize: 18, labelFont: LABEL_FONT, labelGap: 0 },
    ];
    const rect = el.getBoundingClientRect();
    this.u = new uPlot({
      width: Math.max(200, rect.width),
      height: this.height(rect),
      pxAlign: 0,
      scales: { x: { time: false, auto: false }, y: { auto: false } },
      axes,
      legend: { show: series.length > 1 || Boolean(series[0] && series[0].legend), live: false,
        markers: { width: 2, dash: (u, i) => (u.series[i].dash ? "dashed" : "solid") } },
      cursor: { show: false },
      series: [{ label: "t (s)" }, ...series.map((s) => ({
        label: s.label, stroke: s.stroke, width: s.width || 1.5, dash: s.dash, scale: "y", points: { show: false },
      }))],
    }, [new Float64Array(0), ...series.map(() => new Float64Array(0))], el);
    this.ro = new ResizeObserver(() => {
      const r = el.getBoundingClientRect();
      if (r.width > 0) this.u.setSize({ width: r.width, height: this.height(r) });
    });
    this.ro.observe(el);
  }

  height(rect) {
    if (this.fixedHeight) return this.fixedHeight;
    return Math.max(120, rect.height - 30);
  }

  /** The axis labels and series names, for tests and scripts. */
  describe() {
    return {
      x: this.u.axes[0].show === false ? "" : this.u.axes[0].label,
      y: this.u.axes[1].label,
      yTicks: this.yTicks || [], // the y axis's tick labels as last drawn
      series: this.u.series.slice(1).map((s) => ({ label: s.label, dash: s.dash || null, width: s.width })),
    };
  }

  destroy() {
    this.ro.disconnect();
    this.u.destroy();
  }

  /** Show columns xs/ys in [i0, i1) between xMin and xMax (seconds). */
  update(xs, ys, i0, i1, xMin, xMax) {
    const data = [xs.subarray(i0, i1)];
    let range = null;
    ys.forEach((y) => {
      data.push(y.subarray(i0, i1));
      const r = finiteRange(y, i0, i1);
      if (r) range = range ? [Math.min(range[0], r[0]), Math.max(range[1], r[1])] : r;
    });
    const u = this.u;
    u.batch(() => {
      u.setData(data, false);
      u.setScale("x", { min: xMin, max: xMax });
      const r = padRange(range || [-1, 1], this.minSpan);
      u.setScale("y", { min: r[0], max: r[1] });
    });
  }
}

/**
 * The adapted parameters a controller declares, one small plot each (its own labelled axis), stacked over
 * one time axis. items: [{label, unit, stroke}]; an empty list shows a note instead.
 */
export class PlotStack {
  constructor(el) {
    this.el = el;
    this.plots = [];
  }

  set(items, note) {
    for (const p of this.plots) p.destroy();
    this.plots = [];
    this.el.innerHTML = "";
    this.items = items;
    if (!items.length) {
      const p = document.createElement("p");
      p.className = "muted plot-note";
      p.textContent = note || "nothing to show";
      this.el.append(p);
      return;
    }
    const each = items.length > 2 ? 78 : 100;
    items.forEach((item, k) => {
      const last = k === items.length - 1;
      const title = document.createElement("div");
      title.className = "stack-title";
      title.style.color = item.stroke;
      title.textContent = item.label;
      const box = document.createElement("div");
      box.className = "stack-item";
      this.el.append(title, box);
      const h = each + (last ? 34 : 0);
      box.style.height = `${h}px`;
      this.plots.push(new TimePlot(box, {
        series: [{ label: item.label, stroke: item.stroke, width: 1.5 }],
        yLabel: item.axis, xAxis: last, height: h, minSpan: item.minSpan || 1e-3,
      }));
    });
  }

  update(xs, ys, i0, i1, xMin, xMax) {
    this.plots.forEach((p, k) => p.update(xs, [ys[k]], i0, i1, xMin, xMax));
  }

  describe() {
    return this.plots.map((p) => p.describe());
  }
}

/**
 * True x-y loop plot: earlier cycles grey (cached on an offscreen canvas), the current cycle bold on top.
 * Coordinates in display units (mm, kN). The axes only grow during a test (reset() starts over).
 */
export class LoopPlot {
  constructor(el, { xLabel = "displacement (mm)", yLabel = "force (kN)" } = {}) {
    this.el = el;
    this.xLabel = xLabel;
    this.yLabel = yLabel;
    this.canvas = document.createElement("canvas");
    this.canvas.className = "loop";
    el.appendChild(this.canvas);
    this.cache = document.createElement("canvas");
    this.past = []; // [{x: Float64Array, y: Float64Array}]
    this.maxPast = 40;
    this.reset();
    this.ro = new ResizeObserver(() => this.resize());
    this.ro.observe(el);
    this.resize();
  }

  /** Axis labels (units changed): the loops already drawn are rescaled by fx, fy. */
  setLabels(xLabel, yLabel, fx = 1, fy = 1, minRange = null) {
    this.xLabel = xLabel;
    this.yLabel = yLabel;
    if (minRange) this.minRange = minRange; // smallest half-span of the axes (display units)
    if (fx !== 1 || fy !== 1) {
      for (const p of this.past) {
        p.x = p.x.map((v) => v * fx);
        p.y = p.y.map((v) => v * fy);
      }
      const [a, b, c, d] = this.range;
      this.range = [a * fx, b * fx, c * fy, d * fy];
    }
    this.cacheDirty = true;
    this.draw();
  }

  reset() {
    this.past = [];
    this.range = [-1, 1, -1, 1];
    this.empty = true; // the axes follow the first data, then only grow
    this.cur = null;
    this.cacheDirty = true;
  }

  resize() {
    const r = this.el.getBoundingClientRect();
    const dpr = window.devicePixelRatio || 1;
    this.w = Math.max(100, r.width);
    this.h = Math.max(100, r.height);
    for (const c of [this.canvas, this.cache]) {
      c.width = Math.round(this.w * dpr);
      c.height = Math.round(this.h * dpr);
    }
    this.dpr = dpr;
    this.cacheDirty = true;
    this.draw();
  }

  /** Grow the axes to include [x0,x1] x [y0,y1] (with margin and nice rounding). */
  include(x0, x1, y0, y1) {
    const [a, b, c, d] = this.empty ? [0, 0, 0, 0] : this.range;
    if (!this.empty && x0 >= a && x1 <= b && y0 >= c && y1 <= d) return;
    this.empty = false;
    const grow = (lo, hi, curLo, curHi) => {
      const m = Math.max(Math.abs(lo), Math.abs(hi), Math.abs(curLo), Math.abs(curHi)) * 1.15 || 1;
      const t = niceTicks(0, m, 4);
      const step = t.length > 1 ? t[1] - t[0] : m;
      const top = Math.ceil(m / step) * step;
      return [-top, top];
    };
    const [mx, my] = this.minRange || [0, 0];
    const xr = grow(x0, x1, Math.min(a, -mx), Math.max(b, mx));
    const yr = grow(y0, y1, Math.min(c, -my), Math.max(d, my));
    this.range = [xr[0], xr[1], yr[0], yr[1]];
    this.cacheDirty = true;
  }

  _frame() {
    return { l: 62, r: 12, t: 10, b: 40 };
  }

  _mapper() {
    const f = this._frame();
    const [x0, x1, y0, y1] = this.range;
    const pw = this.w - f.l - f.r;
    const ph = this.h - f.t - f.b;
    return {
      f, pw, ph,
      X: (x) => f.l + ((x - x0) / (x1 - x0)) * pw,
      Y: (y) => f.t + (1 - (y - y0) / (y1 - y0)) * ph,
    };
  }

  _stroke(ctx, m, xs, ys, i0, i1) {
    ctx.beginPath();
    let pen = false;
    for (let i = i0; i < i1; i++) {
      const x = xs[i];
      const y = ys[i];
      if (!(x === x && y === y)) { pen = false; continue; } // NaN gap
      if (pen) ctx.lineTo(m.X(x), m.Y(y));
      else { ctx.moveTo(m.X(x), m.Y(y)); pen = true; }
    }
    ctx.stroke();
  }

  /** An earlier cycle; `ramp`: a ramp cycle (ramp-in, ramp-out), drawn dashed. */
  addPast(xs, ys, { ramp = false } = {}) {
    let lo = Infinity, hi = -Infinity, flo = Infinity, fhi = -Infinity;
    for (let i = 0; i < xs.length; i++) {
      if (xs[i] < lo) lo = xs[i];
      if (xs[i] > hi) hi = xs[i];
      if (ys[i] < flo) flo = ys[i];
      if (ys[i] > fhi) fhi = ys[i];
    }
    if (lo <= hi && flo <= fhi) this.include(lo, hi, flo, fhi);
    this.past.push({ x: xs, y: ys, ramp });
    if (this.past.length > this.maxPast) {
      this.past.shift();
      this.cacheDirty = true;
    }
    if (!this.cacheDirty) this._paintPast(this.past.length - 1);
  }

  /** The current cycle: xs/ys (display units) in [i0, i1). */
  setCurrent(xs, ys, i0, i1) {
    this.cur = { xs, ys, i0, i1 };
    const rx = finiteRange(xs, i0, i1);
    const ry = finiteRange(ys, i0, i1);
    if (rx && ry) this.include(rx[0], rx[1], ry[0], ry[1]);
  }

  _paintAxes(ctx, m) {
    const [x0, x1, y0, y1] = this.range;
    ctx.fillStyle = "#1b2128";
    ctx.fillRect(0, 0, this.w, this.h);
    ctx.strokeStyle = GRID;
    ctx.lineWidth = 1;
    ctx.fillStyle = AXIS;
    ctx.font = "12px system-ui, sans-serif";
    ctx.textAlign = "center";
    ctx.textBaseline = "top";
    for (const t of niceTicks(x0, x1, 6)) {
      const px = Math.round(m.X(t)) + 0.5;
      ctx.beginPath(); ctx.moveTo(px, m.f.t); ctx.lineTo(px, m.f.t + m.ph); ctx.stroke();
      ctx.fillText(String(+t.toPrecision(6)), px, m.f.t + m.ph + 4);
    }
    ctx.textAlign = "right";
    ctx.textBaseline = "middle";
    for (const t of niceTicks(y0, y1, 6)) {
      const py = Math.round(m.Y(t)) + 0.5;
      ctx.beginPath(); ctx.moveTo(m.f.l, py); ctx.lineTo(m.f.l + m.pw, py); ctx.stroke();
      ctx.fillText(String(+t.toPrecision(6)), m.f.l - 6, py);
    }
    ctx.strokeStyle = "#4a5663";
    ctx.beginPath(); ctx.moveTo(m.X(0), m.f.t); ctx.lineTo(m.X(0), m.f.t + m.ph); ctx.stroke();
    ctx.beginPath(); ctx.moveTo(m.f.l, m.Y(0)); ctx.lineTo(m.f.l + m.pw, m.Y(0)); ctx.stroke();
    ctx.textAlign = "center";
    ctx.textBaseline = "bottom";
    ctx.fillText(this.xLabel, m.f.l + m.pw / 2, this.h - 2);
    ctx.save();
    ctx.translate(12, m.f.t + m.ph / 2);
    ctx.rotate(-Math.PI / 2);
    ctx.textBaseline = "middle";
    ctx.fillText(this.yLabel, 0, 0);
    ctx.restore();
  }

  /** Scale to CSS pixels, save the context and clip to the plot frame; returns the data-to-pixel mapper. */
  _clipToFrame(ctx) {
    ctx.setTransform(this.dpr, 0, 0, this.dpr, 0, 0);
    const m = this._mapper();
    ctx.save();
    ctx.beginPath();
    ctx.rect(m.f.l, m.f.t, m.pw, m.ph);
    ctx.clip();
    return m;
  }

  _paintPast(k) {
    const ctx = this.cache.getContext("2d");
    const m = this._clipToFrame(ctx);
    const p = this.past[k];
    ctx.strokeStyle = p.ramp ? "rgba(240, 180, 41, 0.55)" : "rgba(170, 184, 198, 0.45)";
    ctx.lineWidth = 1;
    ctx.setLineDash(p.ramp ? [5, 4] : []);
    this._stroke(ctx, m, p.x, p.y, 0, p.x.length);
    ctx.restore();
  }

  _repaintCache() {
    const ctx = this.cache.getContext("2d");
    ctx.setTransform(this.dpr, 0, 0, this.dpr, 0, 0);
    this._paintAxes(ctx, this._mapper());
    for (let k = 0; k < this.past.length; k++) this._paintPast(k);
    this.cacheDirty = false;
  }

  draw() {
    if (this.cacheDirty) this._repaintCache();
    const ctx = this.canvas.getContext("2d");
    ctx.setTransform(1, 0, 0, 1, 0, 0);
    ctx.drawImage(this.cache, 0, 0);
    if (!this.cur) return;
    const m = this._clipToFrame(ctx);
    ctx.strokeStyle = "#4aa3ff";
    ctx.lineWidth = 2.5;
    const { xs, ys, i0, i1 } = this.cur;
    this._stroke(ctx, m, xs, ys, i0, i1);
    if (i1 > i0) {
      ctx.fillStyle = "#ffd24a";
      ctx.beginPath();
      ctx.arc(m.X(xs[i1 - 1]), m.Y(ys[i1 - 1]), 4.5, 0, 2 * Math.PI);
      ctx.fill();
    }
    ctx.restore();
  }
}
