// Start and Stop: the confirmation of a start (the service's figures of the motion, the warnings that need a
// tick, the limits), the start itself (created and started in one request) and its refusals, and Stop.

import { api, ApiError, errorField, operatorPost } from "./api.js";
import { confirmDialog, summaryTable } from "./dialogs.js";
import { actionName, actionOf, LIMITS, limitValue } from "./limits.js";
import { checkKey } from "./setupcheck.js";
import { BAR, implausible, listOf } from "./setupfields.js";
import { changed, isMove, state } from "./state.js";
import { el, fmtDuration } from "./ui.js";
import { fmtU } from "./units.js";

const $ = (id) => document.getElementById(id);
const num = (v) => typeof v === "number" && Number.isFinite(v);
/** The force the actuator gives both ways at the check's pressure (a sine needs it both ways): the smaller of its
 * push (A_p P_s) and its pull (A_B P_s: a single-rod actuator's rod side); undefined without the check's figures. */
const bothWays = (d) => (d && num(d.max_force_n)
  ? (num(d.max_pull_force_n) ? Math.min(d.max_force_n, d.max_pull_force_n) : d.max_force_n) : undefined);

export class StartPart {
  /**
   * What the motion asks of the rig (SI): the service's figures from the envelope check of exactly this set-up
   * (peak displacement, velocity, force estimate, duration, cycles). If the service gave none, displacement,
   * velocity and duration are worked out here from the motion (a sine, or a protocol as listed), and the force
   * is not estimated: `source` says which.
   */
  figures(body) {
    const d = this.lastCheck.key === checkKey(body) ? this.lastCheck.data || {} : {};
    if (num(d.peak_displacement_m) && num(d.peak_velocity_m_per_s) && num(d.duration_s)) {
      return { source: "service", d: d.peak_displacement_m, v: d.peak_velocity_m_per_s,
        f: num(d.peak_force_n) ? d.peak_force_n : null, duration: d.duration_s, cycles: d.cycles_total };
    }
    const p = body.profile;
    if (p.kind === "sine") {
      return { source: "console", d: Math.abs(p.offset_m || 0) + p.amplitude_m, v: 2 * Math.PI * p.frequency_hz * p.amplitude_m,
        f: null, duration: p.cycles / p.frequency_hz, cycles: p.cycles };
    }
    const listed = this.scaledProtocol();
    if (listed && num(listed.duration_s)) {
      return { source: "console", d: listed.peak_displacement_m, v: listed.peak_velocity_m_per_s, f: null,
        duration: listed.duration_s, cycles: listed.cycles_total };
    }
    return null;
  }

  /** Values that are valid but look like unit mistakes or certain trips: each needs an explicit tick. */
  warnings(body, m) {
    const out = [...this.eq.warnings(body)];
    // the check's own (a limit the first cycle is expected to trip, simulated on the rig model in the check pool)
    const checked = this.lastCheck.key === checkKey(body) ? this.lastCheck.data || {} : {};
    for (const w of checked.warnings || []) out.push(w);
    if (num(body.vertical_load_n)) {
      const w = implausible("vertical_load", body.vertical_load_n);
      if (w) out.push(w);
    }
    const lim = { ...((this.rig && this.rig.limits_default) || {}), ...(body.limits || {}) };
    const outcome = (key) => `the test will trip (${actionName(actionOf(lim, key))})`;
    const trips = (key) => actionOf(lim, key) !== "indicate"; // an indicating limit is warned about below
    if (m) {
      if (num(lim.displacement_m) && m.d >= lim.displacement_m && trips("displacement_m")) {
        out.push(`the peak displacement ${fmtU("length", m.d)} reaches the displacement limit of ` +
          `${fmtU("length", lim.displacement_m)}: ${outcome("displacement_m")}`);
      }
      if (num(lim.velocity_m_per_s) && m.v >= lim.velocity_m_per_s && trips("velocity_m_per_s")) {
        out.push(`the peak velocity ${fmtU("velocity", m.v)} reaches the velocity limit of ` +
          `${fmtU("velocity", lim.velocity_m_per_s, { sig: 4 })}: ${outcome("velocity_m_per_s")}`);
      }
      if (num(m.f) && num(lim.force_n) && m.f >= lim.force_n && trips("force_n")) {
        out.push(`the estimated peak force ${fmtU("force", m.f, { sig: 3 })} is above the force limit of ` +
          `${fmtU("force", lim.force_n, { sig: 3 })}: ${outcome("force_n")} likely`);
      }
      const maxF = bothWays(this.lastCheck.data);
      if (num(m.f) && num(maxF) && m.f > 0.9 * maxF) {
        out.push(`the estimated peak force ${fmtU("force", m.f, { sig: 3 })} is near or above what the actuator gives each way at this pressure (${fmtU("force", maxF, { sig: 3 })})`);
      }
      if (m.d < 1e-4) out.push(`the amplitude ${fmtU("length", m.d)} is very small: entered in the wrong unit?`);
    }
    const onlyIndicate = LIMITS.filter((l) => actionOf(lim, l.key) === "indicate");
    if (onlyIndicate.length) {
      const reached = m ? onlyIndicate.filter((l) => ({ displacement_m: m.d, velocity_m_per_s: m.v, force_n: m.f })[l.key] >= lim[l.key]) : [];
      out.push(`${onlyIndicate.map((l) => limitValue(l, lim[l.key])).join(", ")} only ` +
        `indicate${onlyIndicate.length > 1 ? "" : "s"}: the test goes on beyond ${onlyIndicate.length > 1 ? "these limits" : "it"} ` +
        "(an event each time, nothing stops the rig there)" +
        (reached.length ? `; this motion exceeds ${reached.map((l) => l.short).join(", ")} every cycle` : ""));
    }
    return out;
  }

