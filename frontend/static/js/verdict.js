// How well the table followed its target (sim.follow, the record's summary.tracking_verdict): a pill for History,
// a line for the test page, and the live view's header and banner when a test ends. "did not follow" is marked
// in red with the service's advice (commission the rig) and a link to the Commissioning page.

import { onState, state } from "./state.js";
import { el, setAlertText } from "./ui.js";

const $ = (id) => document.getElementById(id);
const PILL = { followed: "followed", outside_target: "outside target", did_not_follow: "DID NOT FOLLOW", not_judged: "not judged" };
const ENDED = new Set(["completed", "stopped", "aborted", "interrupted", "failed"]);

// The one tracking figure's definition, word for word as the CLI and the report give it (sim/tracking_figure.py,
// docs/metrics.md "The tracking figure"); a time history's verdict rests on J2.
export const TRACKING_DEFINITION = "RMS of reading - target one latency earlier, last two steady cycles, % of amplitude";
export const HISTORY_DEFINITION = "J2: RMS of reading - target over the test, % of the target's RMS";

/** The few words that say what test `t`'s tracking figure is. */
export function trackingDefinition(t) {
  const basis = String((t && t.summary && t.summary.tracking_verdict && t.summary.tracking_verdict.basis) || "");
  return basis.startsWith("J2") ? HISTORY_DEFINITION : TRACKING_DEFINITION;
}

/** The record's verdict split into {verdict, words, short, advice}, or null (a move or a commissioning has none). */
export function trackingVerdict(t) {
  const kind = t && t.profile && !Array.isArray(t.profile) ? t.profile.kind : null;
  if (kind === "move" || kind === "commissioning") return null;
  const v = t && t.summary && t.summary.tracking_verdict;
  if (!v || !v.verdict) return null;
  const words = v.words || v.verdict;
  const cut = v.verdict === "did_not_follow" ? words.indexOf("; ") : -1;
  return { verdict: v.verdict, words, short: cut > 0 ? words.slice(0, cut) : words, advice: cut > 0 ? words.slice(cut + 2) : "" };
}

/** A pill after a History row's status ([] when the record has no verdict). */
export function verdictPill(t) {
  const v = trackingVerdict(t);
  if (!v) return [];
  return [" ", el("span", { class: `pill tracking tv-${v.verdict}`, "data-verdict": v.verdict, text: PILL[v.verdict] || v.verdict, title: v.words })];
}

/** A test stopped because its table did not follow (a limit_trip of detector not_following): as a verdict. */
function notFollowingTrip(t) {
  const trip = ((t && t.events) || []).find((e) => e.kind === "limit_trip" && e.values && e.values.detector === "not_following");
  if (!trip) return null;
  const msg = trip.message || "";
  const at = /at t = ([\d.]+) s/.exec(msg);
  const advice = /; (the rig is not what[^]*|the \w+ controller does not follow[^]*)$/.exec(msg);
  return { verdict: "did_not_follow", words: msg, short: `stopped${at ? ` at t = ${at[1]} s` : ""}: the table did not follow its target`,
    advice: advice ? advice[1] : "the rig is not what the controller was told: commission it" };
}

/** The test page's line: the verdict in words, the advice below it, and where to commission the rig. */
export function verdictBlock(t) {
  const v = notFollowingTrip(t) || trackingVerdict(t);
  if (!v) return null;
  const box = el("div", { class: `kv wide tracking-verdict`, "data-verdict": v.verdict },
    el("span", { text: `tracking error (${trackingDefinition(t)})` }),
    el("b", {}, el("span", { class: `pill tv-${v.verdict}`, text: PILL[v.verdict] || v.verdict }), ` ${v.short}`));
  if (v.advice) {
    box.append(el("small", { class: "tv-advice" }, `${v.advice[0].toUpperCase()}${v.advice.slice(1)}: `,
      el("a", { href: "#/commission", text: "open the Commissioning page" })));
  }
  return box;
}

/** The live view's header: the verdict of the test in view once it has ended; the end banner gets it too. */
export function watchLiveVerdict() {
  const announced = new Set();
  onState((what) => {
    if (what !== "test" && what !== "status") return;
    const t = state.test;
    const kv = $("l-verdict-kv");
    const trip = t && ENDED.has(state.status) ? notFollowingTrip(t) : null;
    const v = trip || (t && ENDED.has(state.status) ? trackingVerdict(t) : null);
    kv.classList.toggle("hidden", !v);
    kv.dataset.verdict = v ? v.verdict : "";
    $("l-verdict").textContent = v ? (trip ? trip.short : v.words) : "-";
    $("l-verdict").title = v ? v.words : "";
    if (!v || announced.has(state.testId)) return;
    announced.add(state.testId);
    const alert = $("alert");
    const text = $("alert-text");
    const ours = !alert.classList.contains("hidden") && new RegExp(`^Test ${state.testId} (completed|stopped)$`).test(text.textContent);
    if (!ours) return;
    setAlertText(`${text.textContent}; tracking error: ${v.words}`);
    if (v.verdict === "did_not_follow") {
      alert.className = "alert warn";
      alert.dataset.kind = "warn";
    }
  });
}
