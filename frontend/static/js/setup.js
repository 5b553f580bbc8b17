// Set-up panel: who and what (specimen, operator, notes), the isolator (its parameters, add one, delete a user
// one), conditions, the motion (sine or a shipped protocol, GET /api/protocols), the controller and its
// options, the limits each with its action (js/limits.js), and the rig envelope for the current choice (asked
// from the API at every change). Numbers are typed as text and parsed explicitly (js/parse.js) in the
// console's units (js/units.js); every field shows its unit and range. Start is enabled only when a start can
// succeed (a UDP rig's table must rest at zero) and asks for a confirmation with the service's figures of the
// motion. While a test runs the form shows that test (locked), also after a reload or in a second browser.
// Manual motion (js/manual.js) lives in this panel too: it moves the table with the set-up's conditions and
// limits, and a sine's offset can be taken from where the table rests.

import { account, api, ApiError, errorField, operatorPost } from "./api.js";
import { confirmDialog, summaryTable } from "./dialogs.js";
import { EarthquakeForm, G } from "./earthquake.js";
import { actionHelp, actionName, actionOf, ACTION_ORDER, DEFAULT_ACTION, LIMITS, limitValue, setActionHelp } from "./limits.js";
import { ManualMotion } from "./manual.js";
import { parseNumber } from "./parse.js";
import { fmtPeriod, rigKind } from "./rig.js";
import { changed, isCommissioning, isMove, onState, runName, sourceWords, state, tablePosition, testRunning } from "./state.js";
import { el, fmtDuration, showAlert } from "./ui.js";
import { fmt, fmtU, inputText, onUnits, sigDigits, toDisplay, toSI, unit } from "./units.js";
import { bindAccountField } from "./who.js";

const $ = (id) => document.getElementById(id);
const num = (v) => typeof v === "number" && Number.isFinite(v);
const DRAFT_KEY = "isorig.setup_draft";
const BAR = 1e5;
const START_TOLERANCE_M = 0.002; // the table must rest this close to zero for a start (the service's default)

// Isolator parameters: key, label, quantity
const ISO_PARAMS = [
  ["rho_bw_per_m", "rho_BW", "inverse_length"],
  ["sigma_bw", "sigma_BW", "ratio"],
  ["n", "n", "ratio"],
  ["kd_n_per_m", "k_d", "stiffness"],
  ["kw_n", "k_w", "force"],
];
// What isolators usually are (SI): a value ten times outside this asks for a confirmation (a unit mistake
// such as kN entered where N is asked is a factor of a thousand).
const USUAL = {
  kd_n_per_m: [1e5, 2e7, "post-yield stiffness"],
  kw_n: [1e3, 5e5, "hysteretic force"],
  rho_bw_per_m: [10, 1e3, "rho_BW"],
  vertical_load: [1e4, 2e6, "vertical load"],
};

function capitalize(text) {
  return text ? text[0].toUpperCase() + text.slice(1) : text;
}

function listOf(data, key) {
  if (Array.isArray(data)) return data;
  if (data && Array.isArray(data[key])) return data[key];
  return [];
}

/** "10 to 210 bar", "up to 150 mm": a range in display units. */
function rangeText(quantity, lo, hi, { openLow = false, integer = false } = {}) {
  const f = (v) => (integer ? String(v) : quantity ? fmt(quantity, v, { sig: 6 }) : String(+v.toPrecision(6)));
  const u = quantity && unit(quantity) !== "-" ? ` ${unit(quantity)}` : "";
  if (openLow && lo === 0) return `above 0, up to ${f(hi)}${u}`;
  return `${f(lo)} to ${f(hi)}${u}`;
}

/** A value ten times or more outside the usual range: the warning text, else "". */
function implausible(key, si) {
  const u = USUAL[key];
  if (!u || !num(si) || si === 0) return "";
  const [lo, hi, name] = u;
  const q = key === "vertical_load" || key === "kw_n" ? "force" : key === "kd_n_per_m" ? "stiffness" : "inverse_length";
  const usual = `${fmt(q, lo, { sig: 3 })} to ${fmtU(q, hi, { sig: 3 })}`;
  if (si < lo / 10) {
    return `${name} ${fmtU(q, si, { sig: 4 })} is ${sigDigits(lo / si, 2)} times below the usual ${usual}: ` +
      "entered in the wrong unit?";
  }
  if (si > hi * 10) {
    return `${name} ${fmtU(q, si, { sig: 4 })} is ${sigDigits(si / hi, 2)} times above the usual ${usual}: ` +
      "entered in the wrong unit?";
  }
  return "";
}

export class SetupPanel {
  constructor({ live }) {
    this.live = live;
    this.isolators = [];
    this.rig = null;
    this.protocols = []; // GET /api/protocols: [{name, title, description, levels, duration_s, ...}]
    this.protocolError = "";
    this.offsetTakenM = null; // the sine's offset taken from the table: the test starts there (start_m)
    this.checkSeq = 0;
    this.checkTimer = null;
    this.lastCheck = { ok: null, key: "", data: null };
    this.values = {}; // field key -> SI value (null: empty, undefined: not a valid number)
    this.refusal = null; // {cause, text}: a refused action, cleared when its cause is gone
    this.locked = false;
    this.lockedTestId = null;
    this.eq = new EarthquakeForm(this); // time history and hybrid simulation (js/earthquake.js)
    this.fields = { ...this.fieldSpecs(), ...this.eq.fieldSpecs() };
    this.manual = new ManualMotion(this);
  }

  // ------------------------------------------------------------------------------------------ fields

  /** Every numeric field: input id, quantity (display unit), range in SI, required or default. */
  fieldSpecs() {
    const env = () => (this.rig && this.rig.envelope) || {};
    const max = () => (this.rig && this.rig.limits_max) || {};
    const def = () => (this.rig && this.rig.limits_default) || {};
    return {
      supply: { id: "f-supply", quantity: "pressure", required: true,
        range: () => [(env().supply_bar_min ?? 10) * BAR, (env().supply_bar_max ?? 210) * BAR] },
      speed: { id: "f-speed", quantity: null, required: true, openLow: true, range: () => [0, env().max_speed ?? 100] },
      vertical_load: { id: "f-vertical_load", quantity: "force", required: false,
        range: () => [0, env().max_vertical_load_n ?? 850e3], usual: "vertical_load" },
      amplitude: { id: "f-amplitude", quantity: "length", required: true, sine: true, openLow: true,
        range: () => [0, env().stroke_m ?? 0.15] },
      frequency: { id: "f-frequency", quantity: "frequency", required: true, sine: true, openLow: true,
        range: () => [0, env().max_frequency_hz ?? 10] },
      cycles: { id: "f-cycles", quantity: null, integer: true, required: true, sine: true,
        range: () => [1, env().max_cycles ?? 100000] },
      taper_cycles: { id: "f-taper_cycles", quantity: null, integer: true, required: true, sine: true,
        // no number of cycles yet (or a wrong one): the taper is not judged against it
        range: () => [0, Math.floor((num(this.values.cycles) ? this.values.cycles : env().max_cycles ?? 100000) / 2)] },
      offset: { id: "f-offset", quantity: "length", required: false, sine: true,
        range: () => [-(env().stroke_m ?? 0.15), env().stroke_m ?? 0.15] },
      lim_displacement: { id: "f-lim_displacement", quantity: "length", required: false, openLow: true, limit: "displacement_m",
        range: () => [0, max().displacement_m ?? 0.15], placeholder: () => def().displacement_m },
      lim_force: { id: "f-lim_force", quantity: "force", required: false, openLow: true, limit: "force_n",
        range: () => [0, max().force_n ?? 280e3], placeholder: () => def().force_n },
      lim_velocity: { id: "f-lim_velocity", quantity: "velocity", required: false, openLow: true, limit: "velocity_m_per_s",
        range: () => [0, max().velocity_m_per_s ?? 0.39], placeholder: () => def().velocity_m_per_s },
      lim_tracking: { id: "f-lim_tracking", quantity: "length", required: false, openLow: true, limit: "tracking_error_m",
        range: () => [0, max().tracking_error_m ?? 0.3], placeholder: () => def().tracking_error_m },
      lim_pressure: { id: "f-lim_pressure", quantity: "pressure", required: false, openLow: true, limit: "load_pressure_pa",
        range: () => [0, max().load_pressure_pa ?? 210e5], placeholder: () => def().load_pressure_pa },
    };
  }

