// Where the table rests and where the test starts: the warning above Start when the rig does not answer or the
// table rests off zero (or off the sine's offset taken from the table), and the offset taken from the table.

import { fmtPeriod } from "./rig.js";
import { capitalize } from "./setupfields.js";
import { changed, sourceWords, state, tablePosition, testRunning } from "./state.js";
import { el } from "./ui.js";
import { fmtU } from "./units.js";

const $ = (id) => document.getElementById(id);
const num = (v) => typeof v === "number" && Number.isFinite(v);

const START_TOLERANCE_M = 0.002; // the table must rest this close to zero for a start (the service's default)

export class PositionPart {
  /** The rig's link (RigLink): explain why Start is disabled on a rig that does not answer. */
  showRigLink(link) {
    state.linkConnected = link.connected();
    state.linkArmed = Boolean(link.link && link.link.armed && link.source !== "test");
    this.rigLink = link;
    this.renderRigWarning();
    changed("link");
  }

  /** A start cannot succeed on this rig now: it does not answer, or its table rests off zero. Said above Start. */
  renderRigWarning() {
    const box = $("rig-warning");
    const link = this.rigLink;
    const down = Boolean(link && link.kind === "udp" && link.connected() === "false");
    const off = down ? null : this.offZero();
    const l = (down && link.link) || {};
    const key = down ? `down|${l.detail}` : off ? `off|${off.text}` : "ok";
    if (key !== this.warningKey) { // rebuilt only when it says something new (a click is never lost to a redraw)
      this.warningKey = key;
      box.classList.toggle("hidden", !down && !off);
      box.dataset.state = down ? "down" : off ? "off-zero" : "ok";
      box.innerHTML = "";
      if (down) {
        const arm = link.info && typeof link.info.arm_timeout_s === "number" ? fmtPeriod(link.info.arm_timeout_s) : "";
        box.append(el("b", { text: "Rig not connected: Start is disabled until it answers." }),
          el("div", { text: `${link.name()}: ${l.detail || "no answer"}. The service arms the rig at Start and gives ` +
            `up${arm ? ` after ${arm}` : ""} without an answer; check that the rig (or isorig rig-emulator) runs ` +
            "and is reachable." }));
      } else if (off) {
        const zero = el("button", { type: "button", id: "warning-zero", class: "small", text: "Zero the table..." });
        zero.addEventListener("click", () => this.manual.go("zero"));
        const actions = el("div", { class: "warning-actions" });
        if (off.startM !== 0) { // the offset was taken from the table, which has moved since
          const fromZero = el("button", { type: "button", id: "warning-from-zero", class: "small",
            text: "Start from zero instead" });
          fromZero.title = "the test starts at zero and reaches its offset during the first cycle";
          fromZero.addEventListener("click", () => this.startFromZero());
          actions.append(fromZero);
          if (!off.nearZero) actions.append(zero);
        } else actions.append(zero);
        actions.append(el("span", { text: "see Manual motion (end of the set-up)" }));
        box.append(el("b", { text: off.startM !== 0
          ? `Table not where this test starts (${fmtU("length", off.startM, { sign: true })}): Start is disabled until it rests there.`
          : "Table off zero: Start is disabled until it rests at zero." }),
        el("div", { text: `${capitalize(off.text)}.` }), actions);
      }
    }
    if (off) this.renderZeroButton(this.manual.blockers("zero"));
  }

  /** The Zero button of the off-zero warning: as usable as Manual motion's own. */
  renderZeroButton(blockers) {
    const button = $("warning-zero");
    if (!button) return;
    button.disabled = blockers.length > 0;
    button.title = blockers.length ? `Zero needs: ${blockers.join("; ")}` : "return the table to zero (asks for a confirmation)";
  }

  startTolerance() {
    const r = (this.rig && this.rig.rig) || {};
    return num(r.start_tolerance_m) ? r.start_tolerance_m : START_TOLERANCE_M;
  }

  /**
   * The table rests more than the start tolerance from zero (GET /api/rig/state while no test runs: a UDP rig's
   * own reading, the simulated rig's table where the last run left it): the service refuses a start there.
   * {at, text} in words, or null.
   */
  offZero() {
    const rs = state.rigState;
    if (!rs || rs.status === "not_connected" || testRunning()) return null;
    const where = tablePosition();
    if (!where || where.source === "live" || where.source === "unknown") return null;
    const tol = this.startTolerance();
    const start = this.startPositionM();
    if (Math.abs(where.m - start) <= tol) return null;
    const at = fmtU("length", where.m, { sign: true });
    const of = start === 0 ? "zero" : `where this test starts, ${fmtU("length", start, { sign: true })}`;
    return { at, startM: start, nearZero: Math.abs(where.m) <= tol,
      text: `the table rests at ${at} (${sourceWords(where.source)}) and a test starts only within ` +
      `\u00b1${fmtU("length", tol, { sig: 3 })} of ${of}` };
  }

  /** The sine's offset no longer taken from the table: the test starts at zero and reaches it in the first cycle. */
  startFromZero() {
    this.offsetTakenM = null;
    this.renderOffsetNote();
    this.formChanged();
  }

  /** Under the offset: where the test starts (the table position it was taken from, or zero). */
  renderOffsetNote(how = "") {
    const taken = this.offsetTakenM;
    $("offset-note").textContent = taken === null ? "" : `set from the table position ${fmtU("length", taken, { sign: true })}` +
      `${how ? ` (${how})` : ""}: the test starts there and runs about it (a typed offset is reached from zero during ` +
      "the first cycle).";
  }

  /** Where the test in the form begins (m): the table position its offset was taken from, else zero. */
  startPositionM() {
    const v = this.values || {};
    const taken = this.offsetTakenM;
    return this.isSine() && taken !== null && num(v.offset) && Math.abs(v.offset - taken) < 1e-9 ? taken : 0;
  }

  /** Where a sine's offset comes from: the table's position now (rounded to 0.01 mm), when it is known. */
  offsetFromTable() {
    const where = tablePosition();
    if (!where || this.locked) return;
    const m = Math.round(where.m / 1e-5) * 1e-5;
    this.setField("offset", m === 0 ? 0 : m);
    this.offsetTakenM = m === 0 ? null : m;
    this.renderOffsetNote(sourceWords(where.source));
    this.formChanged();
  }

  /** The "from table position" button: usable when the console knows where the table rests. */
  renderOffsetButton() {
    const where = tablePosition();
    const button = $("offset-from-table");
    button.disabled = !where || this.locked;
    button.title = where ? `set the offset to ${fmtU("length", where.m, { sign: true })} (${sourceWords(where.source)})`
      : "the table position is not known";
  }
}
