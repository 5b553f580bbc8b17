// The limits of a test and their actions, as the service defines them (GET /api/rig: limits_default,
// limits_max, limit_actions; POST /api/tests body `limits`): which limits there are, what each is called and
// in which quantity it is shown, the actions in words, and a limit set in one line. Every page that names a
// limit (set-up, confirmation, status strip, margins, events, test page) takes it from here.

import { fmtU } from "./units.js";

const num = (v) => typeof v === "number" && Number.isFinite(v);

/** Every operator limit: its key in the service's `limits`, the form field, names and quantity (js/units.js). */
export const LIMITS = [
  { key: "displacement_m", field: "lim_displacement", short: "|d|", name: "displacement", quantity: "length" },
  { key: "force_n", field: "lim_force", short: "|F|", name: "force", quantity: "force" },
  { key: "velocity_m_per_s", field: "lim_velocity", short: "|v|", name: "velocity", quantity: "velocity" },
  { key: "load_pressure_pa", field: "lim_pressure", short: "|P_L|", name: "load pressure", quantity: "pressure" },
  { key: "tracking_error_m", field: "lim_tracking", short: "|y-r|", name: "tracking error", quantity: "length" },
];

export const BY_KEY = Object.fromEntries(LIMITS.map((l) => [l.key, l]));

/**
 * The detector of a table that does not follow its target (sim.follow): an operator's limit with its own actions
 * (`limits.actions.follow`); its thresholds are shares of the amplitude (the record's `limits.follow`).
 */
export const FOLLOW = { key: "follow", name: "follow detector", short: "follow", actions: ["controlled_stop", "indicate"],
  default: "controlled_stop" };
const FOLLOW_THRESHOLDS = { rms_share: 0.01, oscillation_share: 0.02, floor_m: 4e-5, oscillation_window_s: 0.5, corner_hz: 10,
  steady_oscillation_share: 0.005, tone_share: 0.001, tone_floor_m: 1e-5, tone_correlation: 0.9 };
const FOLLOW_HELP = {
  controlled_stop: "the table did not follow: a tracking stop brakes the target to rest under control, an oscillation closes the valve at once (the loop itself oscillates); the test ends aborted",
  indicate: "an event says what the detector saw and when, the test goes on (the tracking verdict still says how well the table followed)",
};

/** The follow detector's action in a limit set (controlled stop where the set names none). */
export function followAction(lim) {
  const a = lim && lim.actions && lim.actions.follow;
  return FOLLOW.actions.includes(a) ? a : FOLLOW.default;
}

/** What the follow detector's action does, in one line. */
export function followHelp(action) {
  return FOLLOW_HELP[action] || "";
}

/** The follow detector's thresholds in words (the record's, else the service's defaults). */
export function followThresholdsText(lim) {
  const f = { ...FOLLOW_THRESHOLDS, ...((lim && lim.follow) || {}) };
  const pc = (x) => `${+(100 * x).toPrecision(3)} %`;
  return `oscillation: RMS above ${f.corner_hz} Hz over ${f.oscillation_window_s} s > ${pc(f.oscillation_share)} of the ` +
    `amplitude (${pc(f.steady_oscillation_share)} in steady cycles; at least ${fmtU("length", f.floor_m, { sig: 2 })}), ` +
    `or a tone of its own (repeating at its own period, correlation >= ${f.tone_correlation}) > ` +
    `${pc(f.tone_share)} of the amplitude (at least ${fmtU("length", f.tone_floor_m, { sig: 2 })}); tracking: ` +
    `RMS |y - r| of a steady cycle > ${pc(f.rms_share)} of the amplitude once the learning stalls`;
}

/** Built-in detectors the service trips on by itself (always valve close). */
const BUILT_IN = { supply_pressure_pa: { name: "supply pressure", quantity: "pressure" } };

export const DEFAULT_ACTION = "valve_close";
export const ACTION_ORDER = ["valve_close", "controlled_stop", "indicate"];

/** The actions in words, as the service describes them (GET /api/rig limit_actions), these when it does not. */
const ACTION_HELP = {
  indicate: "an event is recorded, the test goes on",
  controlled_stop: "the target brakes to rest from where it is, within every displacement limit (one with this action is never passed: the target brakes before it), and holds there under control; the test ends aborted",
  valve_close: "the valve command ramps to 0 V in 0.1 s, open loop; the table coasts on by its stopping distance, so the limit can be passed; the test ends aborted",
};
let serviceHelp = {};

/** Take the service's descriptions of the actions (GET /api/rig limit_actions). */
export function setActionHelp(limitActions) {
  serviceHelp = limitActions && typeof limitActions === "object" ? limitActions : {};
}

/** "valve close", "controlled stop", "indicate". */
export function actionName(action) {
  return String(action || DEFAULT_ACTION).replace(/_/g, " ");
}

/** What the action does, in one line. */
export function actionHelp(action) {
  return serviceHelp[action] || ACTION_HELP[action] || "";
}

/** The action of one limit in a limit set (the default where the set names none). */
export function actionOf(limits, key) {
  const a = limits && limits.actions && limits.actions[key];
  return a || DEFAULT_ACTION;
}

/** A limit (or a built-in detector) by its key, with name and quantity; null when unknown. */
export function limitInfo(key) {
  return BY_KEY[key] || BUILT_IN[key] || null;
}

/** "|v| 50 mm/s": one limit's value in the console's units. */
export function limitValue(l, si) {
  return `${l.short} ${fmtU(l.quantity, si, { sig: 4 })}`;
}

/**
 * A limit set in one line, grouped by action: "valve close: |d| 150 mm, |F| 280.1 kN · indicate: |v| 50 mm/s".
 * Sets recorded before limits had actions read as valve close (what every trip did then).
 */
export function limitsText(lim) {
  if (!lim) return "-";
  const groups = {};
  for (const l of LIMITS) {
    if (!num(lim[l.key])) continue;
    const a = actionOf(lim, l.key);
    (groups[a] = groups[a] || []).push(limitValue(l, lim[l.key]));
  }
  if (followAction(lim) === "indicate") (groups.indicate = groups.indicate || []).push(FOLLOW.name); // said when set so
  const parts = ACTION_ORDER.filter((a) => groups[a]).map((a) => `${actionName(a)}: ${groups[a].join(", ")}`);
  return parts.length ? parts.join(" \u00b7 ") : "-";
}

/** One line per limit: "|d| 150 mm: valve close" (tooltips). */
export function limitsLines(lim) {
  if (!lim) return "";
  return [...LIMITS.filter((l) => num(lim[l.key]))
    .map((l) => `${limitValue(l, lim[l.key])}: ${actionName(actionOf(lim, l.key))}`),
  `${FOLLOW.name}: ${actionName(followAction(lim))}`].join("\n");
}

/** "|v| 12 times, |y-r| 1 time" from a record's summary.limit_indications ({key: count}); "" when none. */
export function indicationsText(counts) {
  if (!counts || typeof counts !== "object") return "";
  return [...LIMITS, FOLLOW].filter((l) => num(counts[l.key]) && counts[l.key] > 0)
    .map((l) => `${l.short} ${counts[l.key]} time${counts[l.key] === 1 ? "" : "s"}`).join(", ");
}
