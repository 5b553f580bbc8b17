// Set-up panel: who and what (specimen, operator, notes), the isolator (its parameters, add one, delete a user
// one), conditions, the motion (sine or a shipped protocol, GET /api/protocols), the controller and its
// options, the limits each with its action (js/limits.js), and the rig envelope for the current choice (asked
// from the API at every change). Numbers are typed as text and parsed explicitly (js/parse.js) in the
// console's units (js/units.js); every field shows its unit and range. Start is enabled only when a start can
// succeed (a UDP rig's table must rest at zero) and asks for a confirmation with the service's figures of the
// motion. While a test runs the form shows that test (locked), also after a reload or in a second browser.
// Manual motion (js/manual.js) lives in this panel too: it moves the table with the set-up's conditions and
// limits, and a sine's offset can be taken from where the table rests.
//
// The panel is one class whose methods live in modules of one job each, joined here (js/mixin.js):
// setupfields.js (the numeric fields), setuplimits.js (limits and actions), setupmotion.js (rig, motion,
// controller), setupposition.js (the table's position and the start position), setupisolators.js,
// setupcheck.js (the request and its envelope check), setupstart.js (confirmation, Start, Stop) and
// setupfollow.js (the draft and a running test's set-up).

import { EarthquakeForm } from "./earthquake.js";
import { ManualMotion } from "./manual.js";
import { mixin } from "./mixin.js";
import { checkKey, CheckPart } from "./setupcheck.js";
import { FieldsPart } from "./setupfields.js";
import { FollowPart } from "./setupfollow.js";
import { IsolatorsPart } from "./setupisolators.js";
import { LimitsPart } from "./setuplimits.js";
import { MotionPart } from "./setupmotion.js";
import { PositionPart } from "./setupposition.js";
import { runningTestId, StartPart } from "./setupstart.js";
import { changed, onState, runName, state, testRunning } from "./state.js";
import { fmtU, onUnits } from "./units.js";
import { bindAccountField } from "./who.js";

const $ = (id) => document.getElementById(id);
const num = (v) => typeof v === "number" && Number.isFinite(v);

export { runningTestId }; // main.js asks which test runs

export class SetupPanel {
  constructor({ live }) {
    this.live = live;
    this.isolators = [];
    this.rig = null;
    this.protocols = []; // GET /api/protocols: [{name, title, description, levels, duration_s, ...}]
    this.protocolError = "";
    this.offsetTakenM = null; // the sine's offset taken from the table: the test starts there (start_m)
    this.checkSeq = 0;
    this.checkTimer = null;
    this.lastCheck = { ok: null, key: "", data: null };
    this.values = {}; // field key -> SI value (null: empty, undefined: not a valid number)
    this.refusal = null; // {cause, text}: a refused action, cleared when its cause is gone
    this.locked = false;
    this.lockedTestId = null;
    this.eq = new EarthquakeForm(this); // time history and hybrid simulation (js/earthquake.js)
    this.fields = { ...this.fieldSpecs(), ...this.eq.fieldSpecs() };
    this.manual = new ManualMotion(this);
  }

  async init() {
    bindAccountField($("f-operator_name"));
    await Promise.all([this.loadRig(), this.loadIsolators(), this.loadProtocols(), this.eq.loadPresets()]);
    this.eq.init();
    this.renderFieldMeta();
    this.restoreDraft();
    this.readAll();
    this.saveDraft(); // this operator's set-up (the defaults at first), where a test run elsewhere returns to
    const form = $("setup-form");
    form.addEventListener("input", (ev) => {
      if (ev.target.closest("#iso-form")) {
        this.readIsoField(ev.target);
        return;
      }
      if (ev.target.closest("#manual-motion")) return; // js/manual.js
      if (ev.target.id === "f-offset") {
        $("offset-note").textContent = "";
        this.offsetTakenM = null; // a typed offset is reached from zero
      }
      ev.target.dataset.touched = "1";
      this.formChanged();
    });
    form.addEventListener("change", (ev) => {
      if (ev.target.closest("#iso-form") || ev.target.closest("#manual-motion")) return;
      if (ev.target.id === "f-isolator") this.showIsolator();
      if (ev.target.id === "f-profile") this.showProfile();
      if (["f-eq_source", "f-eq_acc_unit", "f-eq_preset"].includes(ev.target.id)) this.eq.show();
      if (ev.target.type === "file") return; // read first (js/earthquake.js), then formChanged
      if (ev.target.id === "f-controller") this.showControllerOptions();
      if (ev.target.dataset.limit) this.showActionHelp();
      this.formChanged();
    });
    form.addEventListener("submit", (ev) => {
      ev.preventDefault();
      this.start();
    });
    $("stop").addEventListener("click", () => this.stop());
    $("offset-from-table").addEventListener("click", () => this.offsetFromTable());
    $("iso-save").addEventListener("click", () => this.saveIsolator());
    $("iso-delete").addEventListener("click", () => this.deleteIsolator());
    onUnits(() => this.onUnitsChanged());
    onState((what) => this.onStateChanged(what));
    this.showActionHelp();
    this.showProfile();
    this.updateButtons();
    this.scheduleCheck(0);
    this.onStateChanged("test"); // a test the stream announced before this panel was ready
    this.manual.init();
  }

