// The live view's readouts: the latest sample, the current cycle's peak and valley, and the margin left to each
// limit with its action and how often an indicating limit was exceeded.

import { actionName, actionOf, LIMITS } from "./limits.js";
import { emptyExtremes, FINAL } from "./livebuffer.js";
import { metrics } from "./livemetrics.js";
import { changed, state } from "./state.js";
import { factorIn, fmt, fmtU } from "./units.js";

const $ = (id) => document.getElementById(id);
const num = (v) => typeof v === "number" && Number.isFinite(v);

const READOUT_MS = 100; // readouts change at most 10 times a second (readable)
// The table velocity of the margins, as the service's detector computes it (on the measured displacement):
// (y[k] - y[k - 5]) / 5 ms over contiguous 1 kHz samples of the streamed displacement.
const VELOCITY_SPAN = 5;
const VELOCITY_SPAN_S = 0.005;
const INDICATIONS_RECORDED = 10; // the service keeps the first 10 indications of a limit as events, counts the rest

export class ReadoutsPart {
  /**
   * Peak and valley of the current cycle (incremental), the readouts and the margins to the limits. After a
   * test: those of its last steady cycle (``endedSpan``), never the ramp-out cycle that happened to come last.
   */
  readouts(i1, now) {
    const a = this.buf.a;
    const span = this.endedSpan();
    const start = span ? span.i0 : Math.min(this.cycleStart, i1);
    const end = span ? span.i1 : i1;
    if (this.cyc.start !== start || this.cyc.scanned > end) {
      // a new cycle: the one that ended stays in the margins until this one has gone past it (no jump at a turn)
      this.lastCyc = !span && this.cyc.start < start && this.cyc.scanned <= end ? this.cyc : null;
      this.cyc = emptyExtremes(start);
    }
    this.labelPeaks(span);
    const c = this.cyc;
    for (let i = Math.max(c.scanned, start); i < end; i++) {
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
    c.scanned = end;
    c.yAbs = Math.max(Math.abs(c.yMax), Math.abs(c.yMin));
    c.fAbs = Math.max(Math.abs(c.fMax), Math.abs(c.fMin));
    if (i1 === 0) return;
    this.noteEndCommand();
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

  /** After a test: how still the valve command was over its last second (metrics.endCommandStdV, in V). */
  noteEndCommand() {
    const b = this.buf;
    if (!FINAL.has(this.status) || !b.len) {
      metrics.endCommandStdV = null;
      return;
    }
    const key = `${this.testId}:${b.len}`;
    if (this.endCommandKey === key) return;
    this.endCommandKey = key;
    const a = b.a;
    const i0 = b.lowerBound(a.t[b.len - 1] - 1.0);
    let n = 0, sum = 0, sq = 0;
    for (let i = i0; i < b.len; i++) {
      const v = a.v[i] / factorIn("voltage", this.sys);
      if (!Number.isFinite(v)) continue;
      n++; sum += v; sq += v * v;
    }
    metrics.endCommandStdV = n ? Math.sqrt(Math.max(0, sq / n - (sum / n) ** 2)) : null;
  }

  /**
   * After a test: the buffer's rows [i0, i1) of its last steady cycle (js/liveheadline.js sets ``endedSteady``
   * from the stored cycles), with the cycle's number; null while a test runs, or when the buffer no longer
   * holds that cycle whole.
   */
  endedSpan() {
    const s = this.endedSteady;
    if (!s || !FINAL.has(this.status)) return null;
    const b = this.buf;
    const i0 = b.lowerBound(s.t0 - 1e-9);
    const i1 = b.lowerBound(s.t1 - 1e-9);
    if (i1 - i0 < 2 || b.a.t[i0] > s.t0 + 2e-3) return null;
    return { i0, i1, cycle: s.cycle };
  }

  /** "cycle peak" while a test runs, "cycle N peak" (its last steady cycle) after it. */
  labelPeaks(span) {
    const text = span ? `cycle ${span.cycle}` : "cycle";
    if (this.peakLabel === text) return;
    this.peakLabel = text;
    const why = span ? `cycle ${span.cycle}: the test's last steady cycle (the ramp-out came after it)` : "the current cycle";
    for (const el of document.querySelectorAll("#readouts .pk")) {
      el.textContent = `${text} ${el.dataset.what}`;
      el.parentElement.title = why;
    }
    const name = $("margins-name");
    if (name) name.textContent = span ? `limits: margin in cycle ${span.cycle} (the last steady), action` : "limits: margin over this and the last cycle, action";
  }

  /**
   * Each limit of the test: the largest value of the current and the last whole cycle against it (a margin
   * does not jump back to "all left" as a cycle begins), the margin left, the action when it is exceeded, and
   * for an indicating limit how often it was exceeded so far.
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
    const p = this.lastCyc || emptyExtremes(0);
    const si = (quantity, shown) => shown / factorIn(quantity, this.sys);
    const peaks = { displacement_m: si("length", Math.max(c.yAbs, p.yAbs)), force_n: si("force", Math.max(c.fAbs, p.fAbs)),
      velocity_m_per_s: si("length", Math.max(c.velAbs, p.velAbs)),
      load_pressure_pa: si("pressure", Math.max(c.plAbs, p.plAbs)), tracking_error_m: si("length", Math.max(c.eAbs, p.eAbs)) };
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
      const over = this.peakLabel && this.peakLabel !== "cycle" ? `in ${this.peakLabel}` : "over this and the last cycle";
      row.title = num(limitSI) ? `largest ${l.name} ${over} ${fmtU(l.quantity, peak)} of the limit ` +
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
}
