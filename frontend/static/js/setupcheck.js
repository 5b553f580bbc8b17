// The request of the set-up: the body of POST /api/tests from the form (SI units), and the envelope check of it
// (POST /api/tests/check at every change) with a refusal shown on its field.

import { account, api, ApiError, errorField } from "./api.js";
import { BAR } from "./setupfields.js";
import { el } from "./ui.js";
import { fmtU } from "./units.js";

const $ = (id) => document.getElementById(id);
const num = (v) => typeof v === "number" && Number.isFinite(v);

export class CheckPart {
  /** The request body of POST /api/tests from the form (SI units), or {problems}. */
  body() {
    const problems = this.readAll();
    const v = this.values;
    const p = this.protocol();
    const profile = this.eq.kind() ? this.eq.profile(v) : p ? this.protocolProfile(p, v) : {
      kind: "sine", amplitude_m: v.amplitude, frequency_hz: v.frequency, cycles: v.cycles, taper_cycles: v.taper_cycles,
    };
    if (this.isSine() && num(v.offset) && v.offset !== 0) profile.offset_m = v.offset;
    if (this.isSine() && profile.offset_m !== undefined && this.startPositionM() !== 0) {
      profile.start_m = this.offsetTakenM; // taken from the table: the test starts where the table rests
      profile.offset_m = this.offsetTakenM;
    }
    const body = {
      isolator: $("f-isolator").value,
      supply_bar: num(v.supply) ? v.supply / BAR : null,
      controller: $("f-controller").value,
      speed: this.realTimeOnly ? 1 : v.speed,
      profile,
      specimen_id: $("f-specimen_id").value.trim(),
      operator_name: account.name || "", // the logged-in account (the service records it in any case)
      notes: $("f-notes").value.trim(),
      label: $("f-label").value.trim(),
    };
    if (num(v.vertical_load)) body.vertical_load_n = v.vertical_load;
    const options = this.controllerOptions();
    if (Object.keys(options).length) body.controller_options = options;
    const limits = {};
    for (const [key, spec] of Object.entries(this.fields)) {
      if (spec.limit && num(v[key])) limits[spec.limit] = v[key];
    }
    body.limits = { ...limits, actions: this.actions() }; // every action said, the defaults too
    return { body, problems };
  }

  /** The set-up values a manual move needs that are not valid now (names), [] when all are. */
  moveProblems() {
    const v = this.values;
    const out = [];
    if (!$("f-isolator").value) out.push("isolator");
    if (!num(v.supply)) out.push("supply pressure");
    if (v.vertical_load === undefined) out.push("vertical load");
    for (const [key, spec] of Object.entries(this.fields)) {
      if (spec.limit && v[key] === undefined) out.push(key.replace(/^lim_/, "limit "));
    }
    return out;
  }

  scheduleCheck(delay = 250) {
    clearTimeout(this.checkTimer);
    this.checkPending = true;
    $("envelope").dataset.state = "checking"; // the answer on show is for the form as it was, until the new one
    this.checkTimer = setTimeout(() => this.check(), delay);
  }

