// Set-up panel: isolator (with its Bouc-Wen parameters, and a form to add one), supply pressure, sine profile,
// controller, the rig envelope for the current choice (asked from the API before Start), Start and Stop.

import { api, ApiError, errorField, operatorPost } from "./api.js";
import { fmtPeriod, rigKind } from "./rig.js";
import { el, showAlert } from "./ui.js";

const PARAMS = [
  ["rho_bw_per_m", "rho_BW", "1/m"],
  ["sigma_bw", "sigma_BW", "-"],
  ["n", "n", "-"],
  ["kd_n_per_m", "k_d", "N/m"],
  ["kw_n", "k_w", "N"],
];
// API field -> input id (amplitude is shown in mm)
const FIELD_INPUT = {
  isolator: "f-isolator",
  supply_bar: "f-supply_bar",
  vertical_load_n: "f-vertical_load_kn",
  amplitude_m: "f-amplitude_mm",
  frequency_hz: "f-frequency_hz",
  cycles: "f-cycles",
  taper_cycles: "f-taper_cycles",
  controller: "f-controller",
  speed: "f-speed",
};

const $ = (id) => document.getElementById(id);

function listOf(data, key) {
  if (Array.isArray(data)) return data;
  if (data && Array.isArray(data[key])) return data[key];
  return [];
}

export class SetupPanel {
  constructor({ live }) {
    this.live = live;
    this.isolators = [];
    this.rig = null;
    this.checkSeq = 0;
    this.checkTimer = null;
    this.lastCheck = { ok: false, message: "" };
  }

  async init() {
    await Promise.all([this.loadRig(), this.loadIsolators(), this.findCheckEndpoint()]);
    const form = $("setup-form");
    form.addEventListener("input", (ev) => {
      if (ev.target.closest("#iso-form")) return;
      this.scheduleCheck();
    });
    form.addEventListener("change", (ev) => {
      if (ev.target.closest("#iso-form")) return;
      if (ev.target.id === "f-isolator") this.showIsolator();
      this.scheduleCheck();
    });
    form.addEventListener("submit", (ev) => {
      ev.preventDefault();
      this.start();
    });
    $("stop").addEventListener("click", () => this.stop());
    $("iso-save").addEventListener("click", () => this.saveIsolator());
    this.scheduleCheck(0);
  }

  /** Does the service validate a test without creating it (POST /api/tests/check)? Ask its OpenAPI once. */
  async findCheckEndpoint() {
    try {
      const spec = await api.get("/openapi.json");
      this.checkEndpoint = Boolean(spec && spec.paths && spec.paths["/api/tests/check"]);
    } catch {
      this.checkEndpoint = false;
    }
  }

  async loadRig() {
    try {
      this.rig = await api.get("/api/rig");
    } catch {
      this.rig = null;
    }
    const ctl = $("f-controller");
    const rig = this.rig || {};
    if (Array.isArray(rig.controllers)) this.live.setControllers(rig.controllers.filter((c) => typeof c === "object"));
    const names = rig.controllers
      ? rig.controllers.map((c) => (typeof c === "string" ? c : c.name))
      : ["mrac", "pid"];
    const def = rig.default_controller || names[0];
    ctl.innerHTML = "";
    for (const n of names) ctl.append(el("option", { value: n, text: n === def ? `${n} (default)` : n }));
    ctl.value = def;
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
  }

  /** The rig's link (RigLink): explain before Start why a test would fail on a rig that does not answer. */
  showRigLink(link) {
    const box = $("rig-warning");
    if (!box) return;
    const l = link.link || {};
    const down = link.kind === "udp" && link.connected() === "false";
    box.classList.toggle("hidden", !down);
    box.dataset.state = down ? "down" : "ok";
    if (!down) return;
    const arm = link.info && typeof link.info.arm_timeout_s === "number" ? fmtPeriod(link.info.arm_timeout_s) : "";
    box.innerHTML = "";
    box.append(el("b", { text: "Rig not connected: Start would fail." }),
      el("div", { text: `${link.name()}: ${l.detail || "no answer"}. The service arms the rig at Start and gives ` +
        `up${arm ? ` after ${arm}` : ""} without an answer; check that the rig (or isorig rig-emulator) runs ` +
        "and is reachable." }));
  }

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
      const user = iso.user_defined || iso.source === "user" || iso.kind === "user" || iso.preset === false;
      groups[user ? "user" : "preset"].append(el("option", { value: iso.name, text: iso.name }));
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

