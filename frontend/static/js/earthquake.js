// Earthquake tests in the set-up (issue 16): a time history and a real-time hybrid simulation (RTHS).
// - Time history: a synthetic ground motion shipped with the service (a preset), a ground motion from a CSV file
//   (time_s, acceleration in m/s2, g or cm/s2: the unit the operator chose, else the one the file's header names,
//   else m/s2 assumed, and the page says which) through the isolator's demand model, or a displacement history
//   from a CSV file (time_s, displacement_m). Scale, tapers, the demand model's mass.
// - Hybrid: the building above the isolator (base mass, storey masses and springs, damping ratio; defaults: the
//   demo building of docs/examples/structure_3_storey.json), a ground motion (preset or CSV) and its scale, the
//   stability monitor's threshold (limit_j, relative_limit).
// The CSV is read in the browser into the API's inline form ({time_s, acceleration_m_per_s2, units} or
// {time_s, displacement_m}); a file that cannot be read is refused with its line, never reinterpreted. The
// service checks everything again (POST /api/tests/check; POST /api/tests).

import { api } from "./api.js";
import { parseNumber } from "./parse.js";
import { el, fmtDuration } from "./ui.js";
import { fmtU, sigDigits, unit } from "./units.js";

const $ = (id) => document.getElementById(id);
const num = (v) => typeof v === "number" && Number.isFinite(v);

export const G = 9.80665; // m/s2 per g
const MAX_SAMPLES = 200000; // the API's limit per inline array
const MIN_ROWS = 10;
const MAX_STOREYS = 50;
const MAX_FILE_BYTES = 12e6; // the service's limit (MAX_AT2_CHARS; its request body cap is 16 MiB)
const MASS_MAX_KG = 1e8;
const PLAUSIBLE_G = [0.005, 3]; // the service refuses a peak ground acceleration outside this (in the unit read)
export const UNIT_TO_SI = { "m/s2": 1, g: G, "cm/s2": 0.01 };

/**
 * The synthetic ground motions the service ships (GET /api/ground-motions: sim/ground_motion.py GROUND_MOTIONS,
 * docs/earthquake.md section 5), loaded once by loadPresets: {name, duration_s, pga_g (measured), words}.
 */
let presets = [];

/** The demo building (docs/examples/structure_3_storey.json): 12.75 t in all, the rig's default load. */
export const DEMO_BUILDING = { base_mass_kg: 4000, masses_kg: [3000, 3000, 2750],
  stiffness_n_per_m: [8e6, 6e6, 4e6], damping_ratio: 0.05 };
const DEFAULT_STABILITY = { limit_j: 100, relative_limit: 0.5 }; // sim.hybrid_metrics.EnergyMonitor defaults

// ------------------------------------------------------------------------------------------------ CSV records

const PLAIN = /^[+-]?(\d+\.?\d*|\.\d+)([eE][+-]?\d+)?$/;

/** One cell as a number: {value} or {error}. A decimal comma is read as one (a ';' file's, or unambiguous). */
function cellNumber(cell, decimalComma) {
  const text = decimalComma ? cell.replace(",", ".") : cell;
  if (PLAIN.test(text)) return { value: Number(text) };
  if (/^[+-]?(nan|inf|infinity)$/i.test(text)) return { error: `${cell} is not a finite number` };
  const r = parseNumber(text); // the console's rules: "1,5" read as 1.5, "1,000" refused with both readings
  if (r.ok) return { value: r.value, comma: r.comma };
  return { error: r.empty ? "a missing value" : r.error };
}

/** The unit a header cell names for an acceleration ("acceleration_g", "acc [cm/s2]"), or "". */
export function headerAccelerationUnit(name) {
  const n = String(name || "").toLowerCase();
  if (/cm_per_s2|cm\/s\^?2|cm\/s²|\bgal\b/.test(n)) return "cm/s2";
  if (/m_per_s2|m\/s\^?2|m\/s²/.test(n)) return "m/s2";
  if (/(_g$|\[g\]|\(g\)|\bin g\b|^g$)/.test(n)) return "g";
  return "";
}

/**
 * Read a record: CSV with '#' comments and blank lines skipped, an optional header row (a row with no number in
 * it), separators ',', ';' (then ',' is a decimal comma), tab or spaces; the time column by name (time_s, time,
 * t) and the value column by its prefix (acc..., disp...), else the first two. Time must increase with a
 * uniform step (within 1 %, as the service checks). Returns {ok: true, ...} or {ok: false, error} naming the line.
 */