  /** Ask the API whether the current choice fits the rig, and explain a refusal before Start. */
  async check() {
    const seq = ++this.checkSeq;
    const box = $("envelope");
    box.dataset.state = "checking";
    const { body, problems } = this.body();
    const key = checkKey(body);
    const firstProblem = Object.entries(problems)[0];
    let result;
    if (firstProblem) {
      result = { ok: false, local: true, key, message: `${firstProblem[0].replace(/_/g, " ")}: ${firstProblem[1]}` };
    } else {
      try {
        const data = await api.postQuiet("/api/tests/check", body);
        result = { ok: data.ok !== false, key, data, message: data.detail, field: data.field };
      } catch (e) {
        if (e instanceof ApiError && e.status === 422) {
          result = { ok: false, key, message: e.message, field: errorField(e.detail), data: e.detail };
        } else if (e instanceof ApiError && e.status === 503) { // the service's check pool is busy: ask again
          if (seq === this.checkSeq) { // asked again with the form as it is then, after the answer's Retry-After
            box.className = "envelope";
            box.textContent = `Checking: the service is busy with other checks; asking again in ${e.retryAfterS} s ...`;
            this.scheduleCheck(e.retryAfterS * 1000);
          }
          return;
        } else {
          result = { ok: null, key, message: `envelope check not available (${e.message})` };
        }
      }
    }
    if (seq !== this.checkSeq) return; // a newer check is on its way
    this.checkPending = false;
    this.lastCheck = result;
    const d = result.data || {};
    const limits = [];
    if (num(d.max_force_n)) {
      const pull = num(d.max_pull_force_n) && d.max_pull_force_n < d.max_force_n
        ? ` pushing, ${fmtU("force", d.max_pull_force_n, { sig: 3 })} pulling (its rod side)` : "";
      limits.push(`actuator force up to ${fmtU("force", d.max_force_n, { sig: 3 })}${pull} at this pressure`);
    }
    if (result.ok === false && num(d.max_amplitude_m)) limits.push(`amplitude up to ${fmtU("length", d.max_amplitude_m)} at this frequency`);
    if (result.ok === false && num(d.max_frequency_hz)) limits.push(`frequency up to ${fmtU("frequency", d.max_frequency_hz, { sig: 3 })} at this amplitude`);
    box.innerHTML = "";
    if (result.ok === false) {
      box.className = "envelope refused";
      let text = result.message || "outside the rig envelope";
      if (d.limit && !text.includes(String(d.limit))) text += ` (limit: ${d.limit})`;
      box.append(el("div", { text: `${result.local ? "Not valid" : "Refused"}: ${text}` }));
      this.markField(result.field || d.field);
    } else if (result.ok === true) {
      box.className = "envelope ok";
      box.append(el("div", { text: "Within the rig envelope." }));
      for (const w of d.warnings || []) box.append(el("div", { class: "warn", text: `Warning: ${w}` }));
      this.markField("");
      if (this.refusal && this.refusal.cause === "envelope") this.clearRefusal();
    } else {
      box.className = "envelope";
      box.append(el("div", { text: result.message }));
    }
    if (limits.length) box.append(el("div", { class: "muted", text: `Rig: ${limits.join("; ")}.` }));
    box.dataset.state = result.ok === false ? "refused" : result.ok ? "ok" : "unknown";
    this.renderFieldMeta();
    this.updateButtons();
  }

  markField(field) {
    document.querySelectorAll("#setup-fields .service-invalid").forEach((x) => x.classList.remove("service-invalid", "invalid"));
    const key = field ? String(field).split(".").pop() : "";
    const map = { supply_bar: "f-supply", vertical_load_n: "f-vertical_load", amplitude_m: "f-amplitude",
      frequency_hz: "f-frequency", cycles: "f-cycles", taper_cycles: "f-taper_cycles", speed: "f-speed",
      isolator: "f-isolator", controller: "f-controller", displacement_m: "f-lim_displacement",
      force_n: "f-lim_force", tracking_error_m: "f-lim_tracking", load_pressure_pa: "f-lim_pressure",
      velocity_m_per_s: "f-lim_velocity", name: "f-profile", profile: "f-profile" };
    const target = this.eq.fieldInput(field) ||
      (/(^|\.)actions\./.test(String(field)) ? this.actionSelect(key) : $(map[key]));
    if (target) target.classList.add("invalid", "service-invalid");
  }
}

/** The part of the body the envelope depends on (who and notes are not checked against the rig). */
export function checkKey(body) {
  const { specimen_id: _s, operator_name: _o, notes: _n, label: _l, ...rest } = body;
  return JSON.stringify(rest, (k, v) => (Array.isArray(v) && v.length > 64 ? `[record ${recordId(v)}]` : v));
}

const RECORD_IDS = new WeakMap(); // an inline record (array) of a file read: one id per array, for checkKey
let recordSeq = 0;
function recordId(array) {
  if (!RECORD_IDS.has(array)) RECORD_IDS.set(array, ++recordSeq);
  return RECORD_IDS.get(array);
}