  isSine() {
    return $("f-profile").value === "sine";
  }

  /** Does a field apply to the motion chosen (a sine's fields to a sine, a hybrid test's to a hybrid test)? */
  applies(spec) {
    if (spec.sine) return this.isSine();
    return spec.when ? spec.when() : true;
  }

  /** Parse one field: updates this.values[key] and its message; returns the problem text or "". */
  readField(key) {
    const spec = this.fields[key];
    const input = $(spec.id);
    const label = input.closest(".field");
    const msg = label && label.querySelector(".msg");
    const r = parseNumber(input.value, { integer: spec.integer });
    let problem = "";
    let note = "";
    let si;
    if (r.empty) {
      si = null;
      if (spec.required && this.applies(spec)) problem = "required";
    } else if (!r.ok) {
      si = undefined;
      problem = r.error;
    } else {
      si = spec.quantity ? toSI(spec.quantity, r.value) : r.value;
      const [lo, hi] = spec.range();
      const tooLow = spec.openLow ? si <= lo : si < lo - 1e-12 * Math.abs(lo);
      if (tooLow || si > hi * (1 + 1e-12)) {
        problem = `outside the allowed range: ${rangeText(spec.quantity, lo, hi, spec)}`;
      } else if (r.comma) {
        note = `read as ${spec.quantity ? fmtU(spec.quantity, si, { sig: 8 }) : String(r.value)}`;
      }
      if (!problem && spec.usual) note = implausible(spec.usual, si) || note;
    }
    this.values[key] = problem && si !== null ? undefined : si;
    if (msg) {
      msg.textContent = problem && problem !== "required" ? problem : problem === "required" ? "required" : note;
      msg.className = `msg${problem ? " bad" : note && !note.startsWith("read as") ? " warn" : note ? " info" : ""}`;
    }
    input.classList.toggle("invalid", (Boolean(problem) && !(problem === "required" && r.empty && !input.dataset.touched)) ||
      input.classList.contains("service-invalid"));
    return problem;
  }

  /** Units and ranges of every field (at start, when the units or the rig answer change). */
  renderFieldMeta() {
    for (const [key, spec] of Object.entries(this.fields)) {
      const input = $(spec.id);
      const label = input.closest(".field");
      if (!label) continue;
      const u = label.querySelector(".unit");
      if (u && spec.quantity) u.textContent = `(${unit(spec.quantity)})`;
      const range = label.querySelector(".range");
      const [lo, hi] = spec.range();
      let text = rangeText(spec.quantity, lo, hi, spec);
      if (key === "amplitude" && this.lastCheck.data && num(this.lastCheck.data.max_amplitude_m)) {
        text = `up to ${fmtU("length", hi, { sig: 4 })} (stroke); at this frequency up to ${fmtU("length", this.lastCheck.data.max_amplitude_m, { sig: 4 })}`;
      }
      if (key === "frequency" && this.lastCheck.data && num(this.lastCheck.data.max_frequency_hz)) {
        text += `; at this amplitude up to ${fmtU("frequency", this.lastCheck.data.max_frequency_hz, { sig: 3 })}`;
      } else if (key === "frequency" && this.lastCheck.data && this.lastCheck.data.max_frequency_hz === null &&
        num(this.lastCheck.data.max_amplitude_m)) {
        text += "; no frequency fits this amplitude (lower the amplitude)";
      }
      if (key === "taper_cycles") text += " (at most half the cycles)";
      if (key === "offset") text += "; empty: 0 (the sine runs about zero); reached during the first cycle";
      if (key === "speed" && this.realTimeOnly) text = "";
      if (key === "eq_scale") {
        text = this.eq.fromGroundMotion() ? `${text} (times the ground acceleration)` : `${text} (times the displacement)`;
      }
      if (spec.quantity === "mass" || (spec.storey !== undefined && spec.quantity === "stiffness")) {
        const shown = toDisplay(spec.quantity, hi);
        text = `above 0, at most ${shown >= 1e5 ? shown.toExponential(0).replace("+", "") : fmt(spec.quantity, hi)} ${unit(spec.quantity)}`;
      }
      if (key === "eq_mass") {
        const load = num(this.values.vertical_load) ? this.values.vertical_load : this.defaultVerticalLoad().value;
        text += `; empty: the vertical load / g = ${fmtU("mass", load / G)}`;
      }
      if (spec.when && !spec.limit && spec.placeholder) {
        input.placeholder = fmt(spec.quantity, spec.placeholder(), { sig: 6 });
        text += `; empty: ${fmtU(spec.quantity, spec.placeholder(), { sig: 6 })}`;
      }
      if (key === "vertical_load") {
        const d = this.defaultVerticalLoad();
        text += `; empty: ${fmtU("force", d.value, { sig: 6 })}${d.iso ? " (the isolator's design load)" : d.building ? " (the building's weight)" : ""}`;
        input.placeholder = fmt("force", d.value, { sig: 6 });
      }
      if (spec.limit) {
        const p = spec.placeholder();
        if (num(p)) input.placeholder = fmt(spec.quantity, p, { sig: 6 });
        text += num(p) ? `; empty: ${fmtU(spec.quantity, p, { sig: 6 })}` : "";
      }
      if (range) range.textContent = text;
    }
    for (const [key, , quantity] of ISO_PARAMS) {
      const label = $(`iso-${key}`).closest(".field");
      label.querySelector(".unit").textContent = `(${unit(quantity)})`;
      const usual = USUAL[key];
      label.querySelector(".range").textContent = usual
        ? `usually ${fmt(quantity, usual[0], { sig: 3 })} to ${fmtU(quantity, usual[1], { sig: 3 })}` : "";
    }
  }

  defaultVerticalLoad() {
    const env = (this.rig && this.rig.envelope) || {};
    const building = this.eq.totalMass(this.values); // a hybrid test runs under the building's weight
    if (num(building)) return { value: building * G, building: true };
    const iso = this.isolators.find((i) => i.name === $("f-isolator").value) || {};
    if (num(iso.design_vertical_load_n)) return { value: iso.design_vertical_load_n, iso: true };
    return { value: num(env.vertical_load_n_default) ? env.vertical_load_n_default : 125e3, iso: false };
  }