  summary(body, m) {
    const rows = [
      ["specimen", body.specimen_id, `operator ${body.operator_name}`],
      ["isolator", body.isolator, `controller ${body.controller}`],
    ];
    if (body.profile.kind === "sine") {
      const off = body.profile.offset_m;
      const from = num(body.profile.start_m) ? `the table's ${fmtU("length", body.profile.start_m, { sign: true })}` : "zero";
      rows.push(["motion", `sine ${fmtU("length", body.profile.amplitude_m)} at ${fmtU("frequency", body.profile.frequency_hz)}` +
        `${num(off) ? ` about ${fmtU("length", off, { sign: true })}` : ""}`,
        `${body.profile.cycles} cycles, ${body.profile.taper_cycles} taper` +
        `${num(off) ? (off === body.profile.start_m ? "; the target starts where the table rests"
          : `; the target starts at ${from} and reaches the offset during the first cycle`) : ""}`]);
    } else if (this.eq.kind()) {
      const check = this.lastCheck.key === checkKey(body) ? this.lastCheck.data : null;
      rows.push(...this.eq.summaryRows(body, check));
    } else {
      const p = this.scaledProtocol() || {};
      const dbd = (num(p.design_displacement_m) ? `, d_bd ${fmtU("length", p.design_displacement_m)} (${p.designFrom})` : "") +
        (p.frequencyFrom === "entered" ? `, at ${fmtU("frequency", p.frequency_hz)} (entered)` : "");
      rows.push(["motion", `protocol ${body.profile.name}${dbd}`, Array.isArray(p.levels)
        ? `${p.levels.length} levels: ${p.levels.map((l) => `${fmtU("length", l.amplitude_m)} at ${fmtU("frequency", l.frequency_hz)} x ${l.cycles}`).join(", ")}`
        : ""]);
    }
    if (m) {
      const maxF = bothWays(this.lastCheck.data);
      const by = m.source === "service" ? "" : " (worked out in this console from the motion: the service's check gave no figures)";
      const v = this.values || {};
      const about = this.isSine() && num(v.offset) && v.offset !== 0 && num(v.amplitude) ? v.offset : null;
      rows.push(about === null
        ? ["peak displacement", `\u00b1${fmtU("length", m.d)}`, `stroke \u00b1${fmtU("length", this.rig.envelope.stroke_m, { sig: 4 })}${by}`]
        : ["displacement range", `${fmtU("length", about - v.amplitude, { sign: true })} to ${fmtU("length", about + v.amplitude, { sign: true })}`,
          `the sine about ${fmtU("length", about, { sign: true })}; largest |r| ${fmtU("length", m.d)}; stroke \u00b1${fmtU("length", this.rig.envelope.stroke_m, { sig: 4 })}${by}`]);
      const eq = Boolean(this.eq.kind());
      if (eq) rows[rows.length - 1][2] = `the target's largest |r|, sample by sample (${rows[rows.length - 1][2]})`;
      rows.push(["peak velocity", fmtU("velocity", m.v), eq ? "the target's largest |r'|" : `2 pi f A${by}`]);
      rows.push(num(m.f)
        ? ["peak force (estimate)", `about ${fmtU("force", m.f, { sig: 3 })}`, "the service's upper estimate: isolator, " +
          "guide friction at the vertical load, viscous and inertia forces" +
          (num(maxF) ? `; the actuator gives ${fmtU("force", maxF, { sig: 3 })} each way at this pressure` : "")]
        : ["peak force (estimate)", "not available", "the service's check gave no force estimate"]);
      const wall = m.duration / (body.speed || 1);
      rows.push(["duration", fmtDuration(m.duration), `${num(m.cycles) && m.cycles > 0 ? `${m.cycles} cycles, ` : ""}` +
        (body.speed !== 1 ? `test time; ${fmtDuration(wall)} wall time at ${body.speed}x` : "real time")]);
    } else {
      rows.push(["peak figures", "not available", "the service gave none and this console cannot work them out"]);
    }
    const given = num(body.vertical_load_n);
    const load = given ? body.vertical_load_n : this.defaultVerticalLoad().value;
    rows.push(["supply / vertical load", `${fmtU("pressure", body.supply_bar * BAR)} / ${fmtU("force", load)}`,
      `vertical load: ${given ? "entered" : this.defaultVerticalLoad().source}`]);
    const box = el("div", {}, summaryTable(rows));
    box.append(this.limitsBox(body.limits));
    return box;
  }