  formChanged() {
    if (this.refusal && this.refusal.cause === "form") this.clearRefusal();
    else if (!this.refusal) this.message("", ""); // "cancelled", "saved": said once, gone at the next change
    const { body, problems } = this.body();
    this.saveDraft();
    this.renderRigWarning(); // where the test starts follows the offset (taken from the table or typed)
    if (this.protocol()) this.renderProtocol(); // the levels follow the design displacement
    // a value that is not valid is said at once (no request); who and notes do not change the envelope; an
    // unchanged set-up is not asked again (a blur's change event)
    if (Object.keys(problems).length) {
      clearTimeout(this.checkTimer);
      this.check();
    } else if (this.checkPending || this.lastCheck.local || checkKey(body) !== this.lastCheck.key) {
      // (a problem outside the body, such as a structure file that could not be read, is gone: ask the service)
      this.scheduleCheck();
    }
    this.updateButtons();
    changed("form");
  }

  onStateChanged(what) {
    if (what === "test" || what === "status") {
      const t = state.test;
      if (testRunning() && t && t.id === state.testId) this.followTest(t);
      else if (!testRunning() && this.locked) this.unlock();
    }
    if (what === "rigState" || what === "position" || what === "status") {
      this.renderRigWarning();
      this.renderOffsetButton();
    }
    if (what === "rig" || what === "rigState" || what === "status" || what === "conn" || what === "link" ||
        what === "test" || what === "stopping") {
      this.updateButtons();
    }
  }

  /** Why Start cannot succeed now ([] when it can). */
  startBlockers() {
    const out = [];
    if (!state.conn) out.push("no connection to the service");
    if (testRunning()) out.push(`${runName(state.test, state.testId ?? (state.rigState && state.rigState.test_id))} is running`);
    if (state.linkConnected === "false") out.push("the rig is not connected");
    else if (!testRunning()) {
      const off = this.offZero();
      if (off && off.startM === 0) out.push(`the table at zero (it rests at ${off.at}, see above: Zero brings it back)`);
      else if (off) out.push(`the table at ${fmtU("length", off.startM, { sign: true })}, where this test starts (it rests at ${off.at})`);
    }
    if (!this.locked) {
      const { body, problems } = this.body();
      if (!body.specimen_id) out.push("a specimen id");
      const bad = Object.keys(problems);
      if (bad.length) out.push(`valid values (${bad.map((k) => k.replace(/^lim_/, "limit ").replace(/_/g, " ")).join(", ")})`);
      else if (this.lastCheck.ok === false) out.push(this.lastCheck.local ? "valid values (see the fields)" : "a set-up within the rig envelope (see above)");
      else if (this.checkPending || this.lastCheck.key !== checkKey(body)) out.push("the envelope check (running)");
      else if (this.lastCheck.ok !== true) out.push("the envelope check (not available)");
    }
    return out;
  }

  updateButtons() {
    const blockers = this.startBlockers();
    const start = $("start");
    start.disabled = blockers.length > 0;
    const why = $("start-why");
    why.textContent = blockers.length ? `Start needs: ${blockers.join("; ")}.` : "Start asks for a confirmation with the motion before the valve opens.";
    why.className = `why${blockers.length ? " blocked" : ""}`;
    why.dataset.blocked = blockers.length ? "1" : "0";
    const stop = $("stop");
    stop.disabled = !testRunning() || state.stopping || !state.conn;
    stop.textContent = state.stopping ? "Stopping..." : "Stop";
    // a refusal whose cause is gone is cleared
    if (this.refusal) {
      const c = this.refusal.cause;
      if ((c === "busy" && !testRunning()) || (c === "rig" && state.linkConnected !== "false") ||
          (c === "conn" && state.conn) || (c === "position" && this.tableBackAtZero())) {
        this.clearRefusal();
      }
    }
  }

  message(text, kind = "") {
    const m = $("setup-message");
    m.textContent = text;
    m.className = `message ${kind}`;
  }

  /** After an off-zero refusal: the rig's own reading, asked after the refusal, is back within the tolerance. */
  tableBackAtZero() {
    const rs = state.rigState;
    if (testRunning()) return true;
    if (!rs || state.rigStateSeq <= this.refusal.rigStateSeq) return false;
    return rs.position_source !== "live" && num(rs.table_position_m) &&
      Math.abs(rs.table_position_m) <= this.startTolerance();
  }

  refuse(cause, text) {
    this.refusal = { cause, text, rigStateSeq: state.rigStateAsked }; // only a reading asked for after it counts
    this.message(text, "error");
    $("setup-message").dataset.cause = cause;
  }

  clearRefusal() {
    this.refusal = null;
    this.message("", "");
    delete $("setup-message").dataset.cause;
  }
}

mixin(SetupPanel, FieldsPart, LimitsPart, MotionPart, PositionPart, IsolatorsPart, CheckPart, StartPart, FollowPart);
