// The Commissioning page (#/commission, issue 20): measure the rig the controller is told of. A form (supply,
// specimen, vertical load, the stroke and velocity bounds, in the console's units), what will move and why
// before Start (POST /api/commissioning/check: the service's own figures), a confirmation, the run's progress
// (its phase is the as_hat column: 4 valve null, 0 valve sweeps, 1 dither, 2 return, 3 rest; ar_hat the dither's gate; then
// the service fits the record), then the result (GET /api/commissioning/{id}): the verdict with each reason,
// fitted against declared values with their uncertainties, the measured frequency response against the fitted
// model's, the fit's figures, the rig file to download and "Make this the service's rig"
// (POST /api/commissioning/{id}/apply).

import uPlot from "../vendor/uplot/uPlot.esm.js";
import { NewestOnly, account, api, askLogin, errorField, operatorPost, refreshAccount } from "./api.js";
import { confirmDialog, summaryTable } from "./dialogs.js";
import { parseNumber } from "./parse.js";
import { onState, sourceWords, state, tablePosition, testRunning } from "./state.js";
import { el, fmtDuration, fmtTime, showAlert } from "./ui.js";
import { factorIn, fmtU, inputText, onUnits, sigDigits, system, toSI, unit, unitIn } from "./units.js";
import { bindAccountField } from "./who.js";

const $ = (id) => document.getElementById(id);
const num = (v) => typeof v === "number" && Number.isFinite(v);
const PHASES = ["valve sweeps", "dither", "return", "rest", "valve null"]; // the excitation's as_hat (sim.controllers.excitation)
const STEPS = ["valve sweeps", "dither", "return", "fitting", "result"];
const FINAL = new Set(["completed", "stopped", "aborted", "interrupted", "failed"]);
const BUSY = new Set(["ready", "running", "fitting"]);
const DEFAULTS = { supply: 100e5, stroke: 0.002, velocity: 0.02 }; // SI: the service's defaults
const RANGES = { stroke: [2e-4, 0.01], velocity: [0.01, 0.1] }; // sim.commission.identify STROKE/VELOCITY_RANGE

// A quantity of the console's (units.js): its [unit, factor from SI] per unit system, as every page shows it.
const asConsole = (quantity) => Object.fromEntries(["lab", "si"].map((sys) => [sys, [unitIn(quantity, sys), factorIn(quantity, sys)]]));

// Each fitted quantity as a person reads it: label, and [unit, factor from SI] per unit system.
const PARAMS = {
  flow_gain_m3_per_s_v_sqrt_pa: ["valve flow gain K_q", { lab: ["(l/min)/(V\u221abar)", 6e4 * Math.sqrt(1e5)], si: ["m3/(s V\u221aPa)", 1] }],
  driver_gain_negative: ["negative-side gain k_en", { lab: ["-", 1], si: ["-", 1] }],
  dead_zone_v: ["valve dead zone (half width; negative: underlap)", { lab: ["V", 1], si: ["V", 1] }],
  driver_offset_v: ["valve null offset", { lab: ["V", 1], si: ["V", 1] }],
  valve_play_v: ["valve play (backlash, full width)", { lab: ["V", 1], si: ["V", 1] }],
  valve_natural_frequency_rad_s: ["valve natural frequency", { lab: ["Hz", 1 / (2 * Math.PI)], si: ["rad/s", 1] }],
  valve_damping_ratio: ["valve damping ratio", { lab: ["-", 1], si: ["-", 1] }],
  bulk_modulus_pa: ["oil bulk modulus (the oil column)", { lab: ["MPa", 1e-6], si: ["Pa", 1] }],
  position_latency_s: ["position sensor delay", { lab: ["ms", 1e3], si: ["s", 1] }],
  mass_kg: ["moving mass", asConsole("mass")],
  friction_force_n: ["friction (at this vertical load)", asConsole("force")],
  viscous_n_s_per_m: ["viscous damping", { lab: ["kN s/m", 1e-3], si: ["N s/m", 1] }],
  presliding_m: ["pre-sliding distance (Dahl law; 0: Coulomb's)", asConsole("length")],
  bristle_damping_n_s_per_m: ["pre-sliding damping (Dahl law)", { lab: ["kN s/m", 1e-3], si: ["N s/m", 1] }],
};

function paramUnit(name, sys = system()) {
  const p = PARAMS[name];
  return p ? p[1][sys === "si" ? "si" : "lab"] : ["", 1];
}

/** A fitted quantity in the console's units, 4 significant digits (the uncertainty says how many count). */
function paramText(name, si, sig = 4) {
  if (!num(si)) return "-";
  const [, factor] = paramUnit(name);
  return sigDigits(si * factor, sig);
}

/** Decimals that give a fitted quantity's uncertainty two significant digits in the console's unit. */
function decimalsFor(name, std) {
  const s = num(std) && std > 0 ? std * paramUnit(name)[1] : null;
  return s ? Math.max(0, Math.min(8, 1 - Math.floor(Math.log10(s)))) : null;
}

/** A value with the decimals its uncertainty allows (else 4 significant digits). */
function paramWithStd(name, si, std) {
  const dec = decimalsFor(name, std);
  if (!num(si)) return "-";
  return dec === null ? paramText(name, si) : (si * paramUnit(name)[1]).toFixed(dec);
}

/** How far a fitted value is from the declared one: in per cent, or from a declared 0 in the row's unit with the
 * decimals its uncertainty allows ("+4.4 ms"; "0.000000 V" within its uncertainty of 0). */
function changeText(name, si, declared, std) {
  if (!num(declared) || !num(si)) return "-";
  if (declared !== 0) return `${si >= declared ? "+" : ""}${(100 * (si - declared) / Math.abs(declared)).toFixed(1)} %`;
  let text = paramWithStd(name, si - declared, std);
  if (Number(text) === 0) text = text.replace(/^-/, "");
  else if (si > declared) text = `+${text}`;
  const [u] = paramUnit(name);
  return u === "-" ? text : `${text} ${u}`;
}