  async start() {
    this.updateButtons();
    if ($("start").disabled) return;
    const { body, problems } = this.body();
    if (Object.keys(problems).length) return;
    const m = this.figures(body);
    const answer = await confirmDialog({
      title: "Start this test? The valve opens when you confirm.",
      body: this.summary(body, m),
      warnings: this.warnings(body, m),
      ok: "Start motion",
    });
    if (!answer) {
      this.message("Start cancelled: nothing was sent to the rig.", "");
      return;
    }
    if (this.startBlockers().length) { // the state changed while the dialog was open
      this.refuse("busy", `Not started: ${this.startBlockers().join("; ")}.`);
      return;
    }
    this.message("starting the test...");
    let record;
    try { // created and started in one request: a start the service refuses leaves no test behind
      record = await operatorPost("/api/tests?start=true", body);
    } catch (e) {
      if (e instanceof ApiError && e.status === 422) {
        this.showRefusal(e);
        this.refuse("envelope", `Refused by the service: ${e.message}`);
      } else if (e instanceof ApiError && e.status === 409) {
        // a test runs elsewhere, or the table rests off zero (a UDP rig's own reading at Start): nothing moved
        this.refuse(/table is at/.test(e.message) ? "position" : "busy", `Not started, refused by the service: ${e.message}`);
      } else if (e instanceof ApiError && (e.status === 401 || e.status === 0)) {
        this.refuse("form", `Not started: ${e.message}`);
      } else {
        this.refuse("form", `Refused: ${e.message}`);
      }
      return;
    }
    try { localStorage.setItem("isorig.operator_name", body.operator_name); } catch { /* fine */ }
    this.startedId = record.id;
    this.message(`Test #${record.id} started.`, "ok");
    state.stopping = false;
    location.hash = "#/live";
  }

  /** A refusal of the service (422 at Start) shown where the envelope is explained. */
  showRefusal(e) {
    this.checkSeq++; // a pending check must not overwrite it
    clearTimeout(this.checkTimer);
    this.checkPending = false;
    const box = $("envelope");
    box.innerHTML = "";
    box.className = "envelope refused";
    box.dataset.state = "refused";
    box.append(el("div", { text: `Refused by the service: ${e.message}` }));
    this.lastCheck = { ok: false, key: this.lastCheck.key, message: e.message };
    this.markField(errorField(e.detail));
    this.updateButtons();
  }

  async stop() {
    const id = await runningTestId(this.live);
    if (id === null) {
      this.refuse("busy", "No test is running.");
      return;
    }
    try {
      await api.endTest(`/api/tests/${id}/stop`);
      state.stopping = true;
      state.stoppingReason = state.stoppingReason || "stop requested from this console";
      changed("stopping");
      this.message(isMove(state.test) && state.testId === id
        ? `Manual move #${id}: stopping, the table holds where it is.`
        : `Test #${id}: stopping with a ramp-out from the next whole cycle.`, "ok");
      this.live.refreshEvents(id);
    } catch (e) {
      this.refuse("form", `Stop refused: ${e.message}`);
    }
  }
}

/** The id of the test the rig runs now: from the live stream, else asked from the API. */
export async function runningTestId(live) {
  if (live && live.testId !== null && live.status === "running") return live.testId;
  try {
    const list = listOf(await api.get("/api/tests?status=running"), "tests");
    if (list.length) return list[0].id;
  } catch { /* fall through */ }
  return null;
}
