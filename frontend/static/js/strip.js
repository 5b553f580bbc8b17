// The status strip under the top bar, always visible: the rig (running / stopping / idle / armed / faulted /
// not connected), supply pressure, table position and where that figure comes from, vertical load, the limits
// in force with their actions, and the last event in words. It reads js/state.js: the live stream (fresh, 10
// times a second during a test), the rig link, and GET /api/rig/state (every 2 s: also when no test runs, and
// what another console did); what the service does not report is said, not guessed.

import { limitsLines, limitsText } from "./limits.js";
import { isCommissioning, isMove, onState, runName, state, tablePosition, testRunning } from "./state.js";
import { eventLine } from "./ui.js";
import { fmt, fmtU, onUnits } from "./units.js";

const $ = (id) => document.getElementById(id);
const num = (v) => typeof v === "number" && Number.isFinite(v);

export class StatusStrip {
  constructor() {
    this.nextLimits = null; // () -> limits the next test would use (the set-up panel)
    onState(() => this.render());
    onUnits(() => this.render());
  }

  /**
   * GET /api/rig/state's last answer, unless it is older than what the live stream says: an answer of while the
   * test still ran, when the stream has seen it end (the next answer comes within 2 s).
   */
  serviceState() {
    const rs = state.rigState || {};
    const busy = rs.status === "running" || rs.status === "stopping";
    if (busy && state.conn && state.helloSeen && !testRunning()) return { driver: rs.driver, last_event: rs.last_event };
    return rs;
  }

  /** The rig's state: [word, class, why] (why is shown next to the word when it matters). */
  rigState() {
    const rs = this.serviceState();
    if (!state.conn) {
      return ["NO CONNECTION", "bad", state.everConnected ? "to the service: reconnecting; the rest is the last known state"
        : "connecting to the service..."];
    }
    if (state.linkConnected === "false" || rs.status === "not_connected") {
      return ["NOT CONNECTED", "bad", rs.detail || "the rig does not answer"];
    }
    if (testRunning()) {
      const id = state.testId ?? rs.test_id;
      const serviceStopping = rs.status === "stopping" && rs.test_id === id;
      if (state.stopping || serviceStopping) {
        return ["STOPPING", "stopping", state.stoppingReason || rs.stopping_reason || "the test is ending"];
      }
      return ["RUNNING", "running", runName(state.test, id)];
    }
    if (rs.status === "faulted") return ["FAULTED", "bad", rs.rig_status ? `the rig reports: ${rs.rig_status}` : "the rig reports a fault"];
    if (state.faulted) return ["FAULTED", "bad", state.faulted];
    if (state.linkArmed || rs.armed) return ["ARMED", "warn", "the rig is armed, no test runs"];
    const t = state.test;
    const simulated = (rs.driver || (state.rig && state.rig.driver)) === "simulated";
    const last = t && t.status && t.status !== "running" ? `; last test #${state.testId} ${t.status}` : "";
    return ["IDLE", "idle", `${simulated ? "simulated rig, " : "connected, "}no test runs${last}`];
  }