  /** Put an SI value into a field, in the display unit. */
  setField(key, si) {
    const spec = this.fields[key];
    $(spec.id).value = si === null || si === undefined ? "" : spec.quantity ? inputText(spec.quantity, si) : String(si);
  }

  /** The units changed: every valid value is shown again in the new unit (the SI value is kept). */
  onUnitsChanged() {
    for (const [key, si] of Object.entries(this.values)) {
      if (num(si) && this.fields[key] && this.fields[key].quantity) this.setField(key, si);
    }
    for (const [key, , quantity] of ISO_PARAMS) {
      const input = $(`iso-${key}`);
      const si = Number(input.dataset.si);
      if (input.value.trim() && input.dataset.si !== undefined && num(si)) input.value = inputText(quantity, si);
    }
    this.renderFieldMeta();
    this.showIsolator();
    this.readAll();
    this.check();
  }

  readAll() {
    const problems = {};
    for (const key of Object.keys(this.fields)) {
      const p = this.readField(key);
      if (p && this.applies(this.fields[key])) problems[key] = p;
    }
    Object.assign(problems, this.eq.problems()); // a record file that could not be read, its unit
    for (const input of document.querySelectorAll("#controller-options-fields input[data-option]")) {
      const p = this.readOption(input);
      if (p) problems[`option ${input.dataset.option}`] = p;
    }
    return problems;
  }

  // ------------------------------------------------------------------------------------------ init

  async init() {
    bindAccountField($("f-operator_name"));
    await Promise.all([this.loadRig(), this.loadIsolators(), this.loadProtocols(), this.eq.loadPresets()]);
    this.eq.init();
    this.renderFieldMeta();
    this.restoreDraft();
    this.readAll();
    this.saveDraft(); // this operator's set-up (the defaults at first), where a test run elsewhere returns to
    const form = $("setup-form");
    form.addEventListener("input", (ev) => {
      if (ev.target.closest("#iso-form")) {
        this.readIsoField(ev.target);
        return;
      }
      if (ev.target.closest("#manual-motion")) return; // js/manual.js
      if (ev.target.id === "f-offset") {
        $("offset-note").textContent = "";
        this.offsetTakenM = null; // a typed offset is reached from zero
      }
      ev.target.dataset.touched = "1";
      this.formChanged();
    });
    form.addEventListener("change", (ev) => {
      if (ev.target.closest("#iso-form") || ev.target.closest("#manual-motion")) return;
      if (ev.target.id === "f-isolator") this.showIsolator();
      if (ev.target.id === "f-profile") this.showProfile();
      if (["f-eq_source", "f-eq_acc_unit", "f-eq_preset"].includes(ev.target.id)) this.eq.show();
      if (ev.target.type === "file") return; // read first (js/earthquake.js), then formChanged
      if (ev.target.id === "f-controller") this.showControllerOptions();
      if (ev.target.dataset.limit) this.showActionHelp();
      this.formChanged();
    });
    form.addEventListener("submit", (ev) => {
      ev.preventDefault();
      this.start();
    });
    $("stop").addEventListener("click", () => this.stop());
    $("offset-from-table").addEventListener("click", () => this.offsetFromTable());
    $("iso-save").addEventListener("click", () => this.saveIsolator());
    $("iso-delete").addEventListener("click", () => this.deleteIsolator());
    onUnits(() => this.onUnitsChanged());
    onState((what) => this.onStateChanged(what));
    this.showActionHelp();
    this.showProfile();
    this.updateButtons();
    this.scheduleCheck(0);
    this.onStateChanged("test"); // a test the stream announced before this panel was ready
    this.manual.init();
  }

  formChanged() {
    if (this.refusal && this.refusal.cause === "form") this.clearRefusal();
    else if (!this.refusal) this.message("", ""); // "cancelled", "saved": said once, gone at the next change
    const { body, problems } = this.body();
    this.saveDraft();
    this.renderRigWarning(); // where the test starts follows the offset (taken from the table or typed)
    // a value that is not valid is said at once (no request); who and notes do not change the envelope; an
    // unchanged set-up is not asked again (a blur's change event)
    if (Object.keys(problems).length) {
      clearTimeout(this.checkTimer);
      this.check();
    } else if (this.checkPending || SetupPanel.checkKey(body) !== this.lastCheck.key) {
      this.scheduleCheck();
    }
    this.updateButtons();
    changed("form");
  }

  // ------------------------------------------------------------------------------------------ limit actions

  /** The action choices of every limit (GET /api/rig limit_actions; the default marked). */
  renderActions() {
    const rig = this.rig || {};
    setActionHelp(rig.limit_actions);
    const actions = rig.limit_actions ? ACTION_ORDER.filter((a) => a in rig.limit_actions) : ACTION_ORDER;
    const defaults = (rig.limits_default && rig.limits_default.actions) || {};
    for (const l of LIMITS) {
      const sel = this.actionSelect(l.key);
      const keep = sel.value;
      const def = defaults[l.key] || DEFAULT_ACTION;
      sel.innerHTML = "";
      for (const a of actions) sel.append(el("option", { value: a, text: actionName(a) }));
      sel.value = actions.includes(keep) ? keep : def;
      sel.dataset.default = def;
      sel.title = `default: ${actionName(def)}\n${actions.map((a) => `${actionName(a)}: ${actionHelp(a)}`).join("\n")}`;
    }
    // what each action does, in the service's words, once under the limits
    const help = $("limit-actions-help");
    help.innerHTML = "";
    for (const a of actions) {
      const def = a === DEFAULT_ACTION ? " (the default)" : "";
      help.append(el("div", { "data-action": a }, el("b", { text: `${actionName(a)}${def}` }), ` ${actionHelp(a)}`));
    }
  }

  actionSelect(key) {
    return document.querySelector(`select[data-limit="${key}"]`);
  }

  /** Each limit's action: {key: action} (SI keys of the service). */
  actions() {
    return Object.fromEntries(LIMITS.map((l) => [l.key, this.actionSelect(l.key).value || DEFAULT_ACTION]));
  }

  /** Each limit row says its action (an action other than the default is marked). */
  showActionHelp() {
    for (const l of LIMITS) {
      const sel = this.actionSelect(l.key);
      const row = sel.closest(".limit-row");
      row.dataset.action = sel.value;
      row.dataset.changed = sel.value !== (sel.dataset.default || DEFAULT_ACTION) ? "1" : "0";
    }
  }

  // ------------------------------------------------------------------------------------------ rig