/** The bounds and conditions typed into the form, in SI ({ok, body} or {ok: false, field, error}). */
function readForm(rigAnswer) {
  const env = (rigAnswer && rigAnswer.envelope) || {};
  const out = {};
  const problems = [];
  const field = (id, quantity, { min, max, required = true, empty = null } = {}) => {
    const input = $(id);
    const p = parseNumber(input.value);
    const label = input.closest("label");
    const msg = label.querySelector(".msg");
    input.classList.remove("invalid");
    msg.textContent = "";
    msg.className = "msg";
    if (p.empty) {
      if (required) {
        problems.push([id, "a value is needed"]);
        input.classList.add("invalid");
        msg.textContent = "a value is needed";
        msg.className = "msg bad";
      }
      return empty;
    }
    if (!p.ok) {
      problems.push([id, p.error]);
      input.classList.add("invalid");
      msg.textContent = p.error;
      msg.className = "msg bad";
      return null;
    }
    const si = quantity ? toSI(quantity, p.value) : p.value;
    if ((num(min) && si < min - 1e-12) || (num(max) && si > max + 1e-12)) {
      const range = `${quantity ? fmtU(quantity, min, { sig: 4 }) : min} to ${quantity ? fmtU(quantity, max, { sig: 4 }) : max}`;
      problems.push([id, `outside ${range}`]);
      input.classList.add("invalid");
      msg.textContent = `outside the allowed ${range}`;
      msg.className = "msg bad";
      return null;
    }
    if (p.comma) {
      msg.textContent = `read as ${p.value}`;
      msg.className = "msg info";
    }
    return si;
  };
  out.supply_bar = field("c-supply", "pressure", { min: (env.supply_bar_min || 10) * 1e5, max: (env.supply_bar_max || 210) * 1e5 });
  if (num(out.supply_bar)) out.supply_bar /= 1e5;
  out.vertical_load_n = field("c-vertical_load", "force", { min: 0, max: env.max_vertical_load_n, required: false });
  out.max_stroke_m = field("c-stroke", "length", { min: RANGES.stroke[0], max: RANGES.stroke[1] });
  out.max_velocity_m_per_s = field("c-velocity", "velocity", { min: RANGES.velocity[0], max: RANGES.velocity[1] });
  out.speed = $("c-speed").disabled ? 1 : field("c-speed", null, { min: 1, max: env.max_speed || 100 });
  out.isolator = $("c-isolator").value || "none";
  out.operator_name = account.name || ""; // the logged-in account (the service records it in any case)
  if (out.vertical_load_n === null) delete out.vertical_load_n;
  return problems.length ? { ok: false, problems, body: out } : { ok: true, body: out };
}

export class CommissionPage {
  constructor({ onApplied } = {}) {
    this.checks = new NewestOnly(); // the form's checks, the commissioning opened, the earlier ones: the newest wins
    this.opens = new NewestOnly();
    this.lists = new NewestOnly();
    this.onApplied = onApplied || (() => {});
    this.rig = null; // GET /api/rig
    this.check = null; // the service's answer for the form as it is
    this.current = null; // GET /api/commissioning/{id} of the commissioning on the page
    this.runId = null; // the commissioning being run or fitted
    this.ws = null;
    this.trace = { t: [], y: [], u: [] }; // the run so far, every 10th sample: time (s), displacement (m), command (V)
    this.phase = null;
    this.gate = null;
    this.progress = 0;
    this.plots = [];
    this.livePlot = null;
    this.polling = null;
    this.visible = false;
    window.__isorigCommission = () => this.describe();
  }

  async init(rigAnswer) {
    this.rig = rigAnswer;
    const form = $("commission-form");
    form.addEventListener("input", () => this.formChanged());
    form.addEventListener("change", () => this.formChanged());
    form.addEventListener("submit", (ev) => {
      ev.preventDefault();
      this.start();
    });
    $("c-stop").addEventListener("click", () => this.stop());
    $("c-apply").addEventListener("click", () => this.apply());
    $("c-supply").value = inputText("pressure", DEFAULTS.supply);
    $("c-stroke").value = inputText("length", DEFAULTS.stroke);
    $("c-velocity").value = inputText("velocity", DEFAULTS.velocity);
    bindAccountField($("c-operator"));
    await this.loadIsolators();
    this.setRig(rigAnswer);
    onUnits((sys) => this.unitsChanged(sys));
    onState((what) => {
      if (what === "rigState" || what === "status" || what === "conn" || what === "test") this.renderButtons();
      if (what === "rigState") this.renderRigInForce();
      if ((what === "test" || what === "status") && this.visible) this.followLive();
    });
    this.renderMeta();
    this.formChanged();
  }

  setRig(rigAnswer) {
    this.rig = rigAnswer || this.rig;
    const simulated = ((this.rig && this.rig.rig) || {}).kind !== "udp";
    const speed = $("c-speed");
    speed.disabled = !simulated;
    if (!simulated) speed.value = "1";
    $("c-speed-note").textContent = simulated ? "simulated rig: time scale of the run" : "fixed: a real rig runs in real time";
    this.renderMeta();
    this.renderRigInForce();
  }

  async loadIsolators() {
    const select = $("c-isolator");
    let list = [];
    try {
      list = await api.get("/api/isolators");
    } catch { /* the presets are listed by the service only */ }
    select.innerHTML = "";
    select.append(el("option", { value: "none", text: "none: the bare rig, no specimen (best)" }));
    for (const iso of list || []) {
      select.append(el("option", { value: iso.name, text: `${iso.name} (${iso.source === "user" ? "user" : "preset"}, mounted)` }));
    }
  }

  unitsChanged(sys) {
    for (const [id, quantity] of [["c-supply", "pressure"], ["c-vertical_load", "force"], ["c-stroke", "length"], ["c-velocity", "velocity"]]) {
      const p = parseNumber($(id).value);
      const before = sys === "si" ? "lab" : "si";
      if (p.ok) {
        const factorBefore = { pressure: { lab: 1e-5, si: 1e-6 }, force: { lab: 1e-3, si: 1 }, length: { lab: 1e3, si: 1 }, velocity: { lab: 1e3, si: 1 } }[quantity];
        $(id).value = inputText(quantity, p.value / factorBefore[before]);
      }
    }
    this.renderMeta();
    this.formChanged();
    if (this.current) this.renderResult(this.current);
    this.drawLive();
  }

