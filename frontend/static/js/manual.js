// Manual motion: the table moved to a position, or back to zero, at a safe speed when no test runs
// (POST /api/rig/move, POST /api/rig/zero, by a logged-in operator). A move uses the set-up's isolator, supply
// pressure, vertical load and limits with their actions (the same detectors as a test) and asks for a
// confirmation first: from where to where, the peak speed, how long, the limits. The service runs it as a run
// of its own (profile kind "move", a minimum-jerk target, then 0.5 s holding the position, the valve closed at
// the end): the live view, the status strip and the events follow it as they follow a test; Stop holds the
// table where it is, ABORT closes the valve. This block shows where the table is, the move under way and how
// the last one ended, and why Zero or Move cannot be used now.

import { ApiError, errorField, operatorPost } from "./api.js";
import { confirmDialog, summaryTable } from "./dialogs.js";
import { parseNumber } from "./parse.js";
import { isMove, onState, runName, sourceWords, state, tablePosition, testRunning } from "./state.js";
import { el, fmtDuration } from "./ui.js";
import { fmt, fmtU, inputText, onUnits, toSI, unit } from "./units.js";

const $ = (id) => document.getElementById(id);
const num = (v) => typeof v === "number" && Number.isFinite(v);
const BAR = 1e5;
// The service's manual motion (sim/motion.py, GET /api/rig's manual_motion): a peak speed up to a maximum, a
// default speed, and a hold at the new position; these are what the console assumes until the rig is read.
// A minimum-jerk move lasts 1.875 distance / peak speed (at least 0.2 s).
const MANUAL_MOTION = { min_speed_m_per_s: 0.001, max_speed_m_per_s: 0.05, default_speed_m_per_s: 0.005, hold_s: 0.5 };
const PEAK_VELOCITY_FACTOR = 1.875;
const MIN_MOVE_S = 0.2;
const SPEED_KEY = "isorig.move_speed_m_per_s";
const FINAL = new Set(["completed", "stopped", "aborted", "interrupted", "failed"]);

/** How long a move takes (s): the minimum-jerk part and the hold; null when the start is unknown. */
export function moveSeconds(fromM, toM, speed) {
  if (!num(fromM) || !num(toM) || !(speed > 0)) return null;
  return Math.max(MIN_MOVE_S, (PEAK_VELOCITY_FACTOR * Math.abs(toM - fromM)) / speed);
}

export class ManualMotion {
  constructor(setup) {
    this.setup = setup; // the set-up panel: isolator, supply, vertical load, limits, operator
    this.values = { target: null, speed: MANUAL_MOTION.default_speed_m_per_s }; // SI; null: empty, undefined: not valid
    this.busy = false; // a request on its way
    this.note = null; // {text, kind}: what this console last did (cancelled, refused, started)
    this.endedShown = null; // the move whose end was last said
  }

  /** The service's manual-motion figures (GET /api/rig), else the console's assumption. */
  motion() {
    const served = (this.setup.rig && this.setup.rig.manual_motion) || {};
    const pick = (key) => (num(served[key]) && served[key] > 0 ? served[key] : MANUAL_MOTION[key]);
    return { min: pick("min_speed_m_per_s"), max: pick("max_speed_m_per_s"), default: pick("default_speed_m_per_s"),
             hold: pick("hold_s") };
  }

  init() {
    let speed = this.motion().default;
    try {
      const stored = Number(localStorage.getItem(SPEED_KEY));
      if (stored >= this.motion().min && stored <= this.motion().max) speed = stored;
    } catch { /* the default */ }
    $("f-mm_speed").value = inputText("velocity", speed);
    for (const id of ["f-mm_target", "f-mm_speed"]) {
      $(id).addEventListener("input", (ev) => {
        ev.target.dataset.touched = "1";
        this.note = null;
        this.render();
        if (id === "f-mm_speed" && num(this.values.speed)) { // this browser's speed for the next time
          try { localStorage.setItem(SPEED_KEY, String(this.values.speed)); } catch { /* this page only */ }
        }
      });
      $(id).addEventListener("keydown", (ev) => { // Enter here asks for this move, never for a test
        if (ev.key !== "Enter") return;
        ev.preventDefault();
        this.go("move");
      });
    }
    $("mm-zero").addEventListener("click", () => this.go("zero"));
    $("mm-move").addEventListener("click", () => this.go("move"));
    onUnits(() => {
      for (const [key, id, quantity] of [["target", "f-mm_target", "length"], ["speed", "f-mm_speed", "velocity"]]) {
        if (num(this.values[key])) $(id).value = inputText(quantity, this.values[key]);
      }
      this.render();
    });
    onState((what) => this.onState(what));
    this.render();
  }