  async loadRig() {
    try {
      this.rig = await api.get("/api/rig");
    } catch {
      this.rig = null;
    }
    state.rig = this.rig;
    const ctl = $("f-controller");
    const rig = this.rig || {};
    if (Array.isArray(rig.controllers)) this.live.setControllers(rig.controllers.filter((c) => typeof c === "object"));
    this.controllers = Array.isArray(rig.controllers) ? rig.controllers.filter((c) => typeof c === "object") : [];
    const names = rig.controllers ? rig.controllers.map((c) => (typeof c === "string" ? c : c.name)) : ["servo"];
    const def = rig.default_controller || names[0];
    ctl.innerHTML = "";
    for (const n of names) ctl.append(el("option", { value: n, text: n === def ? `${n} (default)` : n }));
    ctl.value = def;
    this.showControllerOptions();
    // a real rig runs in real time only: the speed is fixed at 1 (the API refuses any other with 422)
    this.realTimeOnly = rigKind(rig) !== "simulated";
    const speed = $("f-speed");
    speed.disabled = this.realTimeOnly;
    if (this.realTimeOnly) speed.value = "1";
    const note = $("speed-note");
    note.textContent = this.realTimeOnly ? "fixed: a real rig runs in real time" : "";
    note.classList.toggle("hidden", !this.realTimeOnly);
    $("speed-row").title = this.realTimeOnly
      ? `the rig ${rig.driver} runs in real time only: speed 1`
      : "simulated rig only: time scale of the run";
    this.renderActions();
    changed("rig");
  }

  /** The shipped protocols (GET /api/protocols): name, title, levels, peak motion, duration. */
  async loadProtocols() {
    try {
      const data = await api.get("/api/protocols");
      this.protocols = listOf(data, "protocols").filter((p) => p && p.name);
      this.protocolError = "";
    } catch (e) {
      this.protocols = [];
      this.protocolError = `the service lists no protocols (GET /api/protocols: ${e.message}); only a sine can be chosen`;
    }
    const sel = $("f-profile");
    const keep = sel.value;
    sel.innerHTML = "";
    sel.append(el("option", { value: "sine", text: "sine (amplitude, frequency, cycles)" }));
    for (const p of this.protocols) {
      const figures = [num(p.duration_s) ? fmtDuration(p.duration_s) : "", num(p.cycles_total) ? `${p.cycles_total} cycles` : ""];
      sel.append(el("option", { value: `protocol:${p.name}`,
        text: `protocol ${p.name} (${figures.filter(Boolean).join(", ") || "duration not given"})` }));
    }
    sel.append(el("option", { value: "history", text: "time history (earthquake: ground motion or displacement record)" }));
    sel.append(el("option", { value: "hybrid", text: "hybrid simulation (RTHS: a building on the isolator, a ground motion)" }));
    if ([...sel.options].some((o) => o.value === keep)) sel.value = keep;
    $("profile-note").textContent = this.protocolError;
  }

  protocol() {
    const v = $("f-profile").value;
    return v.startsWith("protocol:") ? this.protocols.find((p) => p.name === v.slice(9)) || { name: v.slice(9) } : null;
  }

  /** The chosen protocol: its title, what it is for, every level and the whole (duration, cycles, peaks). */
  showProfile() {
    const p = this.protocol();
    $("sine-fields").classList.toggle("hidden", !this.isSine());
    $("offset-row").classList.toggle("hidden", !this.isSine());
    this.eq.show();
    const info = $("protocol-info");
    info.classList.toggle("hidden", !p);
    info.innerHTML = "";
    if (!p) return;
    info.append(el("b", { class: "protocol-title", text: p.title || `protocol ${p.name}` }));
    if (p.description) info.append(el("div", { class: "muted", text: p.description }));
    if (!Array.isArray(p.levels)) {
      info.append(el("div", { class: "field-error", text: `protocol ${p.name}: the service does not describe it` }));
      return;
    }
    const table = el("table", { class: "params protocol-levels" });
    table.append(el("tr", {}, ...["level", "amplitude", "freq.", "cycles", "time"].map((h) => el("th", { text: h }))));
    for (const l of p.levels) {
      const taper = num(l.taper_cycles) && l.taper_cycles > 0 ? ` +${l.taper_cycles}+${l.taper_cycles}` : "";
      table.append(el("tr", {},
        el("td", { text: l.label || "" }),
        el("td", { text: fmtU("length", l.amplitude_m) }),
        el("td", { text: fmtU("frequency", l.frequency_hz) }),
        el("td", { text: `${l.cycles}${taper}` }),
        el("td", { text: fmtDuration(l.duration_s) })));
    }
    info.append(table);
    info.append(el("div", { class: "muted", text: "cycles: test cycles +ramp-in +ramp-out cycles" }));
    info.append(el("div", { class: "protocol-total", text: `${p.levels.length} levels, ${p.cycles_total} cycles, ` +
      `duration ${fmtDuration(p.duration_s)} (test time); peak \u00b1${fmtU("length", p.peak_displacement_m)}, ` +
      `${fmtU("velocity", p.peak_velocity_m_per_s)}; design displacement ${fmtU("length", p.design_displacement_m)}` }));
  }

  showControllerOptions() {
    const name = $("f-controller").value;
    const c = (this.controllers || []).find((x) => x.name === name);
    const box = $("controller-options-fields");
    box.innerHTML = "";
    const options = (c && c.options) || [];
    $("controller-options-count").textContent = options.length
      ? `(${options.length}; empty = the controller's default, in its own units)` : "(none)";
    for (const o of options) {
      const label = el("label", { class: "field", title: o.meaning || "" });
      label.append(`${o.name}${o.unit && o.unit !== "-" ? ` (${o.unit})` : ""}`);
      if (o.kind === "bool") {
        const sel = el("select", { "data-option": o.name, "data-kind": "bool" });
        sel.append(el("option", { value: "", text: `default (${o.default ? "on" : "off"})` }),
          el("option", { value: "true", text: "on" }), el("option", { value: "false", text: "off" }));
        label.append(sel);
      } else {
        const input = el("input", { type: "text", inputmode: o.kind === "int" ? "numeric" : "decimal",
          "data-option": o.name, "data-kind": o.kind || "float",
          placeholder: o.default === null || o.default === undefined ? "from the rig" : String(o.default) });
        if (num(o.min)) input.dataset.min = String(o.min);
        if (num(o.max)) input.dataset.max = String(o.max);
        label.append(input);
        const range = num(o.min) && num(o.max) ? `${+o.min.toPrecision(6)} to ${+o.max.toPrecision(6)}${o.unit && o.unit !== "-" ? ` ${o.unit}` : ""}` : "";
        label.append(el("small", { class: "range", text: [range, o.meaning].filter(Boolean).join(": ") }));
        label.append(el("small", { class: "msg" }));
      }
      box.append(label);
    }
  }

  readOption(input) {
    const r = parseNumber(input.value, { integer: input.dataset.kind === "int" });
    const msg = input.parentElement.querySelector(".msg");
    let problem = "";
    if (!r.empty && !r.ok) problem = r.error;
    else if (r.ok) {
      const lo = Number(input.dataset.min);
      const hi = Number(input.dataset.max);
      if ((input.dataset.min !== undefined && r.value < lo) || (input.dataset.max !== undefined && r.value > hi)) {
        problem = `outside ${+lo.toPrecision(6)} to ${+hi.toPrecision(6)}`;
      }
    }
    if (msg) {
      msg.textContent = problem || (r.ok && r.comma ? `read as ${r.value}` : "");
      msg.className = `msg${problem ? " bad" : " info"}`;
    }
    input.classList.toggle("invalid", Boolean(problem));
    return problem;
  }