  renderMeta() {
    const env = (this.rig && this.rig.envelope) || {};
    const set = (id, quantity, range) => {
      const label = $(id).closest("label");
      label.querySelector(".unit").textContent = quantity ? `(${unit(quantity)})` : "(x real time)";
      label.querySelector(".range").textContent = range;
    };
    set("c-supply", "pressure", `${fmtU("pressure", (env.supply_bar_min || 10) * 1e5)} to ${fmtU("pressure", (env.supply_bar_max || 210) * 1e5)}`);
    set("c-vertical_load", "force", `empty: design load (0 with none); up to ${fmtU("force", env.max_vertical_load_n, { sig: 4 })}`);
    set("c-stroke", "length", `${fmtU("length", RANGES.stroke[0])} to ${fmtU("length", RANGES.stroke[1])} about where the table rests`);
    set("c-velocity", "velocity", `${fmtU("velocity", RANGES.velocity[0])} to ${fmtU("velocity", RANGES.velocity[1])}`);
    set("c-speed", null, `1 to ${env.max_speed || 100}`);
  }

  // ------------------------------------------------------------------------------ the form and its check

  formChanged() {
    const r = readForm(this.rig);
    this.form = r;
    if (!r.ok) {
      this.check = null;
      this.renderWhat();
      this.renderButtons();
      return;
    }
    if (this.check && this.check.bodyKey !== JSON.stringify(r.body)) this.check = null; // a check of another form
    clearTimeout(this.checkTimer);
    this.checkTimer = setTimeout(() => this.askCheck(), 150);
    this.renderWhat();
    this.renderButtons();
  }

  /** Ask the service to check the form as it is. The check asked last wins: an earlier answer that comes later
   * is dropped, so the page never shows (nor starts on) a check of a form it no longer has. */
  async askCheck() {
    const body = this.form && this.form.ok ? this.form.body : null;
    if (!body) return;
    const stale = this.checks.ask();
    const bodyKey = JSON.stringify(body);
    const key = bodyKey + JSON.stringify(tablePosition());
    let check;
    try {
      const answer = await api.postQuiet("/api/commissioning/check", body);
      check = { ...answer, key, bodyKey };
    } catch (e) {
      check = { ok: false, detail: e.message, field: errorField(e.detail), key, bodyKey };
    }
    if (stale()) return;
    this.check = check;
    const blamed = { supply_bar: "c-supply", vertical_load_n: "c-vertical_load", max_stroke_m: "c-stroke",
      max_velocity_m_per_s: "c-velocity", speed: "c-speed", isolator: "c-isolator" }[this.check.field];
    document.querySelectorAll("#commission-form .refused").forEach((x) => x.classList.remove("refused", "invalid"));
    if (!this.check.ok && blamed) $(blamed).classList.add("invalid", "refused");
    this.renderWhat();
    this.renderButtons();
  }

  /** What will move and why, before Start: the service's figures for exactly this form. */
  renderWhat() {
    const box = $("c-what");
    box.innerHTML = "";
    const f = this.form;
    if (!f || !f.ok) {
      box.className = "note-box what refused";
      box.append(el("b", { text: "Not ready: " }), `${f ? f.problems.map(([id, e]) => `${$(id).closest("label").firstChild.textContent.trim()}: ${e}`).join("; ") : "..."}`);
      return;
    }
    const c = this.check;
    if (c && !c.ok) {
      box.className = "note-box what refused";
      box.append(el("b", { text: "Refused by the service: " }), c.detail || "");
      return;
    }
    const b = f.body;
    const where = tablePosition();
    const start = c && num(c.start_m) ? c.start_m : where ? where.m : null;
    const dur = c && num(c.duration_s) ? c.duration_s : null;
    box.className = "note-box what";
    box.append(
      el("b", { text: "What will move and why" }),
      el("p", { class: "bounds", text: `The table moves at most \u00b1${fmtU("length", b.max_stroke_m)} about where it rests` +
        `${num(start) ? ` (${fmtU("length", start, { sign: true })}${where ? `, ${sourceWords(where.source)}` : ""})` : ""}, ` +
        `below ${fmtU("velocity", b.max_velocity_m_per_s)}, for at most ${dur ? `${dur.toFixed(0)} s` : "20 s"}` +
        `${dur && b.speed !== 1 ? ` (${fmtDuration(dur / b.speed)} at speed ${b.speed})` : ""}:` }),
      el("ol", {},
        el("li", { text: "the valve's null, the table held where it rests; then valve sweeps, slowly each way: the valve's dead zone, null and gain;" }),
        el("li", { text: "a small dither (1 to 100 Hz), the table held: the oil column, the moving mass, the friction, the sensor delay;" }),
        el("li", { text: "back to where it rested; the valve closes." })),
      el("p", { class: "muted", text: "Nothing is assumed about the valve (no test controller). Beyond these bounds the " +
        "valve closes" + (c && c.limits ? ` (|d| ${fmtU("length", c.limits.displacement_m)}, |v| ${fmtU("velocity", c.limits.velocity_m_per_s)}, ` +
        `|y-r| ${fmtU("length", c.limits.tracking_error_m)})` : "") + ". Then the service fits the record (5 to 20 s); the " +
        "rig in force changes only when you apply the result." }));
  }

  /** Start needs: a connection, no run, the rig connected, valid fields, the service's check for exactly them. */
  whyNot() {
    if (!state.conn) return "a connection to the service";
    if (testRunning()) return `no run going on (${state.testId !== null ? `#${state.testId}` : "one"} is running)`;
    if (this.runId !== null && this.current && BUSY.has(this.current.state)) return `commissioning #${this.runId} to end`;
    if (state.linkConnected === "false" || (state.rigState && state.rigState.status === "not_connected")) return "the rig connected";
    if (!this.form || !this.form.ok) return "valid values (see the fields)";
    if (!this.check || !this.check.ok) return this.check ? `a set-up the service accepts (${this.check.detail})` : "the service's check";
    return "";
  }

  renderButtons() {
    const why = this.whyNot();
    $("c-start").disabled = Boolean(why);
    $("c-why").textContent = why ? `Start needs: ${why}` : "";
    $("c-why").className = why ? "why blocked" : "why";
    const running = this.current && this.current.status === "running" && this.runId === this.current.id;
    $("c-stop").disabled = !running;
    const t = this.current;
    const applied = t && t.applied;
    const canApply = t && t.state === "trusted" && !testRunning();
    const apply = $("c-apply");
    apply.disabled = !canApply;
    apply.title = !t ? "" : t.state !== "trusted" ? "only a trusted commissioning can become the service's rig"
      : testRunning() ? "not while a run goes on" : applied ? "applied before; apply again to make it the rig in force" : "";
  }