  render() {
    const [word, cls, why] = this.rigState();
    const rig = $("s-rig");
    rig.textContent = word;
    rig.title = why;
    rig.dataset.detail = why;
    const cell = $("s-rig-cell");
    cell.dataset.state = word.toLowerCase().replace(/ /g, "-");
    cell.className = `cell cell-rig ${cls}`;
    const showWhy = ["STOPPING", "NOT CONNECTED", "FAULTED"].includes(word) ||
      (word === "RUNNING" && (isMove(state.test) || isCommissioning(state.test)));
    $("s-rig-why").textContent = showWhy ? why : "";
    $("s-rig-why").title = showWhy ? why : "";
    const running = testRunning();
    const t = state.test || {};
    const rs = this.serviceState();
    // which rig this console drives, by name (several rigs' services may share the records)
    const rigName = rs.rig_name || (state.rigState && state.rigState.rig_name) || (state.rig && state.rig.rig_name);
    $("s-rig-label").textContent = rigName ? `rig ${rigName}` : "rig";
    this.renderSupply(running, t, rs);
    this.renderPosition(rs);
    // vertical load: the running test's, else the last test's condition
    const vl = $("s-vertical");
    const load = running && num(rs.vertical_load_n) ? rs.vertical_load_n : t.vertical_load_n;
    if (num(load)) {
      vl.textContent = `${fmtU("force", load, { sig: 4 })}${running ? "" : ` (test #${state.testId})`}`;
      vl.title = running ? "the running test's vertical load" : "the vertical load of the last test; each test sets its own";
    } else {
      vl.textContent = "no test yet";
      vl.title = "the vertical load is a condition of each test";
    }
    // limits: the running test's (with their actions), else those the next test would get
    const lim = running ? t.limits || rs.limits : this.nextLimits ? this.nextLimits() : null;
    const id = state.testId ?? rs.test_id;
    const what = isMove(state.test) ? "move" : isCommissioning(state.test) ? "commissioning" : "test";
    $("s-limits-label").textContent = running ? `limits of ${what} #${id}, action when exceeded` : "limits of the next test, action when exceeded";
    $("s-limits").textContent = limitsText(lim);
    $("s-limits").title = limitsLines(lim);
    this.renderRigFile(rs);
    // the last event: this page's (the test in view), else the service's latest
    const e = $("s-event");
    const mine = state.lastEvent;
    const theirs = rs.last_event;
    const text = mine ? mine.text : theirs ? `${theirs.test_id ? `test #${theirs.test_id}: ` : ""}${eventLine(theirs)}` : "none yet";
    e.textContent = text;
    e.title = text;
    e.dataset.kind = mine ? mine.kind : theirs ? theirs.kind : "";
  }

  /** The rig file in force and when it was commissioned (GET /api/rig/state: a rig applied elsewhere shows too). */
  renderRigFile(rs) {
    const cell = $("s-rigfile");
    const rf = rs.rig_file || (state.rigState && state.rigState.rig_file);
    if (!rf) {
      cell.textContent = "-";
      cell.title = "the service has not said which rig file is in force";
      return;
    }
    const date = rf.commissioned ? String(rf.commissioned).slice(0, 10) : "";
    const plant = rf.plant_changes && Object.keys(rf.plant_changes).length;
    const name = rf.how === "defaults" ? "sim.rig defaults" : rf.name;
    const when = date ? (name.includes(date) ? "" : ` \u00b7 commissioned ${date}`) : " \u00b7 not commissioned";
    cell.textContent = `${name}${when}${plant ? " \u00b7 simulated plant differs" : ""}`;
    cell.dataset.commissioned = date;
    cell.title = `${rf.name}\n${rf.source}\n${date ? `commissioned ${rf.commissioned}` : "never commissioned"}` +
      `${rf.how === "applied" ? `\napplied by ${rf.applied_by} at ${rf.applied_at} (commissioning ${rf.commissioning_id})` : ""}` +
      `${plant ? `\nthe simulated rig plays a rig unlike this file: ${Object.entries(rf.plant_changes).map(([k, v]) => `${k}=${v}`).join(", ")}` : ""}`;
  }

  /** Supply pressure: measured when the service reports it (a running test, a UDP rig's answer), else the setting. */
  renderSupply(running, t, rs) {
    const supply = $("s-supply");
    const set = running && num(t.supply_bar) ? t.supply_bar * 1e5 : null;
    if (num(rs.supply_pressure_pa)) {
      supply.textContent = `${fmtU("pressure", rs.supply_pressure_pa)}${set !== null ? ` (set ${fmt("pressure", set)})` : ""}`;
      supply.title = `measured (${rs.position_source === "live" ? "the running test's latest sample" : "the rig's answer"}, ` +
        "GET /api/rig/state every 2 s)";
    } else if (set !== null) {
      supply.textContent = `${fmtU("pressure", set)} set`;
      supply.title = "the running test's supply setting (the service reports no measured value yet)";
    } else {
      supply.textContent = "not reported";
      supply.title = "no measured supply pressure: no test runs and this rig reports none while idle";
    }
  }

  /** Table position and where the figure comes from: live, the end of a test or move, the rig's own answer. */
  renderPosition(rs) {
    const pos = $("s-position");
    const where = tablePosition();
    pos.dataset.source = where ? where.source : "";
    if (!where) {
      pos.textContent = "unknown";
      pos.title = rs.position_source ? `position source: ${rs.position_source}` : "no sample since this page opened";
      return;
    }
    pos.textContent = `${fmtU("length", where.m, { sign: true })} \u00b7 ${where.source || "?"}`;
    pos.title = {
      live: "measured, live (the running test's latest sample)",
      "the rig (probe)": "the rig's own reading, asked every 2 s while no test runs",
    }[where.source] || `the last sample of the last run (${where.source}): the simulated table stays where a test or ` +
      "move left it (also after a trip, an abort or a restart of the service)";
  }
}