  showIsolator() {
    const iso = this.isolators.find((i) => i.name === $("f-isolator").value);
    const table = $("isolator-params");
    table.innerHTML = "";
    if (!iso) return;
    for (const [key, label, unit] of PARAMS) {
      const v = iso[key];
      table.append(el("tr", {}, el("td", { text: `${label} (${unit})` }),
        el("td", { text: typeof v === "number" ? String(+v.toPrecision(6)) : "-" })));
    }
    if (iso.description) table.append(el("tr", {}, el("td", { text: "note" }), el("td", { text: iso.description })));
    this.showVerticalLoad();
  }

  /** The vertical load field: its range (the jack) and its default (the isolator's design load, else the rig's). */
  showVerticalLoad() {
    const env = (this.rig && this.rig.envelope) || {};
    const iso = this.isolators.find((i) => i.name === $("f-isolator").value) || {};
    const max = typeof env.max_vertical_load_n === "number" ? env.max_vertical_load_n : 850e3;
    const fallback = typeof env.vertical_load_n_default === "number" ? env.vertical_load_n_default : 125e3;
    const def = typeof iso.design_vertical_load_n === "number" ? iso.design_vertical_load_n : fallback;
    const kn = (n) => String(+(n / 1e3).toPrecision(6));
    $("f-vertical_load_kn").placeholder = kn(def);
    $("f-vertical_load_kn").max = kn(max);
    $("vertical-load-note").textContent = `0 to ${kn(max)} kN; empty: ${kn(def)} kN` +
      (typeof iso.design_vertical_load_n === "number" ? " (the isolator's design load)" : "");
  }

  /** The request body of POST /api/tests from the form (SI units; amplitude converted from mm). */
  body() {
    const num = (id) => {
      const raw = $(id).value.trim();
      return raw === "" ? null : Number(raw);
    };
    const amp = num("f-amplitude_mm");
    const body = {
      isolator: $("f-isolator").value,
      supply_bar: num("f-supply_bar"),
      controller: $("f-controller").value,
      vertical_load_n: num("f-vertical_load_kn") === null ? null : num("f-vertical_load_kn") * 1e3,
      profile: {
        kind: "sine",
        amplitude_m: amp === null ? null : amp / 1000,
        frequency_hz: num("f-frequency_hz"),
        cycles: num("f-cycles"),
        taper_cycles: num("f-taper_cycles"),
      },
    };
    body.speed = this.realTimeOnly ? 1 : num("f-speed");
    return body;
  }

  markField(field) {
    for (const id of Object.values(FIELD_INPUT)) $(id).classList.remove("invalid");
    const key = field ? String(field).split(".").pop() : "";
    if (FIELD_INPUT[key]) $(FIELD_INPUT[key]).classList.add("invalid");
  }

  scheduleCheck(delay = 250) {
    clearTimeout(this.checkTimer);
    this.checkTimer = setTimeout(() => this.check(), delay);
  }