export function parseRecordCsv(text, kind) {
  const what = kind === "displacement" ? "displacement" : "acceleration";
  const lines = String(text).split(/\r\n|\n|\r/);
  let sep = null;
  let header = null;
  let ti = 0;
  let vi = 1;
  const t = [];
  const v = [];
  const lineOf = [];
  let commas = false;
  for (let i = 0; i < lines.length; i++) {
    const raw = lines[i].trim();
    if (!raw || raw.startsWith("#")) continue;
    const line = i + 1;
    if (sep === null) sep = raw.includes(";") ? ";" : raw.includes(",") ? "," : raw.includes("\t") ? "\t" : " ";
    const cells = (sep === " " ? raw.split(/\s+/) : raw.split(sep)).map((c) => c.trim());
    if (header === null && t.length === 0 && cells.every((c) => !PLAIN.test(c.replace(",", ".")))) {
      header = { line, cells };
      const lower = cells.map((c) => c.toLowerCase());
      const tIx = lower.findIndex((c) => c === "t" || c.startsWith("time"));
      const vIx = lower.findIndex((c) => c.startsWith(kind === "displacement" ? "disp" : "acc"));
      if (tIx >= 0) ti = tIx;
      if (vIx >= 0) vi = vIx;
      else if (tIx >= 0) vi = tIx === 0 ? 1 : 0;
      continue;
    }
    if (cells.length < Math.max(ti, vi) + 1) {
      return { ok: false, error: `line ${line}: expected ${Math.max(ti, vi) + 1} values (time, ${what}), found ` +
        `${cells.length}: a missing value` };
    }
    const a = cellNumber(cells[ti], sep === ";");
    if (a.error) return { ok: false, error: `line ${line}: time = '${cells[ti]}': ${a.error}` };
    const b = cellNumber(cells[vi], sep === ";");
    if (b.error) return { ok: false, error: `line ${line}: ${what} = '${cells[vi]}': ${b.error}` };
    if (!Number.isFinite(a.value) || !Number.isFinite(b.value)) {
      return { ok: false, error: `line ${line}: not a finite number` };
    }
    if (a.comma || b.comma || (sep === ";" && /,/.test(cells[ti] + cells[vi]))) commas = true;
    if (t.length && !(a.value > t[t.length - 1])) {
      return { ok: false, error: `line ${line}: time ${a.value} s is not after the previous row's ` +
        `${t[t.length - 1]} s; time must increase` };
    }
    t.push(a.value);
    v.push(b.value);
    lineOf.push(line);
    if (t.length > MAX_SAMPLES) {
      return { ok: false, error: `more than ${MAX_SAMPLES} rows (line ${line}): the service takes at most ${MAX_SAMPLES} samples` };
    }
  }
  if (t.length < MIN_ROWS) {
    return { ok: false, error: `only ${t.length} data row(s); a record needs at least ${MIN_ROWS}` };
  }
  const steps = t.slice(1).map((x, k) => x - t[k]).sort((p, q) => p - q);
  const dt = steps[Math.floor(steps.length / 2)];
  for (let k = 1; k < t.length; k++) {
    const step = t[k] - t[k - 1];
    if (Math.abs(step - dt) > 0.01 * dt) {
      const kindOf = step > 1.5 * dt ? "a gap (missing rows?)" : "a non-uniform step";
      return { ok: false, error: `line ${lineOf[k]}: time steps from ${t[k - 1]} s to ${t[k]} s, a step of ` +
        `${sigDigits(step, 4)} s where the record's step is ${sigDigits(dt, 4)} s: ${kindOf}; records must be ` +
        "uniformly sampled (within 1 %)" };
    }
  }
  const names = header ? header.cells : [];
  let peak = 0;
  for (const x of v) peak = Math.max(peak, Math.abs(x));
  return { ok: true, time_s: t, values: v, rows: t.length, dt, duration: t[t.length - 1] - t[0], peak,
    header: header ? names.join(", ") : "", valueName: names[vi] || "", timeName: names[ti] || "",
    headerUnit: kind === "displacement" ? "" : headerAccelerationUnit(names[vi]),
    headerLength: kind === "displacement" && /_mm\b|\[mm\]|\(mm\)/i.test(names[vi] || "") ? "mm" : "",
    sep: { ",": "comma", ";": "semicolon (decimal comma)", "\t": "tab", " ": "spaces" }[sep], commas };
}

/**
 * A PEER NGA .AT2 file, read by the service (POST /api/ground-motions/read-at2: the CLI's reader) into the same
 * record as parseRecordCsv gives, its unit (g, or cm/s2 if the header says so) as the header's.
 */
export async function readAt2(name, text, checkUnits = true) {
  try {
    const body = { filename: name, text };
    if (!checkUnits) body.check_units = false;
    // the service reads it in its check pool: while that is busy (503), ask again after its Retry-After
    const r = await api.postWhenFree("/api/ground-motions/read-at2", body);
    return { ok: true, time_s: r.time_s, values: r.acceleration, rows: r.rows, dt: r.dt_s, duration: r.duration_s,
      peak: r.peak, header: r.header.join(" / "), valueName: "PEER .AT2 header", timeName: "NPTS, DT",
      headerUnit: r.units, headerLength: "", sep: "PEER .AT2", commas: false, at2: true, title: r.header.slice(0, 2).join(", ") };
  } catch (e) {
    const msg = e.message || String(e);
    return { ok: false, error: msg.startsWith(name) ? msg.slice(name.length).replace(/^[:,]\s*/, "") : msg };
  }
}

