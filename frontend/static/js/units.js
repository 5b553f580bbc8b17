// The one unit choice of the console: SI (m, N, N/m, MPa) or lab units (mm, kN, kN/mm, bar), kept per browser
// and applied to every page (set-up, live view, status strip, history, test page). The service speaks SI
// throughout and the CSV export keeps SI; only what the operator reads and types is converted here.
//
// Every quantity has a display unit per system and a resolution in SI that sets the digits shown: a value is
// never given more digits than the measurement has (0.01 mm, 0.01 kN, 0.1 bar, ...).

const KEY = "isorig.units";

/** quantity -> {system: [unit, factor from SI]} and the resolution (SI) or significant digits. */
const QUANTITIES = {
  length: { lab: ["mm", 1e3], si: ["m", 1], res: 1e-5 },
  force: { lab: ["kN", 1e-3], si: ["N", 1], res: 10 },
  stiffness: { lab: ["kN/mm", 1e-6], si: ["N/m", 1], sig: 4 },
  velocity: { lab: ["mm/s", 1e3], si: ["m/s", 1], res: 1e-4 },
  pressure: { lab: ["bar", 1e-5], si: ["MPa", 1e-6], res: 1e4 },
  energy: { lab: ["J", 1], si: ["J", 1], sig: 4 },
  inverse_length: { lab: ["1/mm", 1e-3], si: ["1/m", 1], sig: 4 },
  flow: { lab: ["l/min", 6e4], si: ["m3/s", 1], sig: 4 },
  voltage: { lab: ["V", 1], si: ["V", 1], res: 1e-3 },
  frequency: { lab: ["Hz", 1], si: ["Hz", 1], sig: 4 },
  time: { lab: ["s", 1], si: ["s", 1], sig: 4 },
  ratio: { lab: ["-", 1], si: ["-", 1], sig: 4 },
  percent: { lab: ["%", 100], si: ["%", 100], res: 1e-4 },
  angle: { lab: ["deg", 1], si: ["deg", 1], res: 0.01 },
  // an earthquake test's building and ground motion: kg and m/s2 in both systems (no lab unit of its own)
  mass: { lab: ["kg", 1], si: ["kg", 1], sig: 5 },
  acceleration: { lab: ["m/s2", 1], si: ["m/s2", 1], sig: 3 },
};

export const SYSTEMS = {
  lab: "lab units: mm, kN, kN/mm, bar",
  si: "SI: m, N, N/m, MPa",
};

let current = null;
const listeners = new Set();

/** The chosen system: "lab" (default) or "si". */
export function system() {
  if (current === null) {
    let stored = null;
    try { stored = localStorage.getItem(KEY); } catch { stored = null; }
    current = stored === "si" ? "si" : "lab";
  }
  return current;
}

/** The lab's default (GET /api/lab units): taken only while this browser has made no choice of its own. */
export function applyLabDefault(name) {
  let stored = null;
  try { stored = localStorage.getItem(KEY); } catch { stored = null; }
  if (stored !== null) return;
  const next = name === "si" ? "si" : "lab";
  if (next === system()) return;
  current = next;
  for (const fn of listeners) fn(next);
}

export function setSystem(name) {
  const next = name === "si" ? "si" : "lab";
  if (next === system()) return;
  current = next;
  try { localStorage.setItem(KEY, next); } catch { /* private mode: this page only */ }
  for (const fn of listeners) fn(next);
}

/** Call fn(system) whenever the choice changes (also from another tab of this browser). */
export function onUnits(fn) {
  listeners.add(fn);
}

window.addEventListener("storage", (ev) => {
  if (ev.key !== KEY) return;
  const next = ev.newValue === "si" ? "si" : "lab";
  if (next === current) return;
  current = next;
  for (const fn of listeners) fn(next);
});

function q(quantity) {
  const d = QUANTITIES[quantity];
  if (!d) throw new Error(`unknown quantity ${quantity}`);
  return d;
}

/** The display unit of a quantity ("mm", "kN", ...). */
export function unit(quantity) {
  return q(quantity)[system()][0];
}

/** The display unit of a quantity in a given system ("lab" or "si"). */
export function unitIn(quantity, sys) {
  return q(quantity)[sys === "si" ? "si" : "lab"][0];
}

/** The factor SI -> display of a quantity in a given system ("lab" or "si"). */
export function factorIn(quantity, sys) {
  return q(quantity)[sys === "si" ? "si" : "lab"][1];
}

/** SI -> display. */
export function toDisplay(quantity, si) {
  return si * q(quantity)[system()][1];
}

/** display -> SI. */
export function toSI(quantity, shown) {
  return shown / q(quantity)[system()][1];
}

/** Decimals that fit a quantity's resolution in the display unit (null: significant digits instead). */
export function decimals(quantity) {
  const d = q(quantity);
  if (d.res === undefined) return null;
  const shown = d.res * d[system()][1];
  return Math.max(0, Math.ceil(-Math.log10(shown) - 1e-9));
}

/** A number with `sig` significant digits, in plain notation between 1e-4 and 1e9 ("883900", "0.0806"). */
export function sigDigits(v, sig = 4) {
  if (!Number.isFinite(v)) return "-";
  if (v === 0) return "0";
  const a = Math.abs(v);
  if (a >= 1e9 || a < 1e-4) return v.toExponential(sig - 1).replace(/\.?0+e/, "e");
  const mag = Math.floor(Math.log10(a));
  const dec = Math.max(0, sig - 1 - mag);
  const scaled = Number(v.toPrecision(sig));
  return noNegativeZero(scaled.toFixed(dec).replace(/(\.\d*?)0+$/, "$1").replace(/\.$/, ""));
}

function noNegativeZero(text) {
  return /^-0(\.0*)?$/.test(text) ? text.slice(1) : text;
}

/**
 * A value (SI) in the display unit, without the unit: digits from the quantity's resolution (or `sig`
 * significant digits), never "-0.00". opts: {sign: true} for "+1.23", {sig: n} to force significant digits.
 */
export function fmt(quantity, si, opts = {}) {
  if (typeof si !== "number" || !Number.isFinite(si)) return "-";
  const v = toDisplay(quantity, si);
  const dec = opts.sig ? null : decimals(quantity);
  let text = dec === null ? sigDigits(v, opts.sig || q(quantity).sig || 4) : noNegativeZero(v.toFixed(dec));
  if (opts.sign && v > 0 && Number(text) !== 0) text = `+${text}`;
  return text;
}

/** fmt() followed by the unit: "30.00 mm", "26.61 kN". */
export function fmtU(quantity, si, opts = {}) {
  const text = fmt(quantity, si, opts);
  if (text === "-") return "-";
  const u = unit(quantity);
  return u === "-" ? text : `${text} ${u}`;
}

/** An input's text for a value (SI): plain, no trailing zeros, enough digits to round-trip what was typed. */
export function inputText(quantity, si) {
  if (typeof si !== "number" || !Number.isFinite(si)) return "";
  return String(Number(toDisplay(quantity, si).toPrecision(10)));
}
