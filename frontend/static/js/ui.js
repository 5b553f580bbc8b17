// Small shared UI helpers: formatting, the status badge, the alert banner, events in words.

import { fmtU } from "./units.js";

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
  if (p.kind === "sine" || p.amplitude_m !== undefined) {
    return `sine ${fmtU("length", p.amplitude_m)} at ${fmtU("frequency", p.frequency_hz)} x ${p.cycles}`;
  }
  return p.kind || "-";
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

/** Prominent banner. kind: "bad" (stays until dismissed), "warn", "info" (fades after 8 s). */
export function showAlert(text, kind = "bad") {
  const el = document.getElementById("alert");
  document.getElementById("alert-text").textContent = text;
  el.className = `alert ${kind === "bad" ? "" : kind}`;
  el.dataset.kind = kind;
  clearTimeout(alertTimer);
  if (kind !== "bad") alertTimer = setTimeout(() => el.classList.add("hidden"), 8000);
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

const DETECTORS = {
  displacement_m: ["displacement", "length"],
  force_n: ["force", "force"],
  load_pressure_pa: ["load pressure", "pressure"],
  tracking_error_m: ["tracking error |y - r|", "length"],
  supply_pressure_pa: ["supply pressure", "pressure"],
};

function capital(text) {
  return text ? text[0].toUpperCase() + text.slice(1) : text;
}

/**
 * An event in words for the operator: what happened, with values in the chosen units; no internals (worker
 * ids, raw value dictionaries). Returns {when, t, text}.
 */
export function eventWords(e) {
  const v = (e && e.values) || {};
  const kind = e.kind || "event";
  let text = e.message || kind;
  if (kind === "limit_trip" && v.limit_name && DETECTORS[v.limit_name]) {
    const [name, quantity] = DETECTORS[v.limit_name];
    const value = Math.abs(v[v.limit_name]);
    text = `LIMIT TRIP: ${name} ${fmtU(quantity, value, { sig: 4 })} beyond the limit of ${fmtU(quantity, v.limit, { sig: 4 })}; ` +
      "valve command ramped to 0 V, test aborted";
  } else if (kind === "limit_trip") {
    text = `LIMIT TRIP: ${e.message || v.detector || "a detector tripped"}`;
  } else if (kind === "rig_fault") {
    text = `RIG FAULT: ${e.message || "the rig stopped"}`;
  } else if (kind === "operator") {
    const who = e.actor && e.actor !== "operator" ? ` (${e.actor})` : "";
    const words = {
      create: "Test created", start: "Test started: the valve opens", stop: "Stop requested: ramp-out from the next whole cycle",
      abort: "Abort requested: valve command to 0 V", discard: "Start refused: the test was not kept",
      delete: "Test deleted (it never ran)",
    }[v.action];
    if (v.action === "archive" || v.action === "restore") {
      text = `${v.action === "archive" ? "Archived" : "Restored"} by ${v.by}: ${v.reason}`;
    } else if (words) {
      text = words + who;
    } else {
      text = capital(text);
    }
  } else if (kind === "status") {
    text = capital(text.replace(/^test \d+ /, "test "));
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
