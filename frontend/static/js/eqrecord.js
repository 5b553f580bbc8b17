// An earthquake test's page after the run (issue 16): the J criteria with their bounds and verdicts, and the
// record against what it should have been, from GET /api/tests/{id}/earthquake (the figures of the PDF report).
// - A time history: the target r and the measured displacement y over the whole test (J1-J3 judge y against r).
// - A hybrid test: the full-numerical reference's base displacement (the same building with the isolator's
//   Bouc-Wen model, integrated offline) beside the hybrid test's own base displacement (the command to the rig)
//   and the measured y (J4, J5 judge the base displacement against the reference); and a table of each channel's
//   peak, hybrid test against reference.
// Data stay in SI and are converted when drawn; the page is drawn again when the unit choice changes.

import { fetchWhenFree } from "./api.js";
import { resampleOnto, TimePlot } from "./plots.js";
import { el } from "./ui.js";
import { fmtU, sigDigits, toDisplay, unit } from "./units.js";

const $ = (id) => document.getElementById(id);
const num = (v) => typeof v === "number" && Number.isFinite(v);

/** A channel name of the structure in words: "drift_2_m" -> "storey 2 drift". */
function channelWords(name) {
  if (name === "base_displacement_m") return ["base displacement", "length"];
  if (name === "isolator_force_n") return ["isolator force", "force"];
  let m = /^drift_(\d+)_m$/.exec(name);
  if (m) return [`storey ${m[1]} drift`, "length"];
  m = /^abs_acc_(\w+)_m_per_s2$/.exec(name);
  if (m) return [`${m[1] === "base" ? "base" : `storey ${m[1]}`} absolute acceleration`, "acceleration"];
  return [name, null];
}

function fmtChannel(quantity, value) {
  if (!num(value)) return "-";
  return quantity ? fmtU(quantity, value) : sigDigits(value, 3); // the console's digits for each quantity
}

export class EarthquakeRecord {
  constructor() {
    this.plot = null;
    this.errPlot = null;
    this.shown = null; // the test id whose figures are on the page
    window.__isorigEqRecord = () => this.describe();
  }

  hide() {
    $("t-eq").classList.add("hidden");
    if (this.plot) this.plot.destroy();
    if (this.errPlot) this.errPlot.destroy();
    this.plot = null;
    this.errPlot = null;
    this.shown = null;
  }

  /** Show test `t`'s figures if it is a history or hybrid test that ran; else hide the panel. The record's
   * thinned series (for the page's F-d plot), or null. */
  async show(t) {
    const p = t.profile || (t.scenario && t.scenario.profile) || (t.request && t.request.profile) || {};
    const kind = p.kind;
    if (kind !== "history" && kind !== "hybrid") {
      this.wanted = null;
      this.hide();
      return null;
    }
    this.wanted = t.id;
    const wanted = () => this.wanted === t.id;
    let data;
    try {
      const res = await fetchWhenFree(`/api/tests/${t.id}/earthquake?points=2000`, {
        wanted,
        onBusy: (waitS) => { // the service's check pool builds other figures or checks: say so, ask again
          $("t-eq").classList.remove("hidden");
          $("t-eq-judged").textContent = `the service is busy with other checks: asking again for the figures in ${waitS} s ...`;
        },
      });
      data = res.ok ? await res.json() : null;
    } catch {
      data = null;
    }
    if (!wanted()) return null; // the page shows another test now
    if (!data || !data.record || !Array.isArray(data.record.verdicts)) {
      this.hide();
      $("t-eq").classList.remove("hidden");
      $("t-eq-judged").textContent = data && !data.record
        ? "no samples stored for this test: nothing to judge" : "the figures could not be loaded";
      $("t-eq-criteria").querySelector("tbody").innerHTML = "";
      $("t-eq-peaks").classList.add("hidden");
      return null;
    }
    this.render(t.id, data);
    return data.record.series;
  }

