// Small shared UI helpers: formatting, the status badge, the alert banner, events in words.

import { actionName, limitInfo } from "./limits.js";
import { fmtU } from "./units.js";

/** A ramp cycle's phase in words (sim.tracking PHASES); a steady cycle has none. */
export const PHASE_WORDS = { taper_in: "ramp-in", taper_out: "ramp-out", ramp_out: "stop ramp-out" };

export function fmtDuration(s) {
  if (typeof s !== "number" || !isFinite(s)) return "-";
  s = Math.max(0, Math.round(s));
  const h = Math.floor(s / 3600);
  const m = Math.floor((s % 3600) / 60);
  const sec = s % 60;
  const two = (x) => String(x).padStart(2, "0");
  return h ? `${h}:${two(m)}:${two(sec)}` : `${m}:${two(sec)}`;
}

/** A test's motion in a few words: "sine 30.00 mm at 0.5 Hz x 10" or "protocol quick_check". */
export function profileText(t) {
  let p = t.profile || (t.scenario && t.scenario.profile) || (t.request && t.request.profile);
  if (Array.isArray(p)) p = p.length === 1 ? p[0] : { kind: `${p.length} sine blocks` };
  if (!p) return "-";
  if (p.kind === "protocol") return `protocol ${p.name || "(inline)"}`;
  if (p.kind === "move") {
    return `manual move ${fmtU("length", p.start_m, { sign: true })} to ${fmtU("length", p.end_m, { sign: true })} ` +
      `at ${fmtU("velocity", p.speed_m_per_s)}`;
  }
  if (p.kind === "history" || p.kind === "hybrid") return earthquakeText(p);
  if (p.kind === "commissioning") {
    return `commissioning \u00b1${fmtU("length", p.max_stroke_m)} about ${fmtU("length", p.start_m, { sign: true })}, ` +
      `below ${fmtU("velocity", p.max_velocity_m_per_s)}`;
  }
  if (p.kind === "sine" || p.amplitude_m !== undefined) {
    const off = typeof p.offset_m === "number" && p.offset_m !== 0 ? ` about ${fmtU("length", p.offset_m, { sign: true })}` : "";
    return `sine ${fmtU("length", p.amplitude_m)} at ${fmtU("frequency", p.frequency_hz)} x ${p.cycles}${off}`;
  }
  return p.kind || "-";
}

/** An earthquake test's profile (the record's description) in words: "time history: near_field_short x 0.5 (0:15)". */
function earthquakeText(p) {
  const gm = p.ground_motion || {};
  const scale = typeof p.scale === "number" ? ` x ${p.scale}` : "";
  const dur = typeof p.duration_s === "number" ? ` (${fmtDuration(p.duration_s)})` : "";
  const motion = gm.preset ? gm.preset : gm.inline ? `a ground motion record (${gm.samples} samples, ${gm.units})` : "a ground motion";
  if (p.kind === "hybrid") {
    const n = p.structure && Array.isArray(p.structure.masses_kg) ? p.structure.masses_kg.length : "?";
    return `hybrid (RTHS): ${n}-storey building, ${motion}${scale}${dur}`;
  }
  if (p.displacement) return `time history: a displacement record (${p.displacement.samples} samples)${scale}${dur}`;
  return `time history: ${motion}${scale}${dur}`;
}

export function setStatusBadge(status) {
  const el = document.getElementById("rig-status");
  const s = (status || "idle").toLowerCase();
  const stale = el.classList.contains("stale");
  el.className = `status-badge status-${s}${stale ? " stale" : ""}`;
  el.textContent = s.toUpperCase();
  el.dataset.status = s;
}

let alertTimer = null;

/** Prominent banner, one line (a click shows it whole). kind: "bad" (stays until dismissed), "warn", "info" (fades
 * after 8 s). */
export function showAlert(text, kind = "bad") {
  const el = document.getElementById("alert");
  setAlertText(text);
  el.className = `alert ${kind === "bad" ? "" : kind}`;
  el.dataset.kind = kind;
  clearTimeout(alertTimer);
  if (kind !== "bad") alertTimer = setTimeout(() => el.classList.add("hidden"), 8000);
}

/** The banner's words, also its title (the line may be cut short on a narrow screen). */
export function setAlertText(text) {
  const words = document.getElementById("alert-text");
  words.textContent = text;
  words.title = text;
}

export function hideAlert() {
  document.getElementById("alert").classList.add("hidden");
}

/** An ISO 8601 time of the service (UTC) as local "YYYY-MM-DD HH:MM:SS", or "" when missing. */
export function fmtTime(iso) {
  if (!iso) return "";
  const d = new Date(iso);
  if (isNaN(d.getTime())) return String(iso);
  const two = (x) => String(x).padStart(2, "0");
  return `${d.getFullYear()}-${two(d.getMonth() + 1)}-${two(d.getDate())} ` +
    `${two(d.getHours())}:${two(d.getMinutes())}:${two(d.getSeconds())}`;
}

function capital(text) {
  return text ? text[0].toUpperCase() + text.slice(1) : text;
}