  async start({ retryOf = null } = {}) {
    this.say("", "");
    // who commissions is asked before the confirmation, which names them (it said operator "-", then asked)
    if (!account.name) await refreshAccount();
    if (!account.name && !(await askLogin("commissioning moves the rig: log in as an operator"))) {
      this.say("Not started: nobody is logged in on this console.", "");
      return;
    }
    if (!["operator", "approver", "admin"].includes(account.role)) {
      this.say(`Not started: ${account.name} is ${account.role}; commissioning needs the role operator or above.`, "error");
      return;
    }
    this.formChanged();
    clearTimeout(this.checkTimer); // this start asks now; a timer's check would supersede its answer
    await this.askCheck();
    const why = this.whyNot();
    if (why) {
      this.say(`Not started: Start needs ${why}.`, "error");
      return;
    }
    const b = this.form.body;
    const c = this.check;
    const where = tablePosition();
    const L = c.limits || {};
    const rows = summaryTable([
      ...(retryOf ? [["second attempt", `of commissioning #${retryOf.id}, refused`, "the same, at the bounds its refusal suggests"]] : []),
      ["what moves", `\u00b1${fmtU("length", b.max_stroke_m)} about ${fmtU("length", c.start_m, { sign: true })}`,
        where ? `where the table rests (${sourceWords(where.source)})` : "where the table rests"],
      ["velocity", `below ${fmtU("velocity", b.max_velocity_m_per_s)}`],
      ["duration", `at most ${c.duration_s.toFixed(1)} s of rig time`, b.speed !== 1 ? `${fmtDuration(c.wall_s)} at speed ${b.speed}` : "real time"],
      ["how", "valve sweeps, then a small dither, then back", "to measure the valve, the oil column, the moving mass and the sensor delay"],
      ["supply", fmtU("pressure", b.supply_bar * 1e5)],
      ["specimen", c.isolator === "none" ? "none (the bare rig)" : c.isolator],
      ["vertical load", fmtU("force", c.vertical_load_n, { sig: 4 })],
      ["operator", b.operator_name || "-"],
      ["limits (valve close)", `|d| ${fmtU("length", L.displacement_m)}, |v| ${fmtU("velocity", L.velocity_m_per_s)}, |y-r| ${fmtU("length", L.tracking_error_m)}`],
      ["then", "the service fits the record (5 to 20 s)", "the rig in force changes only when you apply the result"],
    ]);
    const answer = await confirmDialog({ title: retryOf ? `Commission the rig again, below ${fmtU("velocity", b.max_velocity_m_per_s)}? The table will move.`
      : "Commission the rig? The table will move.", body: rows, ok: "Start commissioning" });
    if (!answer) {
      this.say("Not started: cancelled.", "");
      return;
    }
    try {
      const rec = await operatorPost("/api/commissioning", b);
      this.say(`Commissioning #${rec.id} started.`, "ok");
      location.hash = `#/commission/${rec.id}`;
      await this.open(rec.id);
    } catch (e) {
      this.say(`Not started, refused by the service: ${e.message}`, "error");
      const blamed = errorField(e.detail);
      if (blamed) this.askCheck();
    }
  }

  async stop() {
    if (this.runId === null) return;
    try {
      await api.endTest(`/api/tests/${this.runId}/stop`);
      this.say(`Stop requested: commissioning #${this.runId} ends (the valve closes); a stopped run is not fitted to a rig file.`, "");
    } catch (e) {
      this.say(`Stop failed: ${e.message}`, "error");
    }
  }

  say(text, kind) {
    $("c-message").textContent = text;
    $("c-message").className = `message ${kind || ""}`;
  }

  // ------------------------------------------------------------------------------ showing a commissioning

  /** The page is shown: a given commissioning, else the one running, else the latest. */
  async show(id) {
    this.visible = true;
    this.renderRigInForce();
    this.listEarlier();
    if (id) return this.open(id);
    if (this.current) return this.open(this.current.id);
    const running = state.test && state.test.profile && state.test.profile.kind === "commissioning" && state.status === "running";
    if (running) return this.open(state.testId);
    try {
      const list = await api.get("/api/tests?limit=200");
      const last = (list || []).find((t) => t.profile && t.profile.kind === "commissioning");
      if (last) return this.open(last.id);
    } catch { /* nothing to show */ }
    this.renderResult(null);
  }

  hide() {
    this.visible = false;
  }

  /** A commissioning started elsewhere (another console, a script) while this page is open: follow it. */
  followLive() {
    const t = state.test;
    if (!t || !t.profile || t.profile.kind !== "commissioning" || state.status !== "running") return;
    if (this.runId === state.testId) return;
    this.open(state.testId);
  }

  /** Show commissioning `id`. The one asked for last wins: an earlier open answered later is dropped. */
  async open(id) {
    const stale = this.opens.ask();
    let res;
    try {
      res = await api.get(`/api/commissioning/${id}`);
    } catch (e) {
      if (stale()) return;
      this.renderResult(null, `commissioning #${id}: ${e.message}`);
      return;
    }
    if (stale()) return;
    if (!this.current || this.current.id !== id) {
      this.trace = { t: [], y: [], u: [] };
      this.phase = null;
      this.gate = null;
    }
    this.current = res;
    this.runId = id;
    if (res.status === "running" || res.status === "ready") this.connect(id);
    this.renderResult(res);
    if (BUSY.has(res.state)) this.poll(id);
    // a run that ended before the page looked (its fit may still go on): its whole trace from the record
    if (FINAL.has(res.status) && (!this.trace.t.length || this.trace.t[0] > 0.1)) this.loadTrace(id);
  }

  /** While the run or its fit goes on, ask for the result every second (the state is the truth). */
  poll(id) {
    clearTimeout(this.polling);
    this.polling = setTimeout(async () => {
      if (this.runId !== id) return;
      try {
        const res = await api.get(`/api/commissioning/${id}`);
        if (this.runId !== id) return;
        if (this.current && FINAL.has(this.current.status) && !FINAL.has(res.status)) { // asked before the end
          this.poll(id);
          return;
        }
        const was = this.current && this.current.state;
        this.current = res;
        this.renderResult(res);
        if (was !== res.state && !BUSY.has(res.state)) this.announce(res);
        if (BUSY.has(res.state)) this.poll(id);
      } catch {
        this.poll(id);
      }
    }, 1000);
  }

