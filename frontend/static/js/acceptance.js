// A protocol test's page: its acceptance verdict (PASSED, FAILED, INCOMPLETE, NO VERDICT), the failing rules with
// their cycles, the rules, and each level's figures over its steady cycles (GET /api/tests/{id}/acceptance: the
// report's acceptance page, sim.protocols.evaluate_acceptance). A mean over all the levels of a protocol mixes
// amplitudes and says nothing, so the page shows the levels instead.

import { el } from "./ui.js";
import { fmtU } from "./units.js";

const $ = (id) => document.getElementById(id);
const num = (v) => typeof v === "number" && Number.isFinite(v);

export const VERDICT_CLASS = { PASSED: "met", FAILED: "unmet", INCOMPLETE: "warn", "NO VERDICT": "" };

/** Is test `t` a protocol test? */
export function isProtocol(t) {
  const p = t && (t.profile || (t.scenario && t.scenario.profile) || (t.request && t.request.profile));
  return Boolean(p && !Array.isArray(p) && p.kind === "protocol");
}

export class ProtocolAcceptance {
  hide() {
    this.wanted = null;
    $("t-acc").classList.add("hidden");
  }

  /** Show test `t`'s acceptance if it ran a protocol; else hide the panel. */
  async show(t) {
    this.wanted = t && t.id; // a late answer for another test (the page moved on) is dropped
    if (!isProtocol(t) || t.status === "ready") {
      this.hide();
      return;
    }
    let data = null;
    let why = "";
    try {
      const res = await fetch(`/api/tests/${t.id}/acceptance`);
      data = res.ok ? await res.json() : null;
      if (!res.ok) why = `HTTP ${res.status}`;
    } catch (e) {
      why = e.message;
    }
    if (this.wanted !== t.id) return;
    $("t-acc").classList.remove("hidden");
    if (!data) {
      $("t-acc-verdict").textContent = "not available";
      $("t-acc-verdict").className = "pill";
      $("t-acc-note").textContent = `the acceptance could not be loaded (${why})`;
      return;
    }
    this.render(data);
  }

  render(d) {
    const s = d.summary || {};
    $("t-acc-title").textContent = `Acceptance: ${d.title || `protocol ${d.protocol}`}`;
    const verdict = $("t-acc-verdict");
    verdict.textContent = d.verdict;
    verdict.className = `pill big ${VERDICT_CLASS[d.verdict] || ""}`;
    const missing = num(d.checks_missing) && d.checks_missing > 0 ? `, ${d.checks_missing} without a measured cycle` : "";
    $("t-acc-note").textContent = `${s.verdicts} checks on ${d.judged_on || "the steady cycles"}, ${s.failed} failed${missing}`;
    const failed = $("t-acc-failed");
    failed.innerHTML = "";
    for (const r of s.failed_rules || []) {
      failed.append(el("li", { text: `${r.rule}: ${r.failures} failure(s), cycle(s) ${r.cycles.join(", ")}; first: ${r.first}` }));
    }
    failed.classList.toggle("hidden", !(s.failed_rules || []).length);
    const rules = $("t-acc-rules");
    rules.innerHTML = "";
    for (const text of d.rules || []) rules.append(el("li", { text }));
    this.renderLevels(d.levels || []);
  }

  renderLevels(levels) {
    const tbody = $("t-acc-levels").querySelector("tbody");
    tbody.innerHTML = "";
    for (const lv of levels) {
      const m = lv.means || {};
      const cell = (quantity, key) => el("td", { class: "num", text: num(m[key]) ? fmtU(quantity, m[key]) : "-" });
      tbody.append(el("tr", {},
        el("td", { text: `${lv.level}${lv.label ? ` (${lv.label})` : ""}` }),
        el("td", { class: "num", text: fmtU("length", lv.amplitude_m) }),
        el("td", { class: "num", text: fmtU("frequency", lv.frequency_hz) }),
        el("td", { class: "num", text: String(lv.steady_cycles ?? "-") }),
        cell("stiffness", "k_eff_n_per_m"), cell("energy", "edc_j"), cell("percent", "xi_eff"), cell("force", "qd_n")));
    }
  }
}