  controllerOptions() {
    const out = {};
    for (const input of document.querySelectorAll("#controller-options-fields [data-option]")) {
      if (input.dataset.kind === "bool") {
        if (input.value) out[input.dataset.option] = input.value === "true";
        continue;
      }
      const r = parseNumber(input.value, { integer: input.dataset.kind === "int" });
      if (r.ok) out[input.dataset.option] = r.value;
    }
    return out;
  }

  /** The rig's link (RigLink): explain why Start is disabled on a rig that does not answer. */
  showRigLink(link) {
    state.linkConnected = link.connected();
    state.linkArmed = Boolean(link.link && link.link.armed && link.source !== "test");
    this.rigLink = link;
    this.renderRigWarning();
    changed("link");
  }

  /** A start cannot succeed on this rig now: it does not answer, or its table rests off zero. Said above Start. */
  renderRigWarning() {
    const box = $("rig-warning");
    const link = this.rigLink;
    const down = Boolean(link && link.kind === "udp" && link.connected() === "false");
    const off = down ? null : this.offZero();
    const l = (down && link.link) || {};
    const key = down ? `down|${l.detail}` : off ? `off|${off.text}` : "ok";
    if (key !== this.warningKey) { // rebuilt only when it says something new (a click is never lost to a redraw)
      this.warningKey = key;
      box.classList.toggle("hidden", !down && !off);
      box.dataset.state = down ? "down" : off ? "off-zero" : "ok";
      box.innerHTML = "";
      if (down) {
        const arm = link.info && typeof link.info.arm_timeout_s === "number" ? fmtPeriod(link.info.arm_timeout_s) : "";
        box.append(el("b", { text: "Rig not connected: Start is disabled until it answers." }),
          el("div", { text: `${link.name()}: ${l.detail || "no answer"}. The service arms the rig at Start and gives ` +
            `up${arm ? ` after ${arm}` : ""} without an answer; check that the rig (or isorig rig-emulator) runs ` +
            "and is reachable." }));
      } else if (off) {
        const zero = el("button", { type: "button", id: "warning-zero", class: "small", text: "Zero the table..." });
        zero.addEventListener("click", () => this.manual.go("zero"));
        const actions = el("div", { class: "warning-actions" });
        if (off.startM !== 0) { // the offset was taken from the table, which has moved since
          const fromZero = el("button", { type: "button", id: "warning-from-zero", class: "small",
            text: "Start from zero instead" });
          fromZero.title = "the test starts at zero and reaches its offset during the first cycle";
          fromZero.addEventListener("click", () => this.startFromZero());
          actions.append(fromZero);
          if (!off.nearZero) actions.append(zero);
        } else actions.append(zero);
        actions.append(el("span", { text: "see Manual motion (end of the set-up)" }));
        box.append(el("b", { text: off.startM !== 0
          ? `Table not where this test starts (${fmtU("length", off.startM, { sign: true })}): Start is disabled until it rests there.`
          : "Table off zero: Start is disabled until it rests at zero." }),
        el("div", { text: `${capitalize(off.text)}.` }), actions);
      }
    }
    if (off) this.renderZeroButton(this.manual.blockers("zero"));
  }

  /** The Zero button of the off-zero warning: as usable as Manual motion's own. */
  renderZeroButton(blockers) {
    const button = $("warning-zero");
    if (!button) return;
    button.disabled = blockers.length > 0;
    button.title = blockers.length ? `Zero needs: ${blockers.join("; ")}` : "return the table to zero (asks for a confirmation)";
  }

  startTolerance() {
    const r = (this.rig && this.rig.rig) || {};
    return num(r.start_tolerance_m) ? r.start_tolerance_m : START_TOLERANCE_M;
  }

  /**
   * The table rests more than the start tolerance from zero (GET /api/rig/state while no test runs: a UDP rig's
   * own reading, the simulated rig's table where the last run left it): the service refuses a start there.
   * {at, text} in words, or null.
   */
  offZero() {
    const rs = state.rigState;
    if (!rs || rs.status === "not_connected" || testRunning()) return null;
    const where = tablePosition();
    if (!where || where.source === "live" || where.source === "unknown") return null;
    const tol = this.startTolerance();
    const start = this.startPositionM();
    if (Math.abs(where.m - start) <= tol) return null;
    const at = fmtU("length", where.m, { sign: true });
    const of = start === 0 ? "zero" : `where this test starts, ${fmtU("length", start, { sign: true })}`;
    return { at, startM: start, nearZero: Math.abs(where.m) <= tol,
      text: `the table rests at ${at} (${sourceWords(where.source)}) and a test starts only within ` +
      `\u00b1${fmtU("length", tol, { sig: 3 })} of ${of}` };
  }

  /** The sine's offset no longer taken from the table: the test starts at zero and reaches it in the first cycle. */
  startFromZero() {
    this.offsetTakenM = null;
    this.renderOffsetNote();
    this.formChanged();
  }

  /** Under the offset: where the test starts (the table position it was taken from, or zero). */
  renderOffsetNote(how = "") {
    const taken = this.offsetTakenM;
    $("offset-note").textContent = taken === null ? "" : `set from the table position ${fmtU("length", taken, { sign: true })}` +
      `${how ? ` (${how})` : ""}: the test starts there and runs about it (a typed offset is reached from zero during ` +
      "the first cycle).";
  }

  /** Where the test in the form begins (m): the table position its offset was taken from, else zero. */
  startPositionM() {
    const v = this.values || {};
    const taken = this.offsetTakenM;
    return this.isSine() && taken !== null && num(v.offset) && Math.abs(v.offset - taken) < 1e-9 ? taken : 0;
  }

  // ------------------------------------------------------------------------------------------ isolators

  async loadIsolators(select) {
    let data = [];
    try {
      data = listOf(await api.get("/api/isolators"), "isolators");
    } catch (e) {
      showAlert(`Could not load isolators: ${e.message}`, "warn");
    }
    this.isolators = data;
    const sel = $("f-isolator");
    const keep = select || sel.value || "IUT_b";
    sel.innerHTML = "";
    const groups = { preset: el("optgroup", { label: "presets" }), user: el("optgroup", { label: "user-defined" }) };
    for (const iso of data) {
      groups[iso.source === "user" ? "user" : "preset"].append(el("option", { value: iso.name, text: iso.name }));
    }
    sel.append(groups.preset);
    if (groups.user.children.length) sel.append(groups.user);
    if (data.some((i) => i.name === keep)) sel.value = keep;
    this.showIsolator();
    const hsel = $("h-isolator");
    const hkeep = hsel.value;
    hsel.innerHTML = "";
    hsel.append(el("option", { value: "", text: "any" }));
    for (const iso of data) hsel.append(el("option", { value: iso.name, text: iso.name }));
    hsel.value = hkeep;
  }

  selectedIsolator() {
    return this.isolators.find((i) => i.name === $("f-isolator").value) || null;
  }