  announce(res) {
    if (res.state === "trusted") showAlert(`Commissioning ${res.id}: trusted; its rig file can be made the service's rig`, "info");
    else if (res.state === "not_trusted") showAlert(`Commissioning ${res.id}: NOT trusted, no rig file: ${(res.identification && res.identification.problems || []).join("; ")}`, "warn");
    else if (res.state === "fit_failed") showAlert(`Commissioning ${res.id}: the fit failed (${res.error}); the record keeps its samples`, "warn");
  }

  /** The run's own stream (its samples carry the phase and the gate). */
  connect(id) {
    if (this.ws && this.wsId === id) return;
    if (this.ws) this.ws.close();
    const proto = location.protocol === "https:" ? "wss" : "ws";
    const ws = new WebSocket(`${proto}://${location.host}/ws/tests/${id}`);
    this.ws = ws;
    this.wsId = id;
    ws.onmessage = (ev) => {
      let msg;
      try { msg = JSON.parse(ev.data); } catch { return; }
      if (msg.type === "samples") this.onSamples(msg);
      else if (msg.type === "status") this.onStatus(msg);
    };
    ws.onclose = () => {
      if (this.ws === ws) {
        this.ws = null;
        this.wsId = null;
      }
    };
  }

  onSamples(msg) {
    const cols = msg.columns || [];
    const it = cols.indexOf("time_s");
    const iy = cols.indexOf("displacement_m");
    const iu = cols.indexOf("voltage_v");
    const ip = cols.indexOf("as_hat");
    const ig = cols.indexOf("ar_hat");
    const tr = this.trace;
    for (const row of msg.rows || []) {
      const t = row[it];
      if (tr.t.length && t <= tr.t[tr.t.length - 1] + 0.0095) continue; // every 10th sample (100 Hz)
      tr.t.push(t);
      tr.y.push(row[iy] === null ? NaN : row[iy]);
      tr.u.push(row[iu] === null ? NaN : row[iu]);
    }
    const last = (msg.rows || [])[msg.rows.length - 1];
    if (last) {
      if (num(last[ip])) this.phase = last[ip];
      if (num(last[ig])) this.gate = last[ig];
    }
    this.liveDirty = true;
    if (!this.drawPending) {
      this.drawPending = true;
      requestAnimationFrame(() => {
        this.drawPending = false;
        this.renderProgress();
        this.drawLive();
      });
    }
  }

  onStatus(msg) {
    if (!this.current || msg.test_id !== this.current.id) return;
    if (typeof msg.progress === "number") this.progress = msg.progress;
    this.current = { ...this.current, status: msg.status, time_s: msg.time_s, reason: msg.reason || this.current.reason };
    if (FINAL.has(msg.status)) {
      this.current.state = "fitting";
      if (this.ws) this.ws.close();
      this.poll(this.current.id);
      this.renderResult(this.current);
      if (!this.trace.t.length || this.trace.t[0] > 0.1) this.loadTrace(this.current.id); // joined late: the whole run
      return;
    }
    this.renderProgress();
    this.renderButtons();
  }

  /** A commissioning that ended before the page looked: its displacement and command from the record (CSV). */
  async loadTrace(id) {
    try {
      const text = await (await fetch(`/api/tests/${id}/data.csv`)).text();
      if (this.runId !== id) return;
      const lines = text.split("\n");
      const head = lines[0].split(",");
      const it = head.indexOf("time_s");
      const iy = head.indexOf("displacement_m");
      const iu = head.indexOf("voltage_v");
      const tr = { t: [], y: [], u: [] };
      for (let k = 1; k < lines.length; k += 10) {
        const c = lines[k].split(",");
        if (c.length < head.length) continue;
        tr.t.push(Number(c[it]));
        tr.y.push(c[iy] === "" ? NaN : Number(c[iy]));
        tr.u.push(c[iu] === "" ? NaN : Number(c[iu]));
      }
      this.trace = tr;
      this.drawLive();
    } catch { /* no trace: the result stands without it */ }
  }

  /** The steps: valve sweeps, dither, return (the run's phase), fitting, result. */
  renderProgress() {
    const c = this.current;
    const box = $("c-steps");
    box.innerHTML = "";
    if (!c) return;
    let at;
    if (c.status === "running" || c.status === "ready") {
      const phase = this.phase === null ? 0 : Math.round(this.phase);
      at = phase === 4 ? 0 : Math.min(2, Math.max(0, phase)); // the valve null belongs to the sweeps' step
    }
    else if (c.state === "fitting") at = 3;
    else at = 4;
    STEPS.forEach((name, k) => {
      box.append(el("li", { class: k < at ? "done" : k === at ? "now" : "", "data-step": name, text: name }));
    });
    const running = c.status === "running";
    const pct = running ? Math.round(100 * this.progress) : c.state === "fitting" || !BUSY.has(c.state) ? 100 : 0;
    $("c-progress-bar").style.width = `${pct}%`;
    const phaseText = running && this.phase !== null ? PHASES[Math.round(this.phase)] || "-" : c.state;
    $("c-phase").textContent = phaseText;
    $("c-phase").dataset.phase = running ? phaseText : c.state;
    $("c-time").textContent = running ? `t = ${(c.time_s || 0).toFixed(1)} s of ${num(c.duration_s) ? c.duration_s.toFixed(1) : "?"} s` +
      `${num(this.gate) && Math.round(this.phase) === 1 ? ` \u00b7 dither gate ${Math.round(100 * this.gate)} %` : ""}`
      : c.state === "fitting" ? "the run has ended; the service fits its record (5 to 20 s)" : c.words || "";
  }