  /** What the rig envelope (GET /api/rig) says about the form, without asking the service: a fallback. */
  staticCheck(body) {
    const env = (this.rig && this.rig.envelope) || {};
    const p = body.profile;
    const bad = (field, value, limit, message) => ({ ok: false, field, message, data: { field, value, limit } });
    const num = (v) => typeof v === "number" && isFinite(v);
    if (!num(body.supply_bar)) return bad("supply_bar", body.supply_bar, "a number", "supply pressure is missing");
    if (num(env.supply_bar_min) && num(env.supply_bar_max) &&
        (body.supply_bar < env.supply_bar_min || body.supply_bar > env.supply_bar_max)) {
      return bad("supply_bar", body.supply_bar, `${env.supply_bar_min}-${env.supply_bar_max} bar`,
        `supply_bar = ${body.supply_bar} bar is outside ${env.supply_bar_min}-${env.supply_bar_max} bar`);
    }
    const maxLoad = num(env.max_vertical_load_n) ? env.max_vertical_load_n : 850e3;
    if (body.vertical_load_n !== null && (!num(body.vertical_load_n) || body.vertical_load_n < 0 || body.vertical_load_n > maxLoad)) {
      return bad("vertical_load_n", body.vertical_load_n, `0-${maxLoad / 1e3} kN`,
        `vertical load ${body.vertical_load_n / 1e3} kN is outside 0-${maxLoad / 1e3} kN (the jack)`);
    }
    if (!num(p.amplitude_m) || p.amplitude_m <= 0) return bad("amplitude_m", p.amplitude_m, "> 0", "amplitude must be a positive number");
    if (num(env.stroke_m) && p.amplitude_m > env.stroke_m) {
      return bad("amplitude_m", p.amplitude_m, `stroke ${env.stroke_m * 1000} mm`,
        `amplitude ${(p.amplitude_m * 1000).toFixed(1)} mm is beyond the stroke of +-${(env.stroke_m * 1000).toFixed(0)} mm`);
    }
    if (!num(p.frequency_hz) || p.frequency_hz <= 0) return bad("frequency_hz", p.frequency_hz, "> 0", "frequency must be a positive number");
    if (num(env.max_frequency_hz) && p.frequency_hz > env.max_frequency_hz) {
      return bad("frequency_hz", p.frequency_hz, `${env.max_frequency_hz} Hz`,
        `frequency ${p.frequency_hz} Hz is above ${env.max_frequency_hz} Hz`);
    }
    if (!Number.isInteger(p.cycles) || p.cycles < 1) return bad("cycles", p.cycles, "a whole number >= 1", "cycles must be a whole number >= 1");
    if (!Number.isInteger(p.taper_cycles) || p.taper_cycles < 0 || 2 * p.taper_cycles > p.cycles) {
      return bad("taper_cycles", p.taper_cycles, "<= cycles / 2", `taper cycles must be a whole number between 0 and ${Math.floor(p.cycles / 2)}`);
    }
    return { ok: null, message: "Basic limits fine; the service checks the full envelope (pump flow, force, valve) at Start." };
  }

  /** Ask the API what the envelope allows for the current choice, and explain a refusal before Start. */
  async check() {
    const seq = ++this.checkSeq;
    const box = $("envelope");
    const body = this.body();
    let result = this.staticCheck(body);
    if (result.ok !== false && this.checkEndpoint !== false) {
      try {
        const data = await api.postQuiet("/api/tests/check", body);
        this.checkEndpoint = true;
        result = { ok: data.ok !== false, data, message: data.message || data.detail };
      } catch (e) {
        if (e instanceof ApiError && e.status === 422) {
          result = { ok: false, message: e.message, field: errorField(e.detail), data: e.detail };
        } else if (e instanceof ApiError && (e.status === 404 || e.status === 405 || e.status === 401)) {
          this.checkEndpoint = false; // this service has no check endpoint: keep the static check
        } else {
          result = { ok: null, message: `envelope check not available (${e.message})` };
        }
      }
    }
    if (seq !== this.checkSeq) return; // a newer check is on its way
    this.lastCheck = result;
    const d = result.data || {};
    const env = (this.rig && this.rig.envelope) || {};
    const limits = [];
    if (typeof d.max_amplitude_m === "number") limits.push(`amplitude up to ${(d.max_amplitude_m * 1000).toFixed(1)} mm at this frequency`);
    if (typeof d.max_frequency_hz === "number") limits.push(`frequency up to ${d.max_frequency_hz.toPrecision(3)} Hz at this amplitude`);
    if (typeof d.max_force_n === "number") limits.push(`force up to ${(d.max_force_n / 1000).toFixed(0)} kN at this pressure`);
    if (!limits.length && typeof env.stroke_m === "number") {
      limits.push(`stroke +-${(env.stroke_m * 1000).toFixed(0)} mm`, `supply ${env.supply_bar_min}-${env.supply_bar_max} bar`,
        `frequency <= ${env.max_frequency_hz} Hz`, `pump ${Math.round(env.pump_max_flow_l_per_min)} l/min`);
    }
    box.innerHTML = "";
    if (result.ok === false) {
      box.className = "envelope refused";
      let text = result.message || "outside the rig envelope";
      if (d.limit && !text.includes(String(d.limit))) text += ` (limit: ${d.limit})`;
      box.append(el("div", { text: `Refused: ${text}` }));
      this.markField(result.field || d.field);
    } else if (result.ok === true) {
      box.className = "envelope ok";
      box.append(el("div", { text: result.message || "Within the rig envelope." }));
      this.markField("");
    } else {
      box.className = "envelope";
      box.append(el("div", { text: result.message }));
      this.markField("");
    }
    if (limits.length) box.append(el("div", { class: "muted", text: `Rig: ${limits.join("; ")}.` }));
    box.dataset.state = result.ok === false ? "refused" : result.ok ? "ok" : "unknown";
  }