// ------------------------------------------------------------------------------------------------ the form

/** Field specs of the earthquake part, merged into the set-up's (js/setup.js readField, renderFieldMeta). */
export class EarthquakeForm {
  constructor(setup) {
    this.setup = setup;
    this.files = { acceleration: null, displacement: null }; // {name, record} of the file read
    this.structureError = ""; // a structure file that could not be read: Start waits until it is replaced or cleared
    this.storeys = 0;
  }

  /** "history", "hybrid" or null (a sine or a protocol). */
  kind() {
    const v = $("f-profile").value;
    return v === "history" || v === "hybrid" ? v : null;
  }

  /** Where the motion comes from: "preset", "acc_csv" (a ground motion) or "disp_csv" (a displacement history). */
  source() {
    const s = $("f-eq_source").value;
    return this.kind() === "hybrid" && s === "disp_csv" ? "preset" : s;
  }

  fromGroundMotion() {
    return this.kind() === "hybrid" || this.source() !== "disp_csv";
  }

  fieldSpecs() {
    const eq = this; // eslint-disable-line consistent-this
    const history = () => this.kind() === "history";
    const hybrid = () => this.kind() === "hybrid";
    return {
      // a ground motion's scale: above 0 (the isolator is nonlinear); a displacement's: either sign (a negative
      // one mirrors the record), not 0 (the API's 0 < |scale| <= 100)
      eq_scale: { id: "f-eq_scale", quantity: null, required: true, when: () => this.kind() !== null,
        get openLow() { return eq.fromGroundMotion(); },
        get nonZero() { return !eq.fromGroundMotion(); },
        range: () => (this.fromGroundMotion() ? [0, 10] : [-100, 100]) },
      eq_taper_in: { id: "f-eq_taper_in", quantity: "time", required: false, when: history, range: () => [0, 600],
        placeholder: () => 0.5 },
      eq_taper_out: { id: "f-eq_taper_out", quantity: "time", required: false, when: history, range: () => [0, 600],
        placeholder: () => 0.5 },
      eq_mass: { id: "f-eq_mass", quantity: "mass", required: false, openLow: true,
        when: () => history() && this.fromGroundMotion(), range: () => [0, MASS_MAX_KG] },
      hy_base_mass: { id: "f-hy_base_mass", quantity: "mass", required: true, openLow: true, when: hybrid,
        range: () => [0, MASS_MAX_KG] },
      hy_damping: { id: "f-hy_damping", quantity: "percent", required: true, openLow: true, when: hybrid,
        range: () => [0, 0.99] },
      hy_limit_j: { id: "f-hy_limit_j", quantity: "energy", required: false, when: hybrid, range: () => [0, 1e9],
        placeholder: () => DEFAULT_STABILITY.limit_j },
      hy_relative: { id: "f-hy_relative", quantity: "percent", required: false, when: hybrid, range: () => [0, 100],
        placeholder: () => DEFAULT_STABILITY.relative_limit },
    };
  }

  /** The storey rows (mass, spring) as fields of the set-up: n storeys, values kept where they exist. */
  setStoreys(n, values = null) {
    n = Math.max(1, Math.min(MAX_STOREYS, n));
    const fields = this.setup.fields;
    const box = $("hy-storeys");
    const hybrid = () => this.kind() === "hybrid";
    for (let i = this.storeys; i < n; i++) {
      const row = el("div", { class: "storey-row", "data-storey": String(i + 1) });
      row.append(el("span", { class: "storey-name", text: `storey ${i + 1}` }));
      for (const [key, label, quantity, title] of [
        [`hy_m_${i}`, "mass", "mass", `mass of storey ${i + 1}`],
        [`hy_k_${i}`, i === 0 ? "spring to the base" : `spring to storey ${i}`, "stiffness",
          `storey ${i + 1}'s spring (shear stiffness) to the ${i === 0 ? "base slab" : `storey below`}`],
      ]) {
        const input = el("input", { id: `f-${key}`, type: "text", inputmode: "decimal" });
        row.append(el("label", { class: "field", "data-field": key, title }, `${label} `,
          el("span", { class: "unit" }), input, el("small", { class: "range" }), el("small", { class: "msg" })));
        fields[key] = { id: `f-${key}`, quantity, required: true, openLow: true, when: hybrid, storey: i,
          range: () => [0, quantity === "mass" ? MASS_MAX_KG : 1e12] };
      }
      box.append(row);
    }
    for (let i = n; i < this.storeys; i++) {
      delete fields[`hy_m_${i}`];
      delete fields[`hy_k_${i}`];
      delete this.setup.values[`hy_m_${i}`];
      delete this.setup.values[`hy_k_${i}`];
      const row = box.querySelector(`.storey-row[data-storey="${i + 1}"]`);
      if (row) row.remove();
    }
    this.storeys = n;
    if (values) {
      values.masses_kg.forEach((m, i) => i < n && this.setup.setField(`hy_m_${i}`, m));
      values.stiffness_n_per_m.forEach((k, i) => i < n && this.setup.setField(`hy_k_${i}`, k));
    }
    $("hy-storey-count").textContent = `${n} storey${n > 1 ? "s" : ""}`;
    $("hy-remove").disabled = n <= 1;
    $("hy-add").disabled = n >= MAX_STOREYS;
  }