  showIsolator() {
    const iso = this.selectedIsolator();
    const table = $("isolator-params");
    table.innerHTML = "";
    const del = $("iso-delete");
    const user = Boolean(iso && iso.source === "user");
    del.disabled = !user || this.locked;
    del.title = user ? `delete the user isolator ${iso.name}` : "presets cannot be deleted";
    if (!iso) return;
    for (const [key, label, quantity] of ISO_PARAMS) {
      table.append(el("tr", {}, el("td", { text: `${label} (${unit(quantity)})` }),
        el("td", { text: fmt(quantity, iso[key], { sig: 4 }) })));
    }
    if (num(iso.design_vertical_load_n)) {
      table.append(el("tr", {}, el("td", { text: `design load (${unit("force")})` }),
        el("td", { text: fmt("force", iso.design_vertical_load_n) })));
    }
    if (iso.description) table.append(el("tr", {}, el("td", { text: "note" }), el("td", { text: iso.description })));
    table.append(el("tr", {}, el("td", { text: "source" }), el("td", { text: iso.source === "user" ? "user-defined" : "preset" })));
    this.renderFieldMeta();
  }

  readIsoField(input) {
    const entry = ISO_PARAMS.find(([key]) => `iso-${key}` === input.id);
    if (!entry) return null;
    const [key, , quantity] = entry;
    const r = parseNumber(input.value);
    const msg = input.closest(".field").querySelector(".msg");
    let si = null;
    let text = "";
    let cls = "msg";
    if (!r.empty && !r.ok) {
      text = r.error;
      cls += " bad";
      si = undefined;
    } else if (r.ok) {
      si = toSI(quantity, r.value);
      const warn = implausible(key, si);
      if (warn) {
        text = warn;
        cls += " warn";
      } else if (r.comma) {
        text = `read as ${fmtU(quantity, si, { sig: 8 })}`;
        cls += " info";
      }
    }
    if (num(si)) input.dataset.si = String(si);
    else delete input.dataset.si;
    msg.textContent = text;
    msg.className = cls;
    input.classList.toggle("invalid", si === undefined);
    return si;
  }

  async saveIsolator() {
    const out = $("iso-error");
    out.textContent = "";
    const body = { name: $("iso-name").value.trim(), description: $("iso-description").value.trim() };
    const warnings = [];
    for (const [key] of ISO_PARAMS) {
      const input = $(`iso-${key}`);
      const si = this.readIsoField(input);
      if (si === undefined) {
        out.textContent = `${key}: ${input.closest(".field").querySelector(".msg").textContent}`;
        return;
      }
      body[key] = si;
      const w = implausible(key, si);
      if (w) warnings.push(w);
    }
    if (warnings.length) {
      const ok = await confirmDialog({
        title: `Save isolator ${body.name || "(no name)"} with unusual values?`,
        body: "These values are far outside what isolators usually have. Check the units before saving.",
        warnings, ok: "Save anyway",
      });
      if (!ok) {
        this.message("Isolator not saved: check the values.", "");
        return;
      }
    }
    try {
      const saved = await operatorPost("/api/isolators", body);
      await this.loadIsolators(saved && saved.name ? saved.name : body.name);
      this.formChanged();
      out.textContent = "";
      this.message(`Isolator ${body.name} saved.`, "ok");
    } catch (e) {
      out.textContent = e.message;
    }
  }

  async deleteIsolator() {
    const iso = this.selectedIsolator();
    if (!iso || iso.source !== "user") return;
    const ok = await confirmDialog({
      title: `Delete the user isolator ${iso.name}?`,
      body: "It disappears from the list. Records of tests that used it keep their own copy of its parameters.",
      ok: "Delete isolator", danger: true,
    });
    if (!ok) return;
    try {
      await api.del(`/api/isolators/${encodeURIComponent(iso.name)}`);
      await this.loadIsolators("IUT_b");
      this.formChanged();
      this.message(`Isolator ${iso.name} deleted.`, "ok");
    } catch (e) {
      this.message(`Isolator ${iso.name} not deleted: ${e.message}`, "error");
    }
  }

  // ------------------------------------------------------------------------------------------ the request