  message(text, kind = "") {
    const m = $("setup-message");
    m.textContent = text;
    m.className = `message ${kind}`;
  }

  /** Show a refusal of the service (422 at Start) where the envelope is explained. */
  showRefusal(e) {
    this.checkSeq++; // a pending check must not overwrite it
    clearTimeout(this.checkTimer);
    const box = $("envelope");
    box.innerHTML = "";
    box.className = "envelope refused";
    box.dataset.state = "refused";
    box.append(el("div", { text: `Refused by the service: ${e.message}` }));
    this.markField(errorField(e.detail));
  }

  async start() {
    const body = this.body();
    const pre = this.staticCheck(body);
    if (pre.ok === false) {
      this.scheduleCheck(0);
      this.message(`Refused: ${pre.message}`, "error");
      return;
    }
    this.message("starting the test...");
    let record;
    try { // created and started in one request: a start the service refuses leaves no test behind
      record = await operatorPost("/api/tests?start=true", body);
    } catch (e) {
      if (e instanceof ApiError && e.status === 422) {
        this.showRefusal(e);
        this.message("Refused by the service: the reason is above.", "error");
      } else {
        this.message(`Refused: ${e.message}`, "error");
      }
      return;
    }
    this.message(`Test #${record.id} started.`, "ok");
    location.hash = "#/live";
  }

  async stop() {
    const id = await runningTestId(this.live);
    if (id === null) {
      this.message("No test is running.", "error");
      return;
    }
    try {
      await operatorPost(`/api/tests/${id}/stop`);
      this.message(`Test #${id}: stopping with a ramp-out.`, "ok");
    } catch (e) {
      this.message(`Stop refused: ${e.message}`, "error");
    }
  }

  async saveIsolator() {
    const out = $("iso-error");
    out.textContent = "";
    const body = { name: $("iso-name").value.trim(), description: $("iso-description").value.trim() };
    for (const [key] of PARAMS) {
      const raw = $(`iso-${key}`).value.trim();
      body[key] = raw === "" ? null : Number(raw);
    }
    try {
      const saved = await operatorPost("/api/isolators", body);
      await this.loadIsolators(saved && saved.name ? saved.name : body.name);
      this.scheduleCheck(0);
      out.textContent = "";
      this.message(`Isolator ${body.name} saved.`, "ok");
    } catch (e) {
      out.textContent = e.message;
    }
  }
}

/** The id of the test the rig runs now: from the live stream, else asked from the API. */
export async function runningTestId(live) {
  if (live && live.testId !== null && (live.status === "running" || live.status === "ready" ||
      live.status === "stopping")) {
    return live.testId;
  }
  try {
    const list = listOf(await api.get("/api/tests?status=running"), "tests");
    if (list.length) return list[0].id;
  } catch { /* fall through */ }
  return live && live.testId !== null && live.status === "running" ? live.testId : null;
}