  /** A building into the fields (the defaults, a structure file, the running test's). */
  setBuilding(b) {
    this.setStoreys(b.masses_kg.length);
    this.setStoreys(b.masses_kg.length, b);
    this.setup.setField("hy_base_mass", b.base_mass_kg);
    this.setup.setField("hy_damping", b.damping_ratio);
  }

  /** The shipped ground motions from the service (before init). */
  async loadPresets() {
    const list = await api.get("/api/ground-motions");
    presets = list.map((g) => ({ name: g.name, duration_s: g.duration_s, pga_g: g.measured.pga_g, words: g.description }));
  }

  init() {
    const sel = $("f-eq_preset");
    sel.innerHTML = "";
    for (const p of presets) {
      sel.append(el("option", { value: p.name, text: `${p.name} (${fmtDuration(p.duration_s)}, PGA ${sigDigits(p.pga_g, 2)} g: ${p.words})` }));
    }
    this.setBuilding(DEMO_BUILDING);
    this.setup.setField("eq_scale", 0.5);
    $("hy-add").addEventListener("click", () => {
      const last = this.storeys - 1;
      const v = this.setup.values;
      this.setStoreys(this.storeys + 1);
      this.setup.setField(`hy_m_${last + 1}`, num(v[`hy_m_${last}`]) ? v[`hy_m_${last}`] : null);
      this.setup.setField(`hy_k_${last + 1}`, num(v[`hy_k_${last}`]) ? v[`hy_k_${last}`] : null);
      this.changed();
    });
    $("hy-remove").addEventListener("click", () => {
      this.setStoreys(this.storeys - 1);
      this.changed();
    });
    $("hy-demo").addEventListener("click", () => {
      this.setBuilding(DEMO_BUILDING);
      this.structureNote("the demo building of docs/examples/structure_3_storey.json", "msg");
      this.changed();
    });
    $("hy-file-clear").addEventListener("click", () => {
      this.structureNote("structure file cleared: the building is the one in the fields", "msg");
      this.changed();
    });
    $("hy-file").addEventListener("change", (ev) => this.readStructureFile(ev.target));
    $("f-eq_file").addEventListener("change", (ev) => this.readRecordFile(ev.target));
    $("f-eq_check_units").addEventListener("change", () => this.checkUnitsChanged());
  }

  changed() {
    this.setup.renderFieldMeta();
    this.setup.formChanged();
  }

  /** Show the blocks of the chosen kind and source. */
  show() {
    const kind = this.kind();
    $("eq-fields").classList.toggle("hidden", !kind);
    if (!kind) return;
    const dispOption = $("f-eq_source").querySelector("option[value='disp_csv']");
    dispOption.disabled = kind === "hybrid";
    if (kind === "hybrid" && $("f-eq_source").value === "disp_csv") $("f-eq_source").value = "preset";
    const source = this.source();
    $("eq-preset-row").classList.toggle("hidden", source !== "preset");
    $("eq-file-row").classList.toggle("hidden", source === "preset");
    $("eq-unit-row").classList.toggle("hidden", source !== "acc_csv");
    $("eq-check-units-row").classList.toggle("hidden", source !== "acc_csv");
    $("eq-history-only").classList.toggle("hidden", kind !== "history");
    $("eq-mass-row").classList.toggle("hidden", !(kind === "history" && this.fromGroundMotion()));
    $("hy-fields").classList.toggle("hidden", kind !== "hybrid");
    $("eq-kind-note").textContent = kind === "history"
      ? "The table follows a displacement history: a ground motion through the isolator's demand model (a rigid " +
        "mass on its Bouc-Wen model), or a displacement history itself. Checked sample by sample against the rig."
      : "Real-time hybrid simulation: the building above the isolator is computed in real time, the isolator on " +
        "the rig is the physical specimen; its measured force drives the next command. The envelope is checked on " +
        "the structure's full-numerical prediction.";
    $("f-eq_scale").closest(".field").title = this.fromGroundMotion()
      ? "the ground acceleration times this factor, before the isolator's model (the isolator is nonlinear)"
      : "the displacement history times this factor";
    this.renderFileNote();
  }