  drawLive() {
    const box = $("c-live");
    const tr = this.trace;
    const fx = system() === "si" ? 1 : 1e3;
    const data = [Float64Array.from(tr.t), Float64Array.from(tr.y, (v) => v * fx), Float64Array.from(tr.u)];
    if (!this.livePlot) {
      if (!tr.t.length) return;
      const w = Math.max(300, box.getBoundingClientRect().width);
      this.livePlot = new uPlot({
        width: w, height: 200, pxAlign: 0, cursor: { show: false }, legend: { show: true, live: false },
        scales: { x: { time: false }, y: {}, v: {} },
        axes: [axis("run time (s)"), axis(`displacement (${unit("length")})`, "y"), { ...axis("valve command (V)", "v"), side: 1, grid: { show: false } }],
        series: [{ label: "t (s)" }, { label: `table y (${unit("length")})`, stroke: "#7cc0ff", width: 1.5, scale: "y" },
          { label: "command u (V)", stroke: "#d8b4fe", width: 1, scale: "v" }],
      }, data, box);
      this.livePlot.unit = unit("length");
      new ResizeObserver(() => {
        const r = box.getBoundingClientRect();
        if (r.width > 0 && this.livePlot) this.livePlot.setSize({ width: r.width, height: 200 });
      }).observe(box);
      return;
    }
    if (this.livePlot.unit !== unit("length")) {
      this.livePlot.destroy();
      this.livePlot = null;
      this.drawLive();
      return;
    }
    this.livePlot.setData(data);
  }

  // ------------------------------------------------------------------------------ the result

  renderResult(res, error = "") {
    $("c-result-empty").classList.toggle("hidden", Boolean(res));
    $("c-run").classList.toggle("hidden", !res);
    if (!res) {
      $("c-result-empty").textContent = error || "No commissioning yet: fill in the form and Start.";
      $("c-result").classList.add("hidden");
      this.renderButtons();
      return;
    }
    $("c-run-title").textContent = `Commissioning #${res.id}`;
    // the earlier-commissionings list follows this one's status and state (it said "running" after the end)
    const shown = `${res.id} ${res.status} ${res.state}`;
    if (this.visible && this.listedFor !== shown) {
      this.listedFor = shown;
      this.listEarlier();
    }
    $("c-run-what").textContent = `${res.status}${res.reason ? ` (${res.reason})` : ""} \u00b7 started ${fmtTime(res.started_at || res.created_at)}` +
      ` \u00b7 ${res.isolator === "none" ? "no specimen" : `specimen ${res.isolator}`} \u00b7 ${fmtU("pressure", res.supply_bar * 1e5)}` +
      ` \u00b7 vertical load ${fmtU("force", res.vertical_load_n, { sig: 4 })} \u00b7 rig told of: ${res.rig || "-"}` +
      `${res.operator_name ? ` \u00b7 by ${res.operator_name}` : ""}`;
    const plant = res.plant_changes && Object.keys(res.plant_changes).length
      ? `The simulated rig played a rig unlike its rig file: ${Object.entries(res.plant_changes).map(([k, v]) => `${k} = ${sigDigits(v, 4)}`).join(", ")} (isorig serve --plant-set).` : "";
    $("c-run-plant").textContent = plant;
    $("c-run-plant").classList.toggle("hidden", !plant);
    this.renderProgress();
    this.drawLive();
    const done = !BUSY.has(res.state);
    $("c-result").classList.toggle("hidden", !done);
    this.renderButtons();
    if (!done) return;
    const verdict = $("c-verdict");
    verdict.dataset.state = res.state;
    verdict.textContent = { trusted: "TRUSTED", not_trusted: "NOT TRUSTED", fit_failed: "FIT FAILED" }[res.state] || res.state;
    const ident = res.identification || {};
    const problems = ident.problems || [];
    $("c-verdict-words").textContent = res.state === "trusted"
      ? `The fit explains the record: its rig file${res.rig_file ? ` "${res.rig_file.name}"` : ""} can be made the service's rig.`
      : res.state === "fit_failed" ? `The fit failed (${res.error}). The record keeps every sample; no rig file was written.`
        : "No rig file: the fit cannot be trusted, for these reasons:";
    const list = $("c-problems");
    list.innerHTML = "";
    for (const p of problems) list.append(el("li", { text: p }));
    list.classList.toggle("hidden", !problems.length);
    this.renderSecondAttempt(res);
    this.renderFigures(res);
    this.renderTable(res);
    this.renderResponse(ident.response);
    const link = $("c-download");
    link.classList.toggle("hidden", !res.rig_file);
    if (res.rig_file) {
      link.href = res.rig_file.download;
      link.setAttribute("download", `commissioned-rig-${res.id}.json`);
    }
    $("c-apply").classList.toggle("hidden", res.state !== "trusted");
    const applied = res.applied;
    $("c-applied").textContent = applied ? `Made the service's rig by ${applied.by} at ${fmtTime(applied.at)} (${applied.path}).` : "";
    this.renderButtons();
  }

  /** A refusal a second run at other bounds can cure (identification.second_attempt: sim.commission.identify):
   * why, and a button that fills the form with its bounds and starts through the same confirmation. */
  renderSecondAttempt(res) {
    let box = $("c-second");
    if (!box) {
      box = el("div", { id: "c-second", class: "note-box second-attempt hidden", "aria-live": "polite" });
      $("c-problems").after(box);
    }
    box.innerHTML = "";
    const retry = res.state === "not_trusted" ? (res.identification || {}).second_attempt : null;
    const ok = retry && num(retry.max_stroke_m) && num(retry.max_velocity_m_per_s);
    box.classList.toggle("hidden", !ok);
    if (!ok) return;
    const v = `${inputText("velocity", retry.max_velocity_m_per_s)} ${unit("velocity")}`;
    const button = el("button", { id: "c-retry", type: "button", class: "primary", text: `Run again at ${v}...`,
      title: `fills the form with \u00b1${fmtU("length", retry.max_stroke_m)} and ${v}, then asks before anything moves` });
    button.addEventListener("click", () => this.runAgain(res));
    box.append(el("b", { text: "A second attempt may help: " }), el("span", { class: "why-text", text: retry.why || "" }),
      el("div", { class: "buttons" }, button));
  }

  /** Fill the form as commissioning `res` ran, with its second attempt's bounds, then Start (login and the
   * confirmation as ever: nothing moves before the operator confirms). */
  async runAgain(res) {
    const retry = (res.identification || {}).second_attempt;
    if (!retry) return;
    const cond = res.conditions || {};
    if (num(res.supply_bar)) $("c-supply").value = inputText("pressure", res.supply_bar * 1e5);
    const iso = $("c-isolator");
    if (res.isolator && [...iso.options].some((o) => o.value === res.isolator)) iso.value = res.isolator;
    const load = num(cond.vertical_load_n) ? cond.vertical_load_n : res.vertical_load_n;
    if (num(load)) $("c-vertical_load").value = inputText("force", load);
    if (!$("c-speed").disabled && num(res.speed)) $("c-speed").value = String(res.speed);
    $("c-stroke").value = inputText("length", retry.max_stroke_m);
    $("c-velocity").value = inputText("velocity", retry.max_velocity_m_per_s);
    this.formChanged();
    $("commission-form").scrollIntoView({ block: "nearest" });
    await this.start({ retryOf: res });
  }