  // ------------------------------------------------------------------------------------------ fields

  /** The largest |position| a move may go to: the stroke and the displacement limit in force (SI). */
  reach() {
    const rig = this.setup.rig || {};
    const stroke = (rig.envelope && rig.envelope.stroke_m) || 0.15;
    const lim = this.setup.nextLimits();
    return num(lim.displacement_m) ? Math.min(stroke, lim.displacement_m) : stroke;
  }

  /** Parse one field (target, speed): this.values and the field's message; returns the problem or "". */
  read(key) {
    const [id, quantity] = key === "target" ? ["f-mm_target", "length"] : ["f-mm_speed", "velocity"];
    const input = $(id);
    const field = input.closest(".field");
    const r = parseNumber(input.value);
    let problem = "";
    let note = "";
    let si = null;
    if (r.empty) {
      if (key === "speed") problem = "required";
    } else if (!r.ok) {
      si = undefined;
      problem = r.error;
    } else {
      si = toSI(quantity, r.value);
      if (key === "target" && Math.abs(si) > this.reach() * (1 + 1e-12)) {
        problem = `outside the allowed range: ${this.rangeText("target")}`;
      } else if (key === "speed" && (si < this.motion().min * (1 - 1e-12) || si > this.motion().max * (1 + 1e-12))) {
        problem = `outside the allowed range: ${this.rangeText("speed")}`;
      } else if (r.comma) {
        note = `read as ${fmtU(quantity, si, { sig: 8 })}`;
      }
    }
    this.values[key] = problem ? (r.empty ? null : undefined) : si;
    const msg = field.querySelector(".msg");
    msg.textContent = problem || note;
    msg.className = `msg${problem ? " bad" : note ? " info" : ""}`;
    input.classList.toggle("invalid", Boolean(problem) && (!r.empty || Boolean(input.dataset.touched)));
    return problem;
  }

  rangeText(key) {
    if (key === "speed") {
      return `${fmtU("velocity", this.motion().min, { sig: 3 })} to ${fmtU("velocity", this.motion().max, { sig: 3 })}`;
    }
    const reach = this.reach();
    return `${fmt("length", -reach, { sig: 6 })} to ${fmtU("length", reach, { sig: 6 })} (stroke and displacement limit)`;
  }

  renderMeta() {
    for (const [key, id, quantity] of [["target", "f-mm_target", "length"], ["speed", "f-mm_speed", "velocity"]]) {
      const field = $(id).closest(".field");
      field.querySelector(".unit").textContent = `(${unit(quantity)})`;
      field.querySelector(".range").textContent = this.rangeText(key);
    }
  }

  // ------------------------------------------------------------------------------------------ state

  /** Why Zero ("zero") or Move ("move") cannot be used now ([] when it can). */
  blockers(kind) {
    const out = [];
    if (!state.conn) out.push("a connection to the service");
    if (testRunning()) out.push(`no test running (${runName(state.test, state.testId ?? (state.rigState || {}).test_id)} runs)`);
    if (state.linkConnected === "false") out.push("the rig connected");
    const bad = this.setup.moveProblems();
    if (bad.length) out.push(`valid values above (${bad.join(", ")})`);
    if (!num(this.values.speed)) out.push("a valid speed");
    if (kind === "move") {
      if (this.values.target === null) out.push("a position to move to");
      else if (!num(this.values.target)) out.push("a valid position");
    }
    if (this.busy) out.push("the answer to the last request");
    return out;
  }