  /** A record file chosen: read it in the browser, say what was read (rows, step, duration, peak, unit). */
  readRecordFile(input) {
    const file = input.files && input.files[0];
    const kind = this.source() === "disp_csv" ? "displacement" : "acceleration";
    if (!file) { // the choice was cleared: no file, not the last one read
      this.seq = (this.seq || 0) + 1;
      this.files[kind] = null;
      this.renderFileNote();
      this.changed();
      return;
    }
    if (file.size > MAX_FILE_BYTES) {
      this.seq = (this.seq || 0) + 1; // a read of an earlier file still under way is not this choice
      this.files[kind] = { name: file.name, record: { ok: false, error: `${file.name} is ${(file.size / 1e6).toFixed(1)} MB, more than 12 MB` } };
      this.renderFileNote();
      this.changed();
      return;
    }
    const reader = new FileReader();
    const seq = (this.seq = (this.seq || 0) + 1);
    const done = (record) => {
      if (seq !== this.seq) return; // another file was chosen meanwhile
      this.files[kind] = { name: file.name, record, seq };
      this.renderFileNote();
      this.changed();
    };
    reader.onload = () => {
      if (kind === "acceleration" && /\.at2$/i.test(file.name)) {
        this.files[kind] = { name: file.name, record: { ok: false, pending: true, error: "being read by the service..." }, seq };
        this.renderFileNote();
        readAt2(file.name, reader.result, this.checkUnits()).then((record) => {
          done(record);
          if (seq === this.seq) this.files[kind].at2Text = reader.result; // read again if the unit check changes
        });
      } else done(parseRecordCsv(reader.result, kind));
    };
    reader.onerror = () => done({ ok: false, error: `${file.name} could not be read` });
    reader.readAsText(file);
  }

  /**
   * What the structure file gave, under its buttons. `failed`: it could not be read, and Start waits until a file
   * is read, the demo building is chosen or the file is cleared (never the default building in its place).
   */
  structureNote(text, cls, failed = false) {
    const note = $("hy-file-note");
    const wait = "Start waits until a structure file is read, or this one is cleared.";
    note.textContent = failed ? `${text.replace(/\.$/, "")}. ${wait}` : text;
    note.className = cls;
    this.structureError = failed ? text : "";
    $("hy-file-clear").classList.toggle("hidden", !failed);
  }

  /** A structure file (JSON, the CLI's format): its building into the fields, or why not. */
  readStructureFile(input) {
    const file = input.files && input.files[0];
    if (!file) return;
    const reader = new FileReader();
    reader.onload = () => {
      input.value = "";
      let data;
      try { data = JSON.parse(reader.result); } catch (e) {
        this.structureNote(`${file.name}: not JSON (${e.message}); the fields are unchanged`, "msg bad", true);
        this.changed();
        return;
      }
      const bad = [];
      if (!data || typeof data !== "object") bad.push("not an object");
      else {
        if (!num(data.base_mass_kg)) bad.push("base_mass_kg (a number, kg)");
        if (!Array.isArray(data.masses_kg) || !data.masses_kg.length || !data.masses_kg.every(num)) bad.push("masses_kg (numbers, kg)");
        if (!Array.isArray(data.stiffness_n_per_m) || !data.stiffness_n_per_m.every(num)) bad.push("stiffness_n_per_m (numbers, N/m)");
        else if (Array.isArray(data.masses_kg) && data.stiffness_n_per_m.length !== data.masses_kg.length) {
          bad.push(`as many springs as storeys (${data.masses_kg.length} masses, ${data.stiffness_n_per_m.length} springs)`);
        }
        if (!num(data.damping_ratio)) bad.push("damping_ratio (a number, 0 to 1)");
        if (Array.isArray(data.masses_kg) && data.masses_kg.length > MAX_STOREYS) bad.push(`at most ${MAX_STOREYS} storeys`);
      }
      if (bad.length) {
        this.structureNote(`${file.name} is not a structure file: it needs ${bad.join("; ")}. The fields are unchanged.`,
          "msg bad", true);
        this.changed();
        return;
      }
      this.setBuilding(data);
      this.structureNote(`${file.name}${data.name ? ` (${data.name})` : ""}: ${data.masses_kg.length} storeys read into ` +
        "the fields (SI in the file)", "msg info");
      this.changed();
    };
    reader.readAsText(file);
  }

  /** The acceleration unit: {units (sent, or null: m/s2 assumed by the service), how, problem}. */
  accelerationUnit(record) {
    const chosen = $("f-eq_acc_unit").value;
    const header = record && record.headerUnit;
    if (chosen !== "auto") {
      if (header && header !== chosen && record.at2) {
        return { problem: `a PEER .AT2 file is in ${header} (its header says so) but the unit chosen is ${chosen}: ` +
          "choose 'as the file's header says'" };
      }
      if (header && header !== chosen) {
        return { problem: `the file's header names ${header} ('${record.valueName}') but the unit chosen is ${chosen}: ` +
          "choose the header's unit, or correct the file" };
      }
      return { units: chosen, how: "chosen" };
    }
    if (header) return { units: header, how: record.at2 ? "the .AT2 file's unit" : `from the header '${record.valueName}'` };
    return { units: null, how: "assumed: the header names no unit; choose the unit if it is another" };
  }