  renderFigures(res) {
    const ident = res.identification || {};
    const fit = ident.fit || {};
    const r = ident.response || {};
    const rec = ident.record || {};
    const box = $("c-figures");
    box.innerHTML = "";
    const kv = (k, v, title = "") => box.append(el("div", { class: "kv", title }, el("span", { text: k }), el("b", { text: v })));
    kv("rig time", num(rec.rig_time_s) ? `${rec.rig_time_s.toFixed(1)} s` : "-");
    kv("table within", num(rec.peak_excursion_m) ? `\u00b1${fmtU("length", rec.peak_excursion_m)}` : "-", "the largest |y - y0| of the run");
    kv("|velocity| up to", fmtU("velocity", rec.peak_velocity_m_per_s));
    kv("|command| up to", fmtU("voltage", rec.peak_command_v));
    kv("flow balance R\u00b2", num(fit.flow_r2) ? fit.flow_r2.toFixed(4) : "-", "eq. 3, second line: at least 0.98 is needed");
    kv("force balance R\u00b2", num(fit.force_r2) ? fit.force_r2.toFixed(3) : "-", "eq. 3, first line: at least 0.9 is needed");
    kv("replay error, velocity", num(r.velocity_nrmse) ? `${(100 * r.velocity_nrmse).toFixed(1)} % RMS` : "-",
      "the fitted rig given the same commands: normalised RMS of its velocity against the measured one over the dither (at most 20 %)");
    kv("replay error, load pressure", num(r.pressure_nrmse) ? `${(100 * r.pressure_nrmse).toFixed(1)} % RMS` : "-");
    kv("fit took", num(res.fit_s) ? `${res.fit_s.toFixed(1)} s` : "-");
  }

  renderTable(res) {
    const tbody = $("c-table").querySelector("tbody");
    tbody.innerHTML = "";
    const est = ((res.identification || {}).fit || {}).estimates || {};
    const declared = res.declared || {};
    // a refused fit's values are what the fit gave, not the rig's (they can be nonsense): said above the table, in
    // the column's heading and on each value
    const trusted = res.state === "trusted";
    $("c-table-fitted").textContent = trusted ? "fitted" : "fitted (NOT TRUSTED)";
    $("c-table-note").classList.toggle("hidden", trusted);
    for (const [name, e] of Object.entries(est)) {
      const [u] = paramUnit(name);
      const d = declared[name];
      // a value with no finite uncertainty is not determined: no number is shown for it as if it were one
      const known = num(e.value) && num(e.std);
      const share = known && e.value !== 0 ? e.std / Math.abs(e.value) : Infinity;
      const rel = share < 1 ? ` (${(100 * share).toFixed(share < 0.01 ? 2 : 1)} %)` : ""; // none for a value near 0
      const changed = known && num(d) && Math.abs(e.value - d) > 2 * e.std;
      const fitted = el("td", { class: "num fitted", text: known ? paramWithStd(name, e.value, e.std) : "not determined" });
      if (!known) {
        fitted.classList.add("undetermined");
        fitted.title = `${num(e.value) ? `the fit gave ${paramText(name, e.value)} ${u}` : "the fit gave no value"}, with no finite uncertainty`;
      }
      if (!trusted) {
        fitted.dataset.trusted = "false";
        fitted.title = fitted.title || "not trusted: the fit was refused";
      }
      tbody.append(el("tr", { "data-name": name, ...(changed ? { class: "changed", title: "differs from the declared value by more than two uncertainties" } : {}) },
        el("td", {}, el("b", { text: (PARAMS[name] || [name])[0] }), el("small", { class: "muted", text: ` ${name}` })),
        fitted,
        el("td", { class: "num", text: known ? `\u00b1${paramWithStd(name, e.std, e.std)}${rel}` : "none" }),
        el("td", { class: "num", text: paramWithStd(name, d, e.std) }),
        el("td", { class: "num", text: known ? changeText(name, e.value, d, e.std) : "-" }),
        el("td", { class: "unit", text: u })));
    }
    if (!Object.keys(est).length) tbody.append(el("tr", {}, el("td", { colspan: "6", class: "muted", text: "nothing was fitted" })));
  }

  /** Measured frequency response (points) against the fitted model's (line): magnitude and phase, log frequency. */
  renderResponse(r) {
    for (const p of this.plots) p.destroy();
    this.plots = [];
    const box = $("c-response");
    box.innerHTML = "";
    const shown = Boolean(r && Array.isArray(r.frequency_hz) && r.frequency_hz.length);
    $("c-response-panel").classList.toggle("hidden", !shown);
    $("c-response-panel").parentElement.classList.toggle("no-response", !shown); // the table takes the whole width
    if (!shown) return;
    const f = Float64Array.from(r.frequency_hz);
    const vf = system() === "si" ? 1 : 1e3;
    const pf = system() === "si" ? 1e-6 : 1e-5;
    const vu = `${unit("velocity")}/V`;
    const pu = `${unit("pressure")}/V`;
    const panels = [
      [`velocity per volt: magnitude (${vu})`, r.velocity_per_volt, "magnitude", vf, 3],
      ["velocity per volt: phase (deg)", r.velocity_per_volt, "phase_deg", 1, 1],
      [`load pressure per volt: magnitude (${pu})`, r.load_pressure_per_volt, "magnitude", pf, 3],
      ["load pressure per volt: phase (deg)", r.load_pressure_per_volt, "phase_deg", 1, 1],
    ];
    for (const [title, pair, key, factor, distr] of panels) {
      const cell = el("div", { class: "fr-cell" }, el("h4", { text: title }));
      const host = el("div", { class: "fr-plot" });
      cell.append(host);
      box.append(cell);
      const series = (values) => Float64Array.from(values, (v) => (v === null ? NaN : v * factor));
      const measured = series(pair.measured[key]);
      const model = series(pair.model[key]);
      const width = Math.max(260, host.getBoundingClientRect().width || 360);
      const plot = new uPlot({
        width, height: 210, pxAlign: 0, cursor: { show: false }, legend: { show: true, live: false },
        scales: { x: { time: false, distr: 3 }, y: distr === 3 ? { distr: 3 } : {} },
        axes: [axis("frequency (Hz, log)"), axis(key === "phase_deg" ? "phase (deg)" : title.replace(/^.*magnitude /, "|H| "), "y")],
        series: [{ label: "f (Hz)" },
          { label: "measured", stroke: "#ffd27a", width: 0, points: { show: true, size: 6, fill: "#ffd27a" }, paths: () => null },
          { label: "fitted model", stroke: "#7cc0ff", width: 2, points: { show: false } }],
      }, [f, measured, model], host);
      plot.title = title;
      this.plots.push(plot);
      new ResizeObserver(() => {
        const rr = host.getBoundingClientRect();
        if (rr.width > 0) plot.setSize({ width: rr.width, height: 210 });
      }).observe(host);
    }
    $("c-response-note").textContent = `${f.length} lines from ${sigDigits(f[0], 3)} to ${sigDigits(f[f.length - 1], 3)} Hz, ` +
      `averaged over ${r.periods} periods of the dither; the model is the fitted rig given the same commands`;
  }

