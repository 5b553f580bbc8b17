// The status strip under the top bar, always visible: the rig (connected / armed / running / stopping /
// faulted), supply pressure, table position, vertical load, the limits in force and the last event in words.
// Everything comes from js/state.js (the live stream, the rig link, GET /api/rig, GET /api/rig/state when the
// service has it); what the service does not report is said, not guessed.

import { onState, state, testRunning } from "./state.js";
import { fmtU, onUnits } from "./units.js";

const $ = (id) => document.getElementById(id);
const num = (v) => typeof v === "number" && Number.isFinite(v);

export function limitsText(lim) {
  if (!lim) return "-";
  return [
    num(lim.displacement_m) ? `|d| ${fmtU("length", lim.displacement_m, { sig: 4 })}` : "",
    num(lim.force_n) ? `|F| ${fmtU("force", lim.force_n, { sig: 4 })}` : "",
    num(lim.tracking_error_m) ? `|y-r| ${fmtU("length", lim.tracking_error_m, { sig: 4 })}` : "",
    num(lim.load_pressure_pa) ? `|P_L| ${fmtU("pressure", lim.load_pressure_pa, { sig: 4 })}` : "",
  ].filter(Boolean).join(" \u00b7 ");
}

export class StatusStrip {
  constructor() {
    this.nextLimits = null; // () -> limits the next test would use (the set-up panel)
    onState((what) => this.render(what));
    onUnits(() => this.render("units"));
  }

  /** The rig's state in one word and a class. */
  rigState() {
    const t = state.test;
    const id = state.testId;
    if (!state.conn) {
      return ["NO CONNECTION", "bad", state.everConnected ? "to the service: reconnecting; the rest is the last known state" : "connecting to the service..."];
    }
    if (state.linkConnected === "false") return ["NOT CONNECTED", "bad", "the rig does not answer"];
    if (testRunning()) {
      if (state.stopping) return ["STOPPING", "stopping", `test #${id}: ramp-out to the end of the next whole cycle`];
      return ["RUNNING", "running", `test #${id ?? (state.rigState && state.rigState.test_id)}`];
    }
    if (state.faulted) return ["FAULTED", "bad", state.faulted];
    const rs = state.rigState || {};
    if (state.linkArmed || rs.armed) return ["ARMED", "warn", "the rig is armed, no test runs"];
    const kind = state.rig && state.rig.rig && state.rig.rig.kind;
    const last = t && t.status && t.status !== "running" ? `; last test #${id} ${t.status}` : "";
    return ["IDLE", "idle", `${kind === "simulated" ? "simulated rig, " : "connected, "}no test runs${last}`];
  }

  render() {
    const [word, cls, detail] = this.rigState();
    const rig = $("s-rig");
    rig.textContent = word;
    rig.title = detail;
    const cell = $("s-rig-cell");
    cell.dataset.state = word.toLowerCase().replace(/ /g, "-");
    cell.className = `cell cell-rig ${cls}`;
    rig.dataset.detail = detail;
    const running = testRunning();
    const t = state.test || {};
    const rs = state.rigState || {};
    // supply pressure: measured when the service reports it, else the running test's setting
    const supply = $("s-supply");
    if (num(rs.supply_pressure_pa)) {
      supply.textContent = fmtU("pressure", rs.supply_pressure_pa);
      supply.title = "measured (GET /api/rig/state)";
    } else if (running && num(t.supply_bar)) {
      supply.textContent = `${fmtU("pressure", t.supply_bar * 1e5)} set`;
      supply.title = "the running test's supply setting (the stream does not carry the measured supply pressure)";
    } else {
      supply.textContent = "not reported";
      supply.title = "the service reports no supply pressure while no test runs (no GET /api/rig/state)";
    }
    // table position: the latest measured sample (live during a test; the last of the last test otherwise)
    const pos = $("s-position");
    const p = state.position;
    if (num(rs.table_position_m) && !(p && p.live)) {
      pos.textContent = fmtU("length", rs.table_position_m, { sign: true });
      pos.title = "measured (GET /api/rig/state)";
    } else if (p && num(p.m)) {
      pos.textContent = `${fmtU("length", p.m, { sign: true })}${p.live && running ? "" : ` (end of test #${p.testId})`}`;
      pos.title = p.live && running ? "measured, live" : `last measured sample of test #${p.testId}, t = ${p.t.toFixed(2)} s`;
    } else {
      pos.textContent = "unknown";
      pos.title = "no sample since this page opened and no GET /api/rig/state on this service";
    }
    // vertical load: the running test's (or the last test's) condition
    const vl = $("s-vertical");
    if (num(rs.vertical_load_n) && !running) {
      vl.textContent = fmtU("force", rs.vertical_load_n, { sig: 4 });
    } else if (num(t.vertical_load_n)) {
      vl.textContent = `${fmtU("force", t.vertical_load_n, { sig: 4 })}${running ? "" : ` (test #${state.testId})`}`;
    } else {
      vl.textContent = "no test yet";
      vl.title = "the vertical load is a condition of each test";
    }
    // limits: the running test's, else those the next test would get
    const lim = running && t.limits ? t.limits : this.nextLimits ? this.nextLimits() : null;
    $("s-limits-label").textContent = running ? `limits of test #${state.testId} (trip: abort)` : "limits of the next test";
    $("s-limits").textContent = limitsText(lim);
    const ev = state.lastEvent;
    const e = $("s-event");
    e.textContent = ev ? ev.text : "none yet";
    e.title = ev ? ev.text : "";
    e.dataset.kind = ev ? ev.kind : "";
  }
}