  fileProblem() {
    const source = this.source();
    if (source === "preset") return "";
    const kind = source === "disp_csv" ? "displacement" : "acceleration";
    const f = this.files[kind];
    if (!f) return kind === "displacement" ? "a CSV file (time_s, displacement_m)" : "a CSV file (time_s, acceleration) or a PEER .AT2 file";
    if (!f.record.ok) return `${f.name}: ${f.record.error}`;
    if (kind === "acceleration") return this.accelerationUnit(f.record).problem || "";
    if (f.record.headerLength === "mm") {
      return `${f.name}: the header says mm ('${f.record.valueName}'); give the displacement in m (displacement_m)`;
    }
    return "";
  }

  renderFileNote() {
    const note = $("eq-file-note");
    const source = this.source();
    if (source === "preset" || !this.kind()) {
      note.textContent = "";
      return;
    }
    const kind = source === "disp_csv" ? "displacement" : "acceleration";
    const f = this.files[kind];
    $("eq-file-label").textContent = kind === "displacement"
      ? "CSV file: time_s, displacement_m (m)" : "CSV file (time_s, acceleration; unit below) or PEER .AT2 file (in g)";
    if (!f) {
      note.textContent = "no file chosen: the file is read in this browser and sent with the test";
      note.className = "msg";
      return;
    }
    const r = f.record;
    if (!r.ok) {
      note.textContent = `${f.name}: ${r.error}`;
      note.className = r.pending ? "msg" : "msg bad";
      return;
    }
    const span = `${sigDigits(r.dt, 4)} s, ${sigDigits(r.duration, 4)} s`;
    const base = r.at2
      ? `${f.name} (PEER .AT2${r.title ? `: ${r.title}` : ""}): ${r.rows} values at ${span}`
      : `${f.name}: ${r.rows} rows at ${span}` +
        `${r.header ? `; columns '${r.timeName}', '${r.valueName}'` : "; no header (first two columns)"}` +
        `${r.commas ? "; decimal commas read as decimals" : ""}`;
    if (kind === "displacement") {
      const problem = this.fileProblem();
      note.textContent = problem || `${base}; peak ${fmtU("length", r.peak)} (read in m${r.valueName ? "" : ", assumed"})`;
      note.className = `msg ${problem ? "bad" : "info"}`;
      return;
    }
    const u = this.accelerationUnit(r);
    if (u.problem) {
      note.textContent = `${f.name}: ${u.problem}`;
      note.className = "msg bad";
      return;
    }
    const read = u.units || "m/s2";
    const g = (r.peak * UNIT_TO_SI[read]) / G;
    const plausible = g >= PLAUSIBLE_G[0] && g <= PLAUSIBLE_G[1];
    const refused = this.checkUnits() ? "The service will refuse it" : "Taken as read: the unit check is off";
    note.textContent = `${base}; peak ${sigDigits(r.peak, 4)} ${read}${read === "g" ? "" : ` = ${sigDigits(g, 3)} g`}, read as ${read} ` +
      `(${u.how})${plausible ? "" : `: a peak of ${sigDigits(g, 3)} g is outside what ground motions have ` +
      `(${PLAUSIBLE_G[0]} to ${PLAUSIBLE_G[1]} g): the wrong unit? ${refused}`}`;
    note.className = `msg ${plausible ? "info" : "warn"}`;
  }

  /** Problems of the earthquake part that are not a field's (the file, its unit), for the set-up's list. */
  problems() {
    if (!this.kind()) return {};
    const p = this.fileProblem();
    const out = p ? { [this.source() === "disp_csv" ? "displacement file" : "ground motion file"]: p } : {};
    if (this.kind() === "hybrid" && this.structureError) out["structure file"] = this.structureError;
    return out;
  }

  /** The unit check of a ground motion file (check_units): on unless the operator unticked it. */
  checkUnits() {
    return $("f-eq_check_units").checked;
  }

  /** The unit check ticked or unticked: said under it; an .AT2 file is read again by the service with it. */
  checkUnitsChanged() {
    $("eq-check-units-note").textContent = this.checkUnits() ? ""
      : "off (check_units: false): a peak outside 0.005 to 3 g is taken as read; the confirmation asks you to tick it";
    $("eq-check-units-note").className = this.checkUnits() ? "msg" : "msg warn";
    const f = this.files.acceleration;
    if (f && f.at2Text !== undefined) {
      this.seq = (this.seq || 0) + 1;
      const seq = this.seq;
      readAt2(f.name, f.at2Text, this.checkUnits()).then((record) => {
        if (seq !== this.seq) return;
        this.files.acceleration = { ...f, record, seq };
        this.renderFileNote();
        this.changed();
      });
      return;
    }
    this.renderFileNote();
    this.changed();
  }

  /** What the confirmation asks a tick for: the unit check turned off for a ground motion file. */
  warnings(body) {
    const gm = body.profile && body.profile.ground_motion;
    if (!gm || typeof gm !== "object" || gm.check_units !== false) return [];
    const f = this.files.acceleration;
    const g = f && f.record.ok ? this.peakG(f.record) : null;
    return [`the ground motion's unit check is off (check_units: false): its peak${num(g) ? ` of ${sigDigits(g, 3)} g` : ""} ` +
      "is taken as read, even outside 0.005 to 3 g"];
  }

