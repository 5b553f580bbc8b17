// Review and approval of a record (backend/review.py): the pill in History, and on a test's page the review
// panel: its state, Approve / Reject for an approver who did not run the test, and for an approved record its
// SHA-256 with a check against the record as it is now (GET /api/tests/{id}/approval).

import { account, api, askLogin, onAccount, refreshAccount } from "./api.js";
import { confirmDialog } from "./dialogs.js";
import { el, fmtTime } from "./ui.js";

const $ = (id) => document.getElementById(id);
const ENDED = ["completed", "stopped", "aborted", "interrupted", "failed"];
const RANKS = ["viewer", "operator", "approver", "admin"];

export function reviewOf(t) {
  return t.review || { state: "unreviewed" };
}

/** After the status in History: approved (by whom) or rejected (why); nothing while unreviewed. */
export function reviewPill(t) {
  const r = reviewOf(t);
  if (r.state === "approved") {
    return [" ", el("span", { class: "pill review-approved", text: "approved",
      title: `approved by ${r.by} on ${fmtTime(r.at)}; the record is locked` })];
  }
  if (r.state === "rejected") {
    return [" ", el("span", { class: "pill review-rejected", text: "rejected", title: `rejected by ${r.by}: ${r.note}` })];
  }
  return [];
}

/** Who ran the test, as the record names them ("bob (through automation)" -> "bob"). */
function operatorOf(t) {
  return (t.operator_name || "").split(" (through ")[0];
}

/** Why the logged-in account may not review this record now, or "" if it may. */
function whyNot(t) {
  if (!ENDED.includes(t.status)) return `the test is ${t.status}: a record is reviewed once its test has ended`;
  if (!account.name) return "log in as an approver to review";
  if (RANKS.indexOf(account.role) < RANKS.indexOf("approver")) return `${account.name} is ${account.role}: reviewing needs the role approver`;
  if (operatorOf(t) === account.name) return `${account.name} ran this test: an approver who did not run it reviews it`;
  return "";
}

export class ReviewPanel {
  constructor(onChange) {
    this.onChange = onChange; // called after an approval or rejection (the page reloads the record)
    $("t-approve").addEventListener("click", () => this.decide("approve"));
    $("t-reject").addEventListener("click", () => this.decide("reject"));
    $("t-verify").addEventListener("click", () => this.verify());
    onAccount(() => { if (this.t) this.show(this.t); }); // a login or logout here: the hint and buttons follow it
  }

  /** Another test's page is loading: nothing of the previous test's review stays, nothing acts on it. */
  clear() {
    this.t = null;
    for (const id of ["t-approve", "t-reject", "t-verify"]) $(id).classList.add("hidden");
    for (const id of ["t-review-words", "t-review-hash", "t-review-why", "t-verify-result"]) $(id).textContent = "";
    $("t-review-state").className = "pill";
    $("t-review-state").textContent = "loading...";
  }

  show(t) {
    this.t = t;
    const r = reviewOf(t);
    const state = $("t-review-state");
    state.className = `pill review-${r.state}`;
    state.textContent = { unreviewed: "not reviewed", approved: "approved", rejected: "rejected" }[r.state] || r.state;
    const words = $("t-review-words");
    if (r.state === "approved") {
      words.textContent = `Approved by ${r.by} on ${fmtTime(r.at)}${r.note ? `: ${r.note}` : ""}. The record is locked.`;
    } else if (r.state === "rejected") {
      words.textContent = `Rejected by ${r.by} on ${fmtTime(r.at)}: ${r.note}. It may be approved after another review.`;
    } else {
      words.textContent = ENDED.includes(t.status) ? "An approver who did not run the test reviews it: approving locks the record."
        : "Reviewed once the test has ended.";
    }
    // the record's hash, and the hash of the report PDF kept at the approval (served as it was from then on)
    $("t-review-hash").textContent = r.state !== "approved" ? ""
      : `record SHA-256 ${r.record_sha256}` + (r.report_sha256 ? ` · report PDF SHA-256 ${r.report_sha256} (kept at the approval)`
        : " · no report PDF kept (approved before reports were kept)");
    $("t-verify").classList.toggle("hidden", r.state !== "approved");
    $("t-verify-result").textContent = "";
    const open = r.state !== "approved" && ENDED.includes(t.status);
    const why = whyNot(t);
    for (const id of ["t-approve", "t-reject"]) {
      const b = $(id);
      b.classList.toggle("hidden", !open);
      b.disabled = Boolean(why) && Boolean(account.name);
      b.title = why || "";
    }
    $("t-review-why").textContent = open ? why : "";
  }

  async decide(action) {
    const t = this.t;
    if (!t) return; // the page's record has not loaded yet
    if (!account.name && !(await refreshAccount()).name && !(await askLogin("reviewing needs the role approver"))) return;
    const why = whyNot(t);
    if (why) {
      $("t-review-why").textContent = why;
      return;
    }
    const answer = action === "approve"
      ? await confirmDialog({ title: `Approve test #${t.id}?`, ok: "Approve and lock",
        body: `Approved by ${account.name}. The record is then locked (no archive, no change), its SHA-256 printed in the report, and the report PDF made now is kept as it is (the lab's header and units of today).`,
        fields: [{ name: "note", label: "note (optional)", minLength: 0, maxLength: 400, multiline: true }] })
      : await confirmDialog({ title: `Reject test #${t.id}?`, ok: "Reject", danger: true,
        body: `Rejected by ${account.name}. The record stays as it is; it may be approved after another review.`,
        fields: [{ name: "reason", label: "why (at least 3 characters)", minLength: 3, maxLength: 400, multiline: true }] });
    if (!answer) return;
    const body = action === "approve" ? { note: answer.values.note || "" } : { reason: answer.values.reason };
    try {
      await api.post(`/api/tests/${t.id}/${action}`, body);
      $("t-message").textContent = `Test #${t.id} ${action === "approve" ? "approved" : "rejected"} by ${account.name}.`;
      $("t-message").className = "message ok";
      this.onChange();
    } catch (e) {
      $("t-message").textContent = `Test #${t.id} not ${action}d: ${e.message}`;
      $("t-message").className = "message error";
    }
  }

  async verify() {
    const t = this.t;
    if (!t) return; // the page's record has not loaded yet
    const out = $("t-verify-result");
    out.textContent = "checking...";
    try {
      const v = await api.get(`/api/tests/${t.id}/approval`);
      if (!this.t || this.t.id !== t.id) return; // the page shows another test by now
      const ok = v.intact && v.report_intact !== false;
      out.textContent = ok ? `intact: the record is as it was approved${v.report_intact ? ", and so is its report PDF" : ""}`
        : `CHANGED: ${v.words}`;
      out.className = ok ? "ok" : "field-error";
    } catch (e) {
      if (!this.t || this.t.id !== t.id) return;
      out.textContent = `could not check: ${e.message}`;
      out.className = "field-error";
    }
  }
}