  async apply() {
    const res = this.current;
    if (!res || res.state !== "trusted") return;
    const est = ((res.identification || {}).fit || {}).estimates || {};
    const declared = res.declared || {};
    const moved = Object.entries(est).filter(([name, e]) => num(declared[name]) && Math.abs(e.value - declared[name]) > 2 * e.std)
      .map(([name, e]) => `${(PARAMS[name] || [name])[0]}: ${paramText(name, declared[name])} \u2192 ${paramText(name, e.value)} ${paramUnit(name)[0]}`);
    const body = el("div", {},
      summaryTable([
        ["rig file", res.rig_file ? res.rig_file.name : "-"],
        ["from", `commissioning #${res.id}, ${fmtTime(res.started_at)}`],
        ["in force now", (state.rigState && state.rigState.rig_file && state.rigState.rig_file.name) || "-"],
      ]),
      el("p", { text: "The next tests and moves use it: the controller, the envelope and the limits follow it. It is " +
        "written into the service's data directory and stays in force after a restart (unless the service is started " +
        "with --rig-file). A running test is not affected (none may run)." }),
      ...(moved.length ? [el("p", { text: "What changes (beyond two uncertainties):" }), el("ul", {}, ...moved.map((m) => el("li", { text: m })))] : []));
    const answer = await confirmDialog({ title: `Make commissioning #${res.id}'s rig file the service's rig?`, body,
      ok: "Make it the service's rig" });
    if (!answer) {
      $("c-apply-message").textContent = "Not applied: cancelled.";
      $("c-apply-message").className = "message";
      return;
    }
    try {
      const out = await operatorPost(`/api/commissioning/${res.id}/apply`, {});
      this.current = out.commissioning;
      this.renderResult(this.current);
      $("c-apply-message").textContent = `The service's rig is now "${out.rig_file.name}".${out.in_force.note ? ` Note: ${out.in_force.note}` : ""}`;
      $("c-apply-message").className = "message ok";
      await this.onApplied(out);
      this.renderRigInForce();
    } catch (e) {
      $("c-apply-message").textContent = `Not applied, refused by the service: ${e.message}`;
      $("c-apply-message").className = "message error";
    }
  }

  /** The rig file in force (GET /api/rig/state every 2 s, so a rig applied elsewhere shows too). */
  renderRigInForce() {
    const box = $("c-in-force");
    if (!box) return;
    const rf = (state.rigState && state.rigState.rig_file) || null;
    box.innerHTML = "";
    if (!rf) {
      box.textContent = "Rig file in force: asking the service...";
      return;
    }
    box.append(el("span", { class: "muted", text: "Rig file in force: " }), el("b", { text: rf.name }),
      el("span", { class: "muted", text: rf.commissioned ? ` \u00b7 commissioned ${fmtTime(rf.commissioned).slice(0, 10)}` : " \u00b7 never commissioned" }),
      el("span", { class: "muted", text: rf.how === "applied" ? ` \u00b7 applied by ${rf.applied_by} at ${fmtTime(rf.applied_at)}` : rf.how === "rig_file" ? " \u00b7 --rig-file" : " \u00b7 sim.rig defaults" }));
    const plant = rf.plant_changes && Object.keys(rf.plant_changes).length ? rf.plant_changes : null;
    if (plant) {
      box.append(el("div", { class: "plant-note", text: `Simulated rig for demos and tests: it plays a rig unlike its rig file (${Object.entries(plant).map(([k, v]) => `${k} = ${sigDigits(v, 4)}`).join(", ")}; isorig serve --plant-set). Not a real rig.` }));
    }
  }

  async listEarlier() {
    const list = $("c-earlier");
    const stale = this.lists.ask();
    try {
      const tests = (await api.get("/api/tests?limit=200")).filter((t) => t.profile && t.profile.kind === "commissioning").slice(0, 8);
      if (stale()) return; // a newer list was asked for
      list.innerHTML = "";
      for (const t of tests) {
        const state = ((t.summary || {}).commissioning || {}).state || t.status;
        list.append(el("li", {}, el("a", { href: `#/commission/${t.id}`, text: `#${t.id}` }),
          ` ${fmtTime(t.created_at)} \u00b7 ${t.status} \u00b7 `, el("span", { class: `pill cstate-${state}`, text: state.replace("_", " ") })));
      }
      if (!tests.length) list.append(el("li", { class: "muted", text: "none yet" }));
    } catch { /* the list is a convenience */ }
  }

  /** For tests and scripts: the state, the step, the plots' titles and series. */
  describe() {
    return {
      id: this.current && this.current.id, state: this.current && this.current.state, phase: this.phase,
      steps: [...document.querySelectorAll("#c-steps li")].map((li) => ({ step: li.dataset.step, cls: li.className })),
      response: this.plots.map((p) => ({ title: p.title, x: p.axes[0].label, distr: p.scales.x.distr,
        series: p.series.slice(1).map((s) => s.label), points: p.data[0].length })),
      live: this.trace.t.length,
    };
  }
}

function axis(label, scale) {
  return { stroke: "#8d99a6", grid: { stroke: "#2a323b", width: 1 }, ticks: { stroke: "#2a323b" }, label, labelSize: 18,
    labelFont: "12px system-ui, sans-serif", size: 52, ...(scale ? { scale } : {}) };
}