  /** A record's peak in g, in the unit it is read in. */
  peakG(record) {
    const u = this.accelerationUnit(record);
    return u.problem ? null : (record.peak * UNIT_TO_SI[u.units || "m/s2"]) / G;
  }

  /** The ground motion as the API takes it: a preset's name or the inline record. */
  groundMotion() {
    if (this.source() === "preset") return $("f-eq_preset").value;
    const f = this.files.acceleration;
    if (!f || !f.record.ok) return null;
    const gm = { time_s: f.record.time_s, acceleration_m_per_s2: f.record.values };
    const u = this.accelerationUnit(f.record);
    if (u.units) gm.units = u.units;
    if (!this.checkUnits()) gm.check_units = false;
    return gm;
  }

  /** The profile of POST /api/tests (SI), from the values read (v: the set-up's values). */
  profile(v) {
    const kind = this.kind();
    const p = { kind, scale: v.eq_scale };
    if (kind === "history") {
      if (this.source() === "disp_csv") {
        const f = this.files.displacement;
        p.displacement = f && f.record.ok ? { time_s: f.record.time_s, displacement_m: f.record.values } : null;
      } else {
        p.ground_motion = this.groundMotion();
        if (num(v.eq_mass)) p.mass_kg = v.eq_mass;
      }
      if (num(v.eq_taper_in)) p.taper_in_s = v.eq_taper_in;
      if (num(v.eq_taper_out)) p.taper_out_s = v.eq_taper_out;
      return p;
    }
    p.structure = this.building(v);
    p.ground_motion = this.groundMotion();
    const stability = {};
    if (num(v.hy_limit_j)) stability.limit_j = v.hy_limit_j;
    if (num(v.hy_relative)) stability.relative_limit = v.hy_relative;
    if (Object.keys(stability).length) p.stability = stability;
    return p;
  }

  building(v) {
    const masses = [];
    const springs = [];
    for (let i = 0; i < this.storeys; i++) {
      masses.push(v[`hy_m_${i}`] ?? null);
      springs.push(v[`hy_k_${i}`] ?? null);
    }
    return { base_mass_kg: v.hy_base_mass ?? null, masses_kg: masses, stiffness_n_per_m: springs,
      damping_ratio: v.hy_damping ?? null };
  }

  /** The building's total mass (kg) when every mass is valid, else null. */
  totalMass(v) {
    if (this.kind() !== "hybrid") return null;
    const b = this.building(v);
    const all = [b.base_mass_kg, ...b.masses_kg];
    return all.every(num) ? all.reduce((a, x) => a + x, 0) : null;
  }

  /** The input (id) a refusal of the service names (profile.scale, profile.structure.masses_kg[1], ...). */
  fieldInput(field) {
    const f = String(field || "");
    if (!/^profile\b/.test(f) && !/^(scale|history|units)$/.test(f)) return null;
    let m = /masses_kg\[(\d+)\]/.exec(f);
    if (m) return $(`f-hy_m_${m[1]}`);
    m = /stiffness_n_per_m\[(\d+)\]/.exec(f);
    if (m) return $(`f-hy_k_${m[1]}`);
    if (/base_mass_kg/.test(f)) return $("f-hy_base_mass");
    if (/damping_ratio/.test(f)) return $("f-hy_damping");
    if (/limit_j/.test(f)) return $("f-hy_limit_j");
    if (/relative_limit/.test(f)) return $("f-hy_relative");
    if (/units/.test(f)) return $("f-eq_acc_unit");
    if (/taper_in/.test(f)) return $("f-eq_taper_in");
    if (/taper_out/.test(f)) return $("f-eq_taper_out");
    if (/mass_kg/.test(f)) return $("f-eq_mass");
    if (/ground_motion\.|displacement\./.test(f)) return $("f-eq_file");
    if (/ground_motion$/.test(f)) return this.source() === "preset" ? $("f-eq_preset") : $("f-eq_file");
    if (/history|scale/.test(f)) return $("f-eq_scale"); // beyond the envelope: the scale is what to change
    if (/structure/.test(f)) return $("f-hy_base_mass");
    return null;
  }

  /** The running test's earthquake profile (the record's description) into the form, as far as it can be. */
  follow(p) {
    $("f-profile").value = p.kind;
    const gm = p.ground_motion || {};
    if (p.displacement) $("f-eq_source").value = "disp_csv";
    else if (gm.preset) {
      $("f-eq_source").value = "preset";
      $("f-eq_preset").value = gm.preset;
    } else $("f-eq_source").value = "acc_csv";
    if (num(p.scale)) this.setup.setField("eq_scale", p.scale);
    if (p.kind === "history") {
      this.setup.setField("eq_taper_in", num(p.taper_in_s) ? p.taper_in_s : null);
      this.setup.setField("eq_taper_out", num(p.taper_out_s) ? p.taper_out_s : null);
      this.setup.setField("eq_mass", p.mass_from === "given" && num(p.mass_kg) ? p.mass_kg : null);
    } else if (p.structure) {
      this.setBuilding(p.structure);
      const s = p.stability || {};
      this.setup.setField("hy_limit_j", num(s.limit_j) ? s.limit_j : null);
      this.setup.setField("hy_relative", num(s.relative_limit) ? s.relative_limit : null);
    }
    const inline = p.displacement || (gm.inline ? gm : null);
    $("eq-file-note").textContent = inline ? `the running test's inline record (${inline.samples} samples at ` +
      `${sigDigits(inline.dt_s, 4)} s${inline.units ? `, ${inline.units}: ${inline.units_how}` : ""})` : "";
  }

