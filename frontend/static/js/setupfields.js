// The set-up's numeric fields: what each is (quantity, range, default), how it is read (typed as text, parsed
// explicitly by js/parse.js in the console's units of js/units.js), and what it shows (unit, range, message).
// Also the helpers the other set-up modules share (BAR, listOf, the usual ranges of an isolator's values).

import { G } from "./earthquake.js";
import { parseNumber } from "./parse.js";
import { fmt, fmtU, inputText, sigDigits, toDisplay, toSI, unit } from "./units.js";

const $ = (id) => document.getElementById(id);
const num = (v) => typeof v === "number" && Number.isFinite(v);

export const BAR = 1e5;

// Isolator parameters: key, label, quantity
export const ISO_PARAMS = [
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

export function capitalize(text) {
  return text ? text[0].toUpperCase() + text.slice(1) : text;
}

export function listOf(data, key) {
  if (Array.isArray(data)) return data;
  if (data && Array.isArray(data[key])) return data[key];
  return [];
}

/** "10 to 210 bar", "up to 150 mm": a range in display units. */
function rangeText(quantity, lo, hi, { openLow = false, integer = false, nonZero = false } = {}) {
  const f = (v) => (integer ? String(v) : quantity ? fmt(quantity, v, { sig: 6 }) : String(+v.toPrecision(6)));
  const u = quantity && unit(quantity) !== "-" ? ` ${unit(quantity)}` : "";
  if (openLow && lo === 0) return `above 0, up to ${f(hi)}${u}`;
  if (nonZero) return `${f(lo)} to ${f(hi)}${u}, not 0`;
  return `${f(lo)} to ${f(hi)}${u}`;
}

/** A value ten times or more outside the usual range: the warning text, else "". */
export function implausible(key, si) {
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

export class FieldsPart {
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
      // a protocol's levels scaled to the specimen (EN 15129: fractions of the design displacement d_bd)
      design_displacement: { id: "f-design_displacement", quantity: "length", required: false, openLow: true,
        when: () => this.protocol() !== null, range: () => [0, Math.min(1, env().stroke_m ?? 0.15)],
        placeholder: () => (this.protocol() || {}).design_displacement_m },
      // and run at the specimen's design frequency (EN 15129); empty: each level at its own
      design_frequency: { id: "f-design_frequency", quantity: "frequency", required: false, openLow: true,
        when: () => this.protocol() !== null, range: () => [0, env().max_frequency_hz ?? 10],
        placeholder: () => this.protocolFrequency(), emptyText: "each level at the protocol's frequency" },
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
      if (tooLow || si > hi * (1 + 1e-12) || (spec.nonZero && si === 0)) {
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
        text = this.eq.fromGroundMotion() ? `${text} (times the ground acceleration)` : `${text} (times the displacement; negative: the record mirrored)`;
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
        const p = spec.placeholder();
        input.placeholder = num(p) ? fmt(spec.quantity, p, { sig: 6 }) : "";
        text += num(p) ? `; empty: ${fmtU(spec.quantity, p, { sig: 6 })}` : spec.emptyText ? `; empty: ${spec.emptyText}` : "";
      }
      if (key === "vertical_load") {
        const d = this.defaultVerticalLoad();
        text += `; empty: ${fmtU("force", d.value)} (${d.source})`;
        input.placeholder = fmt("force", d.value);
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
    if (num(building)) return { value: building * G, building: true, source: "the building's weight" };
    const iso = this.isolators.find((i) => i.name === $("f-isolator").value) || {};
    if (num(iso.design_vertical_load_n)) {
      return { value: iso.design_vertical_load_n, iso: true, source: "the isolator's design load" };
    }
    return { value: num(env.vertical_load_n_default) ? env.vertical_load_n_default : 125e3, iso: false,
      source: "the rig's default" };
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
}
