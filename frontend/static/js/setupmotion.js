// What the rig offers the set-up (GET /api/rig): its controllers and their options, its speed (a real rig runs
// in real time), and the motion: a sine or a shipped protocol (GET /api/protocols) with its levels.

import { api } from "./api.js";
import { parseNumber } from "./parse.js";
import { rigKind } from "./rig.js";
import { listOf } from "./setupfields.js";
import { changed, state } from "./state.js";
import { el, fmtDuration } from "./ui.js";
import { fmtU } from "./units.js";

const $ = (id) => document.getElementById(id);
const num = (v) => typeof v === "number" && Number.isFinite(v);

export class MotionPart {
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

  /** The protocol's profile of POST /api/tests: its name, the specimen's design displacement and frequency if given. */
  protocolProfile(p, v) {
    const out = { kind: "protocol", name: p.name };
    if (num(v.design_displacement)) out.design_displacement_m = v.design_displacement;
    if (num(v.design_frequency)) out.frequency_hz = v.design_frequency;
    return out;
  }

  /** The chosen protocol's frequency (Hz) when every level runs at one, else null (each level at its own). */
  protocolFrequency() {
    const p = this.protocol();
    const f = p && Array.isArray(p.levels) ? [...new Set(p.levels.map((l) => l.frequency_hz))] : [];
    return f.length === 1 && num(f[0]) ? f[0] : null;
  }

  /**
   * The chosen protocol as it will run (SI): its levels scaled to the design displacement typed (a level given
   * as a fraction of d_bd: amplitude and peak velocity in proportion; a level in metres: as it is), the peaks,
   * and the design displacement used with where it comes from. null: no protocol, or one the service did not
   * describe.
   */
  scaledProtocol() {
    const p = this.protocol();
    if (!p || !Array.isArray(p.levels)) return null;
    const v = this.values || {};
    const typed = num(v.design_displacement);
    const d = typed ? v.design_displacement : p.design_displacement_m;
    const fTyped = num(v.design_frequency);
    const levels = p.levels.map((l) => {
      let out = l;
      if (typed && num(l.fraction) && num(p.design_displacement_m)) {
        const amplitude = l.fraction * d;
        const k = num(l.amplitude_m) && l.amplitude_m > 0 ? amplitude / l.amplitude_m : 1;
        out = { ...out, amplitude_m: amplitude, peak_velocity_m_per_s: l.peak_velocity_m_per_s * k };
      }
      if (fTyped && num(l.frequency_hz) && l.frequency_hz > 0) { // every level at the design frequency
        const k = v.design_frequency / l.frequency_hz;
        out = { ...out, frequency_hz: v.design_frequency, peak_velocity_m_per_s: out.peak_velocity_m_per_s * k,
          duration_s: out.duration_s / k };
      }
      return out;
    });
    const peakD = Math.max(...levels.map((l) => l.amplitude_m));
    const peakV = Math.max(...levels.map((l) => l.peak_velocity_m_per_s));
    const duration = levels.reduce((sum, l) => sum + l.duration_s, 0);
    return { ...p, levels, design_displacement_m: d, designFrom: typed ? "entered" : "the protocol's",
      frequency_hz: fTyped ? v.design_frequency : this.protocolFrequency(), frequencyFrom: fTyped ? "entered" : "the protocol's",
      duration_s: Number.isFinite(duration) ? duration : p.duration_s,
      peak_displacement_m: Number.isFinite(peakD) ? peakD : p.peak_displacement_m,
      peak_velocity_m_per_s: Number.isFinite(peakV) ? peakV : p.peak_velocity_m_per_s };
  }

  /** The chosen protocol: its title, what it is for, every level and the whole (duration, cycles, peaks). */
  showProfile() {
    $("sine-fields").classList.toggle("hidden", !this.isSine());
    $("offset-row").classList.toggle("hidden", !this.isSine());
    $("design-displacement-row").classList.toggle("hidden", !this.protocol());
    $("design-frequency-row").classList.toggle("hidden", !this.protocol());
    this.eq.show();
    this.renderProtocol();
    this.renderFieldMeta(); // the design displacement's default is the protocol's
  }

  /** The protocol's levels in the console's units, as they will run (scaled to the design displacement). */
  renderProtocol() {
    const p = this.scaledProtocol() || this.protocol();
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
      `${fmtU("velocity", p.peak_velocity_m_per_s)}; design displacement d_bd ${fmtU("length", p.design_displacement_m)}` +
      (p.designFrom === "entered" ? " (entered: the levels are scaled to it)" : " (the protocol's: enter the specimen's to scale the levels)") +
      (num(p.frequency_hz) ? `; frequency ${fmtU("frequency", p.frequency_hz)}${p.frequencyFrom === "entered" ? " (entered: every level)" : " (the protocol's)"}` : "") }));
    info.dataset.designDisplacementM = String(p.design_displacement_m);
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
}