  // ---------------------------------------------------------------------------------------- confirmation

  /** Rows of the confirmation that say what the earthquake profile is (the check's `profile` where given). */
  summaryRows(body, check) {
    const p = body.profile;
    const built = (check && check.profile) || {};
    const rows = [];
    const gmWords = () => {
      if (typeof p.ground_motion === "string") {
        const preset = presets.find((x) => x.name === p.ground_motion) || {};
        const info = built.ground_motion || {};
        const pga = num(info.pga_g) ? info.pga_g : preset.pga_g;
        const dur = num(info.duration_s) ? info.duration_s : preset.duration_s;
        return [`ground motion ${p.ground_motion} x ${p.scale}`, `synthetic (seeded, shipped with the service), ` +
          `${fmtDuration(dur)}, PGA ${sigDigits(pga, 3)} g, scaled: ${sigDigits(pga * p.scale, 3)} g`];
      }
      const f = this.files.acceleration;
      const u = f ? this.accelerationUnit(f.record) : {};
      const r = f ? f.record : {};
      const peakG = r.ok ? (r.peak * UNIT_TO_SI[u.units || "m/s2"]) / G : NaN;
      return [`ground motion from ${f ? f.name : "a file"} x ${p.scale}`, `${r.rows} samples at ${sigDigits(r.dt, 4)} s, ` +
        `read as ${u.units || "m/s2"} (${u.how}); PGA ${sigDigits(peakG, 3)} g, scaled: ${sigDigits(peakG * p.scale, 3)} g`];
    };
    if (p.kind === "history") {
      if (p.displacement) {
        const f = this.files.displacement;
        rows.push(["motion", `time history: displacement from ${f ? f.name : "a file"} x ${p.scale}`,
          `${f ? f.record.rows : "?"} samples at ${f ? sigDigits(f.record.dt, 4) : "?"} s, resampled to the 1 ms control period`]);
      } else {
        const [what, note] = gmWords();
        rows.push(["motion", `time history: ${what}`, note]);
        rows.push(["demand model", num(built.mass_kg) ? `${fmtU("mass", built.mass_kg)} on ${body.isolator}` : `on ${body.isolator}`,
          `a rigid mass on the isolator's Bouc-Wen model${built.mass_from ? ` (${built.mass_from})` : ""}: its displacement is the target`]);
      }
      const tin = num(p.taper_in_s) ? p.taper_in_s : 0.5;
      const tout = num(p.taper_out_s) ? p.taper_out_s : 0.5;
      rows.push(["tapers", `${tin} s in, ${tout} s out`, "raised cosines: the table starts and ends at rest"]);
      return rows;
    }
    const s = p.structure;
    const periods = Array.isArray(built.fixed_base_periods_s)
      ? `; fixed-base periods ${built.fixed_base_periods_s.map((x) => sigDigits(x, 3)).join(", ")} s` : "";
    rows.push(["motion", "hybrid simulation (RTHS)", "the building is computed in real time, the isolator is the specimen on the rig"]);
    rows.push(["building", `base ${fmtU("mass", s.base_mass_kg)} + ${s.masses_kg.length} storeys`,
      `masses ${s.masses_kg.map((m) => fmtU("mass", m)).join(", ")}; springs ${s.stiffness_n_per_m.map((k) => fmtU("stiffness", k)).join(", ")}; ` +
      `damping ${fmtU("percent", s.damping_ratio)}; total ${fmtU("mass", [s.base_mass_kg, ...s.masses_kg].reduce((a, x) => a + x, 0))}${periods}`]);
    const [what, note] = gmWords();
    rows.push(["ground motion", what, note]);
    if (num(built.predicted_peak_base_displacement_m)) {
      rows.push(["predicted base displacement", `\u00b1${fmtU("length", built.predicted_peak_base_displacement_m)}`,
        "the structure's full-numerical reference (the test's own response differs by its tracking)"]);
    }
    const st = { ...DEFAULT_STABILITY, ...(p.stability || {}) };
    rows.push(["stability monitor", `trips at E_err > max(${fmtU("energy", st.limit_j)}, ${fmtU("percent", st.relative_limit)} of the input energy)`,
      "E_err: the energy the tracking error adds to the loop; a trip closes the valve (0 V in 0.1 s), the test ends aborted"]);
    return rows;
  }
}

/** The unit label of a quantity in parentheses, for the field labels: "(kg)", "(kN/mm)". */
export function unitLabel(quantity) {
  return `(${unit(quantity)})`;
}