  onState(what) {
    if (what === "status" || what === "test") {
      const t = state.test;
      if (isMove(t) && FINAL.has(state.status) && this.endedShown !== state.testId) {
        this.endedShown = state.testId;
        this.note = null; // the move's end says it now
      }
    }
    this.render();
  }

  /** The move under way, or how the last move in view ended: {text, kind} or null. */
  moveState() {
    const t = state.test;
    if (!isMove(t)) return null;
    const p = t.profile;
    const id = state.testId;
    const where = tablePosition();
    const route = `${fmtU("length", p.start_m, { sign: true })} to ${fmtU("length", p.end_m, { sign: true })} at ` +
      `${fmtU("velocity", p.speed_m_per_s, { sig: 3 })}`;
    if (testRunning()) {
      let now = "";
      if (where && where.source === "live") {
        const span = p.end_m - p.start_m;
        const done = Math.abs(span) > 1e-5 ? Math.max(0, Math.min(1, (where.m - p.start_m) / span)) : 1;
        now = `; now ${fmtU("length", where.m, { sign: true })} (${Math.round(done * 100)} % of the way)`;
      }
      const stopping = state.stopping ? ": stopping, the table holds where it is" : "";
      return { kind: "running", text: `Moving (${runName(t, id)}) ${route}${now}${stopping}. Stop holds the table ` +
        "where it is; ABORT closes the valve." };
    }
    if (!FINAL.has(state.status)) return null;
    const at = where ? ` The table rests at ${fmtU("length", where.m, { sign: true })}.` : "";
    if (state.status === "completed") return { kind: "ok", text: `Move #${id} completed (${route}).${at}` };
    if (state.status === "stopped") return { kind: "", text: `Move #${id} stopped before its end.${at}` };
    return { kind: "error", text: `Move #${id} ${state.status.toUpperCase()}${state.reason ? `: ${state.reason}` : ""}.${at}` };
  }

  render() {
    this.renderMeta();
    this.read("target");
    this.read("speed");
    const where = tablePosition();
    const pos = $("mm-position");
    pos.textContent = where ? `${fmtU("length", where.m, { sign: true })} \u00b7 ${sourceWords(where.source)}` : "unknown";
    pos.dataset.source = where ? where.source : "";
    const zero = this.blockers("zero");
    const move = this.blockers("move");
    $("mm-zero").disabled = zero.length > 0;
    $("mm-move").disabled = move.length > 0;
    const why = $("mm-why");
    const moving = testRunning() && isMove(state.test); // the move under way says it below
    why.textContent = moving ? "" : zero.length ? `Zero and Move need: ${zero.join("; ")}.`
      : move.length ? `Move needs: ${move.join("; ")}.` : "Zero and Move ask for a confirmation before the valve opens.";
    why.className = `why${zero.length || move.length ? " blocked" : ""}`;
    const shown = this.busy || testRunning() ? this.moveState() || this.note : this.note || this.moveState();
    const status = $("mm-status");
    status.textContent = shown ? shown.text : "";
    status.className = `message ${shown ? shown.kind : ""}`;
    status.dataset.kind = shown ? shown.kind || "info" : "";
    if (shown && shown.kind === "running" && this.scrolledFor !== state.testId) {
      this.scrolledFor = state.testId; // the move under way, in view in the set-up panel
      status.scrollIntoView({ block: "nearest" });
    }
    this.setup.renderZeroButton(zero);
  }

  say(text, kind = "") {
    this.note = text ? { text, kind } : null;
    this.render();
  }

  // ------------------------------------------------------------------------------------------ moves

  /** The body of POST /api/rig/move (/zero): the set-up's isolator, supply, vertical load, limits, operator. */
  body(position) {
    const { body } = this.setup.body();
    const out = { speed_m_per_s: this.values.speed, isolator: body.isolator, supply_bar: body.supply_bar,
      limits: body.limits };
    if (position !== null) out.position_m = position;
    if (num(body.vertical_load_n)) out.vertical_load_n = body.vertical_load_n;
    if (body.operator_name) out.operator_name = body.operator_name;
    return out;
  }