  render(testId, data) {
    const rec = data.record;
    $("t-eq").classList.remove("hidden");
    const hybrid = data.kind === "hybrid";
    const j = rec.judged || {};
    $("t-eq-title").textContent = hybrid
      ? "Hybrid simulation: J criteria, and the base displacement against the full-numerical reference"
      : "Time history: J criteria, and the measured displacement against the target";
    $("t-eq-judged").textContent = `judged on ${j.what || "the record"}` +
      `${num(j.samples) ? ` (${j.samples} samples, to ${sigDigits(j.until_s, 4)} s)` : ""}; ` +
      (hybrid ? "J1-J3: measured y against the command r; J4, J5: the base displacement against the reference"
        : "measured y against the target r");
    const tbody = $("t-eq-criteria").querySelector("tbody");
    tbody.innerHTML = "";
    for (const v of rec.verdicts) {
      const value = num(v.value) ? `${sigDigits(v.value, 4)} ${v.unit}` : "-"; // as the PDF report gives it
      const verdict = v.met === true ? "met" : v.met === false ? "NOT met" : "not judged";
      tbody.append(el("tr", { "data-key": v.key },
        el("td", { text: v.name }), el("td", { text: v.meaning }), el("td", { class: "num", text: value }),
        el("td", { text: v.bound }),
        el("td", {}, el("span", { class: `pill ${v.met === true ? "met" : v.met === false ? "unmet" : ""}`, text: verdict }))));
    }
    this.renderPeaks(hybrid ? rec.structure : null);
    this.renderPlot(rec.series, hybrid);
    this.shown = testId;
  }

  renderPeaks(structure) {
    const table = $("t-eq-peaks");
    const tbody = table.querySelector("tbody");
    tbody.innerHTML = "";
    const peaks = structure && structure.peaks;
    table.classList.toggle("hidden", !peaks);
    if (!peaks) return;
    for (const [name, p] of Object.entries(peaks)) {
      const [words, quantity] = channelWords(name);
      const diff = num(p.rths) && num(p.reference) && p.reference !== 0
        ? `${((100 * (p.rths - p.reference)) / Math.abs(p.reference)).toFixed(2)} %` : "-";
      tbody.append(el("tr", {}, el("td", { text: words }), el("td", { class: "num", text: fmtChannel(quantity, p.rths) }),
        el("td", { class: "num", text: fmtChannel(quantity, p.reference) }), el("td", { class: "num", text: diff })));
    }
  }

  renderPlot(series, hybrid) {
    if (this.plot) this.plot.destroy();
    if (this.errPlot) this.errPlot.destroy();
    const L = unit("length");
    const defs = hybrid
      ? [{ label: "reference base displacement (full-numerical)", stroke: "rgba(170, 184, 198, 0.6)", width: 5 },
        { label: "command r (the hybrid test's base)", stroke: "#f4f6f8", width: 1, dash: [2, 3] },
        { label: "measured y", stroke: "#4aa3ff", width: 1.5 }]
      : [{ label: "target r", stroke: "rgba(170, 184, 198, 0.6)", width: 5 },
        { label: "measured y", stroke: "#4aa3ff", width: 1.5 }];
    this.plot = new TimePlot($("t-eq-plot"), { yLabel: `displacement (${L})`, minSpan: toDisplay("length", 1e-3), series: defs });
    const xs = Float64Array.from(series.time_s);
    const disp = (a) => Float64Array.from(a, (v) => (num(v) ? toDisplay("length", v) : NaN));
    const ys = [];
    if (hybrid && series.reference) {
      ys.push(disp(resampleOnto(series.reference.time_s, series.reference.base_displacement_m, xs)));
    } else if (hybrid) {
      ys.push(new Float64Array(xs.length).fill(NaN));
    }
    ys.push(disp(series.target_m), disp(series.displacement_m));
    this.plot.update(xs, ys, 0, xs.length, xs[0], xs[xs.length - 1]);
    // the differences, which the overlay cannot show at this scale
    const diff = (a, b) => Float64Array.from(a, (v, i) => v - b[i]);
    const errDefs = [{ label: "y - r", stroke: "#ff4d4f", width: 1.5, legend: true }];
    const errs = [diff(ys[ys.length - 1], ys[ys.length - 2])];
    if (hybrid) {
      errDefs.push({ label: "r - reference (base displacement)", stroke: "#f0b429", width: 1.5 });
      errs.push(diff(ys[1], ys[0]));
    }
    this.errPlot = new TimePlot($("t-eq-err"), { yLabel: `difference (${L})`, minSpan: toDisplay("length", 1e-4),
      series: errDefs, height: 200 });
    this.errPlot.update(xs, errs, 0, xs.length, xs[0], xs[xs.length - 1]);
  }

  /** What the plot shows, for tests. */
  describe() {
    return this.plot ? { ...this.plot.describe(), difference: this.errPlot.describe() } : null;
  }
}