/** A limit event (limit_trip, limit_indicate) in words: the quantity, its value and the limit, the action taken. */
function limitWords(e) {
  const v = e.values || {};
  if (v.detector === "not_following" && e.kind === "limit_trip") return notFollowingWords(e);
  if (v.detector === "not_following") { // the follow detector set to indicate (limits.actions.follow)
    return `FOLLOW DETECTOR INDICATED: ${e.message || "the table does not follow its target"}`;
  }
  const info = limitInfo(v.limit_name);
  const reading = info && typeof v[v.limit_name] === "number" && typeof v.limit === "number"
    ? `${info.name} ${fmtU(info.quantity, Math.abs(v[v.limit_name]), { sig: 4 })} beyond the limit of ` +
      `${fmtU(info.quantity, v.limit, { sig: 4 })}`
    : e.message || v.detector || "a detector tripped";
  if (e.kind === "limit_indicate") {
    const n = typeof v.indication === "number" ? ` (indication ${v.indication}` +
      `${v.indication >= 10 ? "; further ones are only counted, in the test's summary" : ""})` : "";
    return `LIMIT INDICATED: ${reading}; the test goes on${n}`;
  }
  if (v.escalation) return `LIMIT TRIP during the controlled stop: ${reading}; valve close: the valve closes now`;
  const action = v.action || "valve_close";
  const done = {
    valve_close: "valve close: the valve command ramps to 0 V in 0.1 s, the test ends aborted",
    controlled_stop: "controlled stop: the target brakes to rest within every displacement limit and holds there under control, the test ends aborted",
  }[action] || `${actionName(action)}: the test ends aborted`;
  return `LIMIT TRIP: ${reading}; ${done}`;
}

/**
 * The table did not follow its target (sim.follow): the service's reason, the action (the valve closes at once:
 * the controller is no longer trusted) and its advice (commission the rig) last, so the banner reads in order.
 */
function notFollowingWords(e) {
  const msg = e.message || "the table does not follow its target";
  let cut = -1; // the first "; " outside parentheses: what was seen, then the advice
  for (let i = 0, depth = 0; i < msg.length - 1; i++) {
    if (msg[i] === "(") depth++;
    else if (msg[i] === ")") depth = Math.max(0, depth - 1);
    else if (depth === 0 && msg[i] === ";" && msg[i + 1] === " ") {
      cut = i;
      break;
    }
  }
  const what = cut > 0 ? msg.slice(0, cut) : msg;
  const advice = cut > 0 ? msg.slice(cut + 2) : "";
  const done = (e.values || {}).action === "controlled_stop"
    ? "controlled stop: the target brakes to rest under control, the test ends aborted"
    : "the valve closes at once (the controller is no longer trusted), the test ends aborted";
  return `LIMIT TRIP: ${what}; ${done}${advice ? `. Advice: ${advice}` : ""}`;
}

/** "stop requested by operator" -> "operator" (the actor of a request streamed live, which has no actor field). */
function requestedBy(e) {
  if (e.actor && e.actor !== "system") return e.actor;
  const m = /requested by (.+)$/.exec(e.message || "");
  return m ? m[1] : "";
}

/**
 * An event in words for the operator: what happened, with values in the chosen units; no internals (worker
 * ids, raw value dictionaries). Returns {when, t, text}.
 */
export function eventWords(e) {
  const v = (e && e.values) || {};
  const kind = e.kind || "event";
  let text = e.message || kind;
  if (kind === "limit_trip" || kind === "limit_indicate") {
    text = limitWords(e);
  } else if (kind === "rig_fault") {
    text = `RIG FAULT: ${e.message || "the rig stopped"}`;
  } else if (kind === "operator") {
    const who = requestedBy(e);
    const requested = /requested by/.test(e.message || "") || (e.actor && e.actor !== "system");
    if (v.action === "stop" && !requested) {
      text = typeof v.ends_at_s === "number" ? `Ramp-out begun: the test ends at t = ${v.ends_at_s.toFixed(2)} s`
        : "Ramp-out begun";
    } else if (v.action === "abort" && !requested) {
      text = "Abort: valve command set to 0 V at once";
    } else if (v.action === "archive" || v.action === "restore") {
      text = `${v.action === "archive" ? "Archived" : "Restored"} by ${v.by}: ${v.reason}`;
    } else if (v.action === "stop" || v.action === "abort") {
      text = v.action === "stop"
        ? `Stop requested by ${who || "an operator"}: ramp-out to the end of the next whole cycle`
        : `Abort requested by ${who || "an operator"}: valve command to 0 V`;
    } else {
      const words = {
        create: "Test created",
        start: v.move ? "Move started: the valve opens" : v.commissioning
          ? "Commissioning started: the valve opens (the excitation, not a test controller)" : "Test started: the valve opens",
        discard: "Start refused: the test was not kept", delete: "Test deleted (it never ran)",
      }[v.action];
      text = words ? `${words}${who && who !== "operator" ? ` (${who})` : ""}` : capital(text);
    }
  } else if (kind === "status") {
    text = capital(text.replace(/^(test|manual move|commissioning) \d+ /, "$1 "));
  } else if (kind === "commissioning") {
    text = capital(text.replace(/^commissioning \d+ /, "commissioning "));
  } else {
    text = capital(text);
  }
  const when = e.created_at ? fmtTime(e.created_at).slice(11) : e.receivedAt ? fmtClock(e.receivedAt) : "";
  const t = typeof e.time_s === "number" ? `t = ${e.time_s.toFixed(e.time_s < 100 ? 2 : 1)} s` : "";
  return { when, t, text, kind };
}

/** One line of an events list: "12:03:04 · t = 3.20 s · Test completed". */
export function eventLine(e) {
  const w = eventWords(e);
  return [w.when, w.t, w.text].filter(Boolean).join(" \u00b7 ");
}

function fmtClock(ms) {
  const d = new Date(ms);
  const two = (x) => String(x).padStart(2, "0");
  return `${two(d.getHours())}:${two(d.getMinutes())}:${two(d.getSeconds())}`;
}

export function el(tag, attrs = {}, ...children) {
  const node = document.createElement(tag);
  for (const [k, v] of Object.entries(attrs)) {
    if (k === "class") node.className = v;
    else if (k === "text") node.textContent = v;
    else node.setAttribute(k, v);
  }
  for (const c of children) node.append(c);
  return node;
}