  /** What the move will do, for its confirmation. */
  summary(kind, body, target, where) {
    const rows = [];
    rows.push(["from", where ? fmtU("length", where.m, { sign: true }) : "unknown",
      where ? `${sourceWords(where.source)}` : "the service moves the table from where it rests"]);
    rows.push(["to", fmtU("length", target, { sign: true }), kind === "zero" ? "zero: where every test's target begins" : ""]);
    const move = where ? moveSeconds(where.m, target, body.speed_m_per_s) : null;
    if (where) rows.push(["distance", fmtU("length", Math.abs(target - where.m))]);
    rows.push(["peak speed", fmtU("velocity", body.speed_m_per_s, { sig: 3 }),
      "minimum-jerk: the table starts and ends at rest"]);
    const hold = this.motion().hold;
    rows.push(["duration", move === null ? "not known" : move + hold < 60 ? `${(move + hold).toFixed(1)} s`
      : fmtDuration(move + hold),
      move === null ? "" : `${move.toFixed(1)} s moving, then ${hold} s holding the position; the valve closes at the end`]);
    const given = typeof body.vertical_load_n === "number";
    const load = given ? body.vertical_load_n : this.setup.defaultVerticalLoad().value;
    rows.push(["isolator", body.isolator, `supply ${fmtU("pressure", body.supply_bar * BAR)}, vertical load ` +
      `${fmtU("force", load)} (${given ? "entered" : this.setup.defaultVerticalLoad().source})`]);
    if (body.operator_name) rows.push(["operator", body.operator_name]);
    const box = el("div", {}, summaryTable(rows));
    box.append(this.setup.limitsBox(body.limits, "move"));
    return box;
  }

  async go(kind) {
    this.render();
    if (this.blockers(kind).length) return;
    const target = kind === "zero" ? 0 : this.values.target;
    const where = tablePosition();
    const body = this.body(kind === "zero" ? null : target);
    const answer = await confirmDialog({
      title: kind === "zero" ? "Return the table to zero? The valve opens when you confirm."
        : `Move the table to ${fmtU("length", target, { sign: true })}? The valve opens when you confirm.`,
      body: this.summary(kind, body, target, where),
      ok: kind === "zero" ? "Zero the table" : "Move the table",
    });
    if (!answer) {
      this.say(`${kind === "zero" ? "Zero" : "Move"} cancelled: nothing was sent to the rig.`);
      return;
    }
    const now = this.blockers(kind);
    if (now.length) { // the state changed while the dialog was open (a test started elsewhere)
      this.say(`Not moved: ${kind === "zero" ? "Zero" : "Move"} needs ${now.join("; ")}.`, "error");
      return;
    }
    this.busy = true;
    this.say("asking the service to move the table...");
    try {
      const rec = await operatorPost(kind === "zero" ? "/api/rig/zero" : "/api/rig/move", body);
      this.busy = false;
      if (state.testId === rec.id && FINAL.has(state.status)) { // the stream has already said how it ended
        this.endedShown = rec.id;
        this.say("");
      } else {
        this.endedShown = null;
        this.say(`${runName(rec, rec.id)} started: ${fmtU("length", rec.profile.start_m, { sign: true })} to ` +
          `${fmtU("length", rec.profile.end_m, { sign: true })}.`, "info");
      }
      location.hash = "#/live";
      $("manual-motion").scrollIntoView({ block: "nearest" }); // where the move's progress is said
    } catch (e) {
      this.busy = false;
      const field = e instanceof ApiError ? errorField(e.detail) : "";
      if (field === "position_m") $("f-mm_target").classList.add("invalid");
      else if (field === "speed_m_per_s") $("f-mm_speed").classList.add("invalid");
      else if (field) this.setup.markField(field);
      const refused = e instanceof ApiError && e.status >= 400;
      this.say(`Not moved${refused ? ", refused by the service" : ""}: ${e.message}`, "error");
    }
  }
}