  /** The request body of POST /api/tests from the form (SI units), or {problems}. */
  body() {
    const problems = this.readAll();
    const v = this.values;
    const p = this.protocol();
    const profile = this.eq.kind() ? this.eq.profile(v) : p ? { kind: "protocol", name: p.name } : {
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

  /** Where a sine's offset comes from: the table's position now (rounded to 0.01 mm), when it is known. */
  offsetFromTable() {
    const where = tablePosition();
    if (!where || this.locked) return;
    const m = Math.round(where.m / 1e-5) * 1e-5;
    this.setField("offset", m === 0 ? 0 : m);
    this.offsetTakenM = m === 0 ? null : m;
    this.renderOffsetNote(sourceWords(where.source));
    this.formChanged();
  }

  /** The "from table position" button: usable when the console knows where the table rests. */
  renderOffsetButton() {
    const where = tablePosition();
    const button = $("offset-from-table");
    button.disabled = !where || this.locked;
    button.title = where ? `set the offset to ${fmtU("length", where.m, { sign: true })} (${sourceWords(where.source)})`
      : "the table position is not known";
  }

  /** The limits the next test would get, with their actions: the form's, else the rig's defaults (SI). */
  nextLimits() {
    const def = (this.rig && this.rig.limits_default) || {};
    const out = { ...def };
    for (const [key, spec] of Object.entries(this.fields)) {
      if (spec.limit && num(this.values[key])) out[spec.limit] = this.values[key];
    }
    out.actions = this.actions();
    return out;
  }

  /** The part of the body the envelope depends on (who and notes are not checked against the rig). */
  static checkKey(body) {
    const { specimen_id: _s, operator_name: _o, notes: _n, ...rest } = body;
    return JSON.stringify(rest, (k, v) => (Array.isArray(v) && v.length > 64 ? `[record ${recordId(v)}]` : v));
  }

  scheduleCheck(delay = 250) {
    clearTimeout(this.checkTimer);
    this.checkPending = true;
    this.checkTimer = setTimeout(() => this.check(), delay);
  }

  /** Ask the API whether the current choice fits the rig, and explain a refusal before Start. */
  async check() {
    const seq = ++this.checkSeq;
    const box = $("envelope");
    const { body, problems } = this.body();
    const key = SetupPanel.checkKey(body);
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
          if (seq === this.checkSeq) {
            box.textContent = "Checking: the service is busy with other checks; asking again in 2 s ...";
            this.scheduleCheck(2000);
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
    if (num(d.max_force_n)) limits.push(`actuator force up to ${fmtU("force", d.max_force_n, { sig: 3 })} at this pressure`);
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

  // ------------------------------------------------------------------------------------------ state

  onStateChanged(what) {
    if (what === "test" || what === "status") {
      const t = state.test;
      if (testRunning() && t && t.id === state.testId) this.followTest(t);
      else if (!testRunning() && this.locked) this.unlock();
    }
    if (what === "rigState" || what === "position" || what === "status") {
      this.renderRigWarning();
      this.renderOffsetButton();
    }
    if (what === "rig" || what === "rigState" || what === "status" || what === "conn" || what === "link" ||
        what === "test" || what === "stopping") {
      this.updateButtons();
    }
  }

  /** A test runs: show its set-up (locked) so this page says what the rig does, also after a reload. */
  followTest(t) {
    if (this.locked && this.lockedTestId === t.id) return;
    this.locked = true;
    this.lockedTestId = t.id;
    $("f-specimen_id").value = t.specimen_id || "";
    $("f-operator_name").dataset.following = "1";
    $("f-operator_name").value = t.operator_name || "";
    $("f-notes").value = t.notes || "";
    if (t.isolator && this.isolators.some((i) => i.name === t.isolator)) $("f-isolator").value = t.isolator;
    if (num(t.supply_bar)) this.setField("supply", t.supply_bar * BAR);
    if (num(t.vertical_load_n)) this.setField("vertical_load", t.vertical_load_n);
    if (num(t.speed)) this.setField("speed", t.speed);
    const p = t.profile || {};
    if (p.kind === "protocol" && p.name) {
      if (![...$("f-profile").options].some((o) => o.value === `protocol:${p.name}`)) {
        $("f-profile").append(el("option", { value: `protocol:${p.name}`, text: `protocol ${p.name}` }));
      }
      $("f-profile").value = `protocol:${p.name}`;
    } else if (p.kind === "history" || p.kind === "hybrid") {
      this.eq.follow(p);
    } else if (p.kind === "sine") {
      $("f-profile").value = "sine";
      this.setField("amplitude", p.amplitude_m);
      this.setField("frequency", p.frequency_hz);
      this.setField("cycles", p.cycles);
      this.setField("taper_cycles", p.taper_cycles);
      this.setField("offset", num(p.offset_m) && p.offset_m !== 0 ? p.offset_m : null);
      this.offsetTakenM = num(p.start_m) && p.start_m !== 0 && p.start_m === p.offset_m ? p.start_m : null;
      this.renderOffsetNote(`where test #${t.id} started`);
    }
    if (t.controller && [...$("f-controller").options].some((o) => o.value === t.controller)) {
      $("f-controller").value = t.controller;
      this.showControllerOptions();
      const opts = (t.scenario && t.scenario.controller_options) || {};
      for (const [k, v] of Object.entries(opts)) {
        const input = document.querySelector(`#controller-options-fields [data-option="${k}"]`);
        if (input) input.value = typeof v === "boolean" ? String(v) : String(v);
      }
    }
    const lim = t.limits || {};
    const def = (this.rig && this.rig.limits_default) || {};
    for (const [key, spec] of Object.entries(this.fields)) {
      if (!spec.limit) continue;
      const v = lim[spec.limit];
      this.setField(key, num(v) && v !== def[spec.limit] ? v : null);
    }
    for (const l of LIMITS) this.actionSelect(l.key).value = actionOf(lim, l.key);
    this.showActionHelp();
    this.showIsolator();
    this.showProfile();
    this.readAll();
    $("setup-fields").disabled = true;
    $("iso-delete").disabled = true;
    const lock = $("form-lock");
    lock.textContent = isMove(t)
      ? `Manual move #${t.id} is running: the form is locked until it ends.`
      : isCommissioning(t) ? `Commissioning #${t.id} is running (see the Commissioning page): the form is locked until it ends.`
        : `The form shows test #${t.id}, which is running: locked until it ends.`;
    lock.classList.remove("hidden");
    this.scheduleCheck(0);
  }

  unlock() {
    const mine = this.lockedTestId !== null && this.lockedTestId === this.startedId;
    this.locked = false;
    this.lockedTestId = null;
    $("setup-fields").disabled = false;
    delete $("f-operator_name").dataset.following; // back to the logged-in account
    $("f-operator_name").value = account.name || "";
    // a test started elsewhere (another console, a script) does not replace this operator's set-up
    if (!mine) {
      this.restoreDraft();
      this.readAll();
    }
    $("form-lock").classList.add("hidden");
    this.showIsolator();
    this.saveDraft();
    this.scheduleCheck(0);
  }

  /** Why Start cannot succeed now ([] when it can). */
  startBlockers() {
    const out = [];
    if (!state.conn) out.push("no connection to the service");
    if (testRunning()) out.push(`${runName(state.test, state.testId ?? (state.rigState && state.rigState.test_id))} is running`);
    if (state.linkConnected === "false") out.push("the rig is not connected");
    else if (!testRunning()) {
      const off = this.offZero();
      if (off && off.startM === 0) out.push(`the table at zero (it rests at ${off.at}, see above: Zero brings it back)`);
      else if (off) out.push(`the table at ${fmtU("length", off.startM, { sign: true })}, where this test starts (it rests at ${off.at})`);
    }
    if (!this.locked) {
      const { body, problems } = this.body();
      if (!body.specimen_id) out.push("a specimen id");
      const bad = Object.keys(problems);
      if (bad.length) out.push(`valid values (${bad.map((k) => k.replace(/^lim_/, "limit ").replace(/_/g, " ")).join(", ")})`);
      else if (this.lastCheck.ok === false) out.push(this.lastCheck.local ? "valid values (see the fields)" : "a set-up within the rig envelope (see above)");
      else if (this.checkPending || this.lastCheck.key !== SetupPanel.checkKey(body)) out.push("the envelope check (running)");
      else if (this.lastCheck.ok !== true) out.push("the envelope check (not available)");
    }
    return out;
  }

  updateButtons() {
    const blockers = this.startBlockers();
    const start = $("start");
    start.disabled = blockers.length > 0;
    const why = $("start-why");
    why.textContent = blockers.length ? `Start needs: ${blockers.join("; ")}.` : "Start asks for a confirmation with the motion before the valve opens.";
    why.className = `why${blockers.length ? " blocked" : ""}`;
    why.dataset.blocked = blockers.length ? "1" : "0";
    const stop = $("stop");
    stop.disabled = !testRunning() || state.stopping || !state.conn;
    stop.textContent = state.stopping ? "Stopping..." : "Stop";
    // a refusal whose cause is gone is cleared
    if (this.refusal) {
      const c = this.refusal.cause;
      if ((c === "busy" && !testRunning()) || (c === "rig" && state.linkConnected !== "false") ||
          (c === "conn" && state.conn) || (c === "position" && this.tableBackAtZero())) {
        this.clearRefusal();
      }
    }
  }

  message(text, kind = "") {
    const m = $("setup-message");
    m.textContent = text;
    m.className = `message ${kind}`;
  }

  /** After an off-zero refusal: the rig's own reading, asked after the refusal, is back within the tolerance. */
  tableBackAtZero() {
    const rs = state.rigState;
    if (testRunning()) return true;
    if (!rs || state.rigStateSeq <= this.refusal.rigStateSeq) return false;
    return rs.position_source !== "live" && num(rs.table_position_m) &&
      Math.abs(rs.table_position_m) <= this.startTolerance();
  }

  refuse(cause, text) {
    this.refusal = { cause, text, rigStateSeq: state.rigStateSeq };
    this.message(text, "error");
    $("setup-message").dataset.cause = cause;
  }

  clearRefusal() {
    this.refusal = null;
    this.message("", "");
    delete $("setup-message").dataset.cause;
  }

  // ------------------------------------------------------------------------------------------ draft

  saveDraft() {
    if (this.locked) return;
    const draft = { values: {}, isolator: $("f-isolator").value, profile: $("f-profile").value,
      controller: $("f-controller").value, specimen_id: $("f-specimen_id").value,
      notes: $("f-notes").value, actions: this.actions(),
      eq: { source: $("f-eq_source").value, preset: $("f-eq_preset").value, unit: $("f-eq_acc_unit").value,
        storeys: this.eq.storeys } }; // a record file is not kept: it is chosen again after a reload
    for (const [key, v] of Object.entries(this.values)) if (num(v) || v === null) draft.values[key] = v;
    try { localStorage.setItem(DRAFT_KEY, JSON.stringify(draft)); } catch { /* not kept */ }
  }

  restoreDraft() {
    let draft = null;
    try { draft = JSON.parse(localStorage.getItem(DRAFT_KEY) || "null"); } catch { draft = null; }
    if (!draft) return;
    if (draft.isolator && this.isolators.some((i) => i.name === draft.isolator)) $("f-isolator").value = draft.isolator;
    if (draft.profile && [...$("f-profile").options].some((o) => o.value === draft.profile)) $("f-profile").value = draft.profile;
    if (draft.controller && [...$("f-controller").options].some((o) => o.value === draft.controller)) {
      $("f-controller").value = draft.controller;
      this.showControllerOptions();
    }
    for (const k of ["specimen_id", "notes"]) if (typeof draft[k] === "string") $(`f-${k}`).value = draft[k];
    const eq = draft.eq || {};
    for (const [id, v] of [["f-eq_source", eq.source], ["f-eq_preset", eq.preset], ["f-eq_acc_unit", eq.unit]]) {
      if (v && [...$(id).options].some((o) => o.value === v)) $(id).value = v;
    }
    if (Number.isInteger(eq.storeys) && eq.storeys > 0) this.eq.setStoreys(eq.storeys);
    for (const [key, v] of Object.entries(draft.values || {})) {
      if (this.fields[key] && !(key === "speed" && this.realTimeOnly)) this.setField(key, v);
    }
    for (const l of LIMITS) {
      const a = draft.actions && draft.actions[l.key];
      const sel = this.actionSelect(l.key);
      if (a && [...sel.options].some((o) => o.value === a)) sel.value = a;
    }
    this.showActionHelp();
    this.showIsolator();
  }

  // ------------------------------------------------------------------------------------------ start, stop

  /**
   * What the motion asks of the rig (SI): the service's figures from the envelope check of exactly this set-up
   * (peak displacement, velocity, force estimate, duration, cycles). If the service gave none, displacement,
   * velocity and duration are worked out here from the motion (a sine, or a protocol as listed), and the force
   * is not estimated: `source` says which.
   */
  figures(body) {
    const d = this.lastCheck.key === SetupPanel.checkKey(body) ? this.lastCheck.data || {} : {};
    if (num(d.peak_displacement_m) && num(d.peak_velocity_m_per_s) && num(d.duration_s)) {
      return { source: "service", d: d.peak_displacement_m, v: d.peak_velocity_m_per_s,
        f: num(d.peak_force_n) ? d.peak_force_n : null, duration: d.duration_s, cycles: d.cycles_total };
    }
    const p = body.profile;
    if (p.kind === "sine") {
      return { source: "console", d: Math.abs(p.offset_m || 0) + p.amplitude_m, v: 2 * Math.PI * p.frequency_hz * p.amplitude_m,
        f: null, duration: p.cycles / p.frequency_hz, cycles: p.cycles };
    }
    const listed = this.protocol();
    if (listed && num(listed.duration_s)) {
      return { source: "console", d: listed.peak_displacement_m, v: listed.peak_velocity_m_per_s, f: null,
        duration: listed.duration_s, cycles: listed.cycles_total };
    }
    return null;
  }

  /** Values that are valid but look like unit mistakes or certain trips: each needs an explicit tick. */
  warnings(body, m) {
    const out = [];
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
      const maxF = this.lastCheck.data && this.lastCheck.data.max_force_n;
      if (num(m.f) && num(maxF) && m.f > 0.9 * maxF) {
        out.push(`the estimated peak force ${fmtU("force", m.f, { sig: 3 })} is near or above what the actuator gives at this pressure (${fmtU("force", maxF, { sig: 3 })})`);
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
      const check = this.lastCheck.key === SetupPanel.checkKey(body) ? this.lastCheck.data : null;
      rows.push(...this.eq.summaryRows(body, check));
    } else {
      const p = this.protocol() || {};
      rows.push(["motion", `protocol ${body.profile.name}`, Array.isArray(p.levels)
        ? `${p.levels.length} levels: ${p.levels.map((l) => `${fmtU("length", l.amplitude_m)} at ${fmtU("frequency", l.frequency_hz)} x ${l.cycles}`).join(", ")}`
        : ""]);
    }
    if (m) {
      const maxF = this.lastCheck.data && this.lastCheck.data.max_force_n;
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
          (num(maxF) ? `; the actuator gives ${fmtU("force", maxF, { sig: 3 })} at this pressure` : "")]
        : ["peak force (estimate)", "not available", "the service's check gave no force estimate"]);
      const wall = m.duration / (body.speed || 1);
      rows.push(["duration", fmtDuration(m.duration), `${num(m.cycles) && m.cycles > 0 ? `${m.cycles} cycles, ` : ""}` +
        (body.speed !== 1 ? `test time; ${fmtDuration(wall)} wall time at ${body.speed}x` : "real time")]);
    } else {
      rows.push(["peak figures", "not available", "the service gave none and this console cannot work them out"]);
    }
    const load = body.vertical_load_n ?? this.defaultVerticalLoad().value;
    rows.push(["supply / vertical load", `${fmtU("pressure", body.supply_bar * BAR)} / ${fmtU("force", load, { sig: 4 })}`]);
    const box = el("div", {}, summaryTable(rows));
    box.append(this.limitsBox(body.limits));
    return box;
  }

  /** A table of the limits (the rig's defaults where `limits` names none), each with its action, explained. */
  /** The limits in force and what each action does; `what`: "test" or "move" (the record that ends aborted). */
  limitsBox(limits, what = "test") {
    const box = el("div", { class: "limits-box" });
    const lim = { ...((this.rig && this.rig.limits_default) || {}), ...(limits || {}) };
    const table = el("table", { class: "params summary-table limits-table" });
    table.append(el("tr", {}, el("th", { text: "limit" }), el("th", { text: "value" }), el("th", { text: "when exceeded" })));
    const used = new Set();
    for (const l of LIMITS) {
      if (!num(lim[l.key])) continue;
      const a = actionOf(lim, l.key);
      used.add(a);
      table.append(el("tr", { "data-limit": l.key, "data-action": a },
        el("td", { text: `${l.name} ${l.short}` }), el("td", {}, el("b", { text: fmtU(l.quantity, lim[l.key], { sig: 4 }) })),
        el("td", {}, el("b", { text: actionName(a) }))));
    }
    box.append(table);
    box.append(el("p", { class: "actions-help" }, ...ACTION_ORDER.filter((a) => used.has(a))
      .map((a) => el("span", {}, el("b", { text: actionName(a) }), `: ${actionHelp(a).replace("the test ends", `the ${what} ends`)}. `))));
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

const RECORD_IDS = new WeakMap(); // an inline record (array) of a file read: one id per array, for checkKey
let recordSeq = 0;
function recordId(array) {
  if (!RECORD_IDS.has(array)) RECORD_IDS.set(array, ++recordSeq);
  return RECORD_IDS.get(array);
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

