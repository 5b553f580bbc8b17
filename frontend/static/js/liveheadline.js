// The live view's headline figures (K_eff, EDC, xi_eff) and which loop is drawn bold. While a test runs: the
// last finished cycle, marked when it is a ramp cycle (ramp-in, ramp-out: a lower amplitude, a stiffer loop).
// Once it has ended: the figures of its steady cycles (the record's summary, the same as the PDF's), or for a
// protocol the last steady cycle (a mean over levels mixes amplitudes), and its last steady loop bold with the
// ramp cycles dashed; never the ramp-out cycle that happened to come last.

import { isProtocol } from "./acceptance.js";
import { FINAL } from "./livebuffer.js";
import { PHASE_WORDS } from "./ui.js";
import { factorIn, fmtU } from "./units.js";

const $ = (id) => document.getElementById(id);
const num = (v) => typeof v === "number" && Number.isFinite(v);

/** The last cycle of `cycles` in the steady phase (a cycle without a phase counts as steady), else null. */
export function lastSteady(cycles) {
  for (let k = cycles.length - 1; k >= 0; k--) if ((cycles[k].phase || "steady") === "steady") return cycles[k];
  return null;
}

export class HeadlinePart {
  /** A finished cycle (the stream's, or the last stored one of a test joined late): {cycle, phase, metrics}. */
  onCycle(msg) {
    const c = { cycle: msg.cycle, phase: msg.phase || "steady", metrics: msg.metrics || {} };
    this.lastCycle = c;
    if (c.phase === "steady") this.lastSteadyCycle = c;
    this.renderHeadline();
  }

  /** What the headline shows: {metrics, label, source}, or null before any cycle. */
  headline() {
    const ended = FINAL.has(this.status);
    const s = (this.test && this.test.summary) || {};
    const means = s.loop_metrics_mean || {};
    if (ended && !isProtocol(this.test) && num(means.k_eff_n_per_m) && s.steady_cycles > 0) {
      const n = s.steady_cycles;
      return { metrics: means, source: "steady-mean", label: `mean of ${n} steady cycle${n === 1 ? "" : "s"}` };
    }
    const steady = this.lastSteadyCycle;
    if (ended && steady) {
      return { metrics: steady.metrics, source: "last-steady",
        label: `cycle ${steady.cycle ?? "?"}, the last steady one` };
    }
    const c = this.lastCycle;
    if (!c) return null;
    const ramp = PHASE_WORDS[c.phase];
    return { metrics: c.metrics, source: ramp ? "ramp" : "cycle",
      label: ramp ? `last cycle: ${ramp}, not steady` : "last cycle" };
  }

  renderHeadline() {
    const h = this.headline();
    const m = (h && h.metrics) || {};
    $("l-keff-label").textContent = `K_eff (${h ? h.label : "last cycle"})`;
    $("l-keff").textContent = h ? fmtU("stiffness", m.k_eff_n_per_m) : "-";
    $("l-edc").textContent = h ? fmtU("energy", m.edc_j) : "-";
    $("l-xi").textContent = h ? fmtU("percent", m.xi_eff) : "-";
    for (const id of ["l-keff", "l-edc", "l-xi"]) $(id).closest(".kv").dataset.source = h ? h.source : "none";
  }

  /**
   * After a test: its stored loops (GET /api/tests/{id}/cycles?arrays=true), the last steady one bold, the ramp
   * cycles dashed, the others grey; the view keeps them until the next test.
   */
  showEndedLoops(testId) {
    this.loopRequests.ask(); // a running test's loops asked for before are not drawn over these
    fetch(`/api/tests/${testId}/cycles?arrays=true`).then((r) => (r.ok ? r.json() : [])).then((cycles) => {
      if (this.testId !== testId || !FINAL.has(this.status) || !Array.isArray(cycles) || !this.plots) return;
      const loops = cycles.filter((c) => Array.isArray(c.displacement_m) && Array.isArray(c.force_n));
      if (!loops.length) return;
      const bold = lastSteady(loops) || loops[loops.length - 1];
      const fx = factorIn("length", this.sys);
      const ff = factorIn("force", this.sys);
      const shown = (c) => ({ x: Float64Array.from(c.displacement_m, (v) => (v === null ? NaN : v * fx)),
        y: Float64Array.from(c.force_n, (v) => (v === null ? NaN : v * ff)) });
      const plot = this.plots.loop;
      plot.past = [];
      plot.cacheDirty = true;
      const others = loops.filter((c) => c !== bold).slice(-plot.maxPast);
      for (const c of others) {
        const l = shown(c);
        plot.addPast(l.x, l.y, { ramp: Boolean(PHASE_WORDS[c.phase]) });
      }
      const phase = bold.phase || "steady";
      this.endedLoop = { ...shown(bold), cycle: bold.cycle, phase };
      // the readouts' peak and valley, and the margins, of that cycle (js/livereadouts.js)
      this.endedSteady = phase === "steady" && num(bold.t_start_s) && num(bold.t_end_s)
        ? { cycle: bold.cycle, t0: bold.t_start_s, t1: bold.t_end_s } : null;
      this.readoutAt = 0;
      const box = $("plot-loop");
      box.dataset.boldCycle = String(bold.cycle);
      box.dataset.boldPhase = phase;
      const ramps = loops.filter((c) => PHASE_WORDS[c.phase]).length;
      $("loop-note").textContent = phase === "steady"
        ? `cycle ${bold.cycle} bold: the last steady cycle; ${ramps ? "ramp cycles dashed, " : ""}the others grey`
        : `cycle ${bold.cycle} bold (${PHASE_WORDS[phase]}: the test had no steady cycle); the others grey`;
      this.dirty = true;
    }).catch(() => {});
  }

  /** A new test in view: the headline and the loop plot follow its cycles again. */
  clearHeadline() {
    this.lastCycle = null;
    this.lastSteadyCycle = null;
    this.endedLoop = null;
    this.endedSteady = null;
    const box = $("plot-loop");
    delete box.dataset.boldCycle;
    delete box.dataset.boldPhase;
    $("loop-note").textContent = "current cycle bold, earlier cycles grey";
    this.renderHeadline();
  }
}
