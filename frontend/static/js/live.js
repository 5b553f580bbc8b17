// Live view: follows /ws/live (websocket schema v1: hello, samples, status, cycle, event), keeps the recent
// samples in typed-array buffers (display units) and redraws the plots on requestAnimationFrame with a smoothly
// advancing clock. Also: large readouts with the current cycle's peak and valley, the margin left to each
// limit with its action and how often an indicating limit was exceeded, the events in words (a stop or abort
// asked from any console arrives as an event), the trip banner with the action taken, and what the console
// knows of the test (js/state.js) for the strip and the form.
//
// The view is one class whose methods live in modules of one job each, joined here (js/mixin.js):
// liveplots.js (plots and loops), livereadouts.js (readouts and margins), liveevents.js (events and trips),
// liveconnection.js (the websocket); the samples are kept in livebuffer.js.

import { NewestOnly } from "./api.js";
import { EarthquakeLive } from "./eqlive.js";
import { BAD, Buffer, CAP, emptyExtremes, FINAL } from "./livebuffer.js";
import { ConnectionPart } from "./liveconnection.js";
import { EventsPart } from "./liveevents.js";
import { HeadlinePart, lastSteady } from "./liveheadline.js";
import { metrics } from "./livemetrics.js";
import { PlotsPart } from "./liveplots.js";
import { ReadoutsPart } from "./livereadouts.js";
import { mixin } from "./mixin.js";
import {
  changed, isCommissioning, isMove, onState, rigReadings, sourceWords, state, tablePosition, testRunning,
} from "./state.js";
import { fmtDuration, profileText, setStatusBadge, showAlert } from "./ui.js";
import { factorIn, fmtU, onUnits, system, toDisplay } from "./units.js";

const $ = (id) => document.getElementById(id);
const num = (v) => typeof v === "number" && Number.isFinite(v);

export { metrics }; // window.__isorig: the figures the browser tests read

/** The header's cycle from a record, as the service's status says it: the cycle under way while the test runs,
 * the cycles done once it has ended; {} when the record does not say. */
function cycleOf(rec) {
  if (!rec || !Number.isFinite(rec.cycles_done) || !Number.isFinite(rec.cycles_total) || !rec.cycles_total) return {};
  if (rec.status !== "running" && !FINAL.has(rec.status)) return {};
  const running = rec.status === "running";
  return { cycle: running ? Math.min(rec.cycles_done + 1, rec.cycles_total) : rec.cycles_done, cycles_total: rec.cycles_total };
}

export class LiveView {
  constructor({ onTest, onLink } = {}) {
    this.onTest = onTest || (() => {});
    this.onLink = onLink || (() => {}); // a status message with a real rig's link figures
    this.buf = new Buffer();
    this.loopRequests = new NewestOnly(); // the stored loops (a reconnect, a test's end): only the newest answer drawn
    this.testId = null;
    this.test = null;
    this.status = null;
    this.lastT = -Infinity;
    this.cycleStart = 0; // buffer index where the current loop cycle began
    this.crossings = []; // buffer indices of upward zero crossings of the target not yet shown
    this.prevTarget = NaN;
    this.offset = 0; // the profile's offset, display units
    this.tDisp = 0; // displayed test time
    this.rate = 1; // test seconds per wall second (the speed factor)
    this.arrivals = []; // [wall ms, test time] of recent sample batches
    this.lastWall = performance.now();
    this.dirty = false;
    this.visible = true;
    this.ws = null;
    this.wsWanted = true;
    this.retryAt = 0;
    this.backoffMs = 250;
    this.plots = null;
    this.sys = system();
    this.adaptScale = { ar: 1, ay: 1, as: 1 };
    this.adaptQuantity = { ar: null, ay: null, as: null };
    this.adaptChannels = [];
    this.modelIsTarget = false;
    this.storedUntil = -Infinity;
    this.localLoops = [];
    this.lastCyc = null;
    this.cyc = emptyExtremes(0);
    this.readoutAt = 0;
    this.events = []; // [{key, e, arrived}] in order
    this.eq = new EarthquakeLive(); // a time-history or hybrid test: the whole record, drifts, stability
    onUnits(() => this.onUnitsChanged());
    // between tests the readouts are the rig now (where the table is, its force, the valve command), as the rig
    // (or the service) says, never the last sample of a test that ended before the service restarted
    onState((what) => { if (what === "rigState" || what === "status" || what === "conn") this.showRigNow(); });
  }

  /**
   * No test running: the DISPLACEMENT readout shows the table's position now (the strip's), FORCE and COMMAND
   * the service's figures of the rig now (GET /api/rig/state), each with its source; a dash says why not.
   */
  showRigNow() {
    if (testRunning()) return;
    const where = tablePosition();
    const el = $("r-y");
    if (!where) {
      el.textContent = "-";
      el.title = "the table now: no reading: no run on record and no reading of the rig";
      el.dataset.source = "none";
    } else if (where.source !== "live") {
      el.textContent = fmtU("length", where.m, { sign: true });
      el.title = `the table now: ${sourceWords(where.source)}`;
      el.dataset.source = where.source;
    }
    const now = rigReadings();
    showReading($("r-f"), "force", "the force now", now.force);
    showReading($("r-v"), "voltage", "the valve command now", now.command);
  }

  resetTest(testId, test) {
    this.buf.clear();
    this.testId = testId;
    metrics.testId = testId; // the test in view, also before its first sample is drawn
    this.test = test;
    this.lastT = -Infinity;
    this.trips = []; // the limit trips of this test in words (a second one: a valve close during a controlled stop)
    this.storedUntil = -Infinity;
    this.localLoops = [];
    this.cycleStart = 0;
    this.lastCyc = null;
    this.cyc = emptyExtremes(0);
    this.crossings = [];
    this.prevTarget = NaN;
    this.tDisp = 0;
    this.arrivals = [];
    this.events = [];
    const speed = test && (test.speed || (test.scenario && test.scenario.speed));
    this.rate = speed > 0 ? speed : 1;
    this.setProfile(test);
    this.setController(test && test.controller);
    if (this.plots) this.plots.loop.reset();
    this.renderEvents();
    this.clearHeadline();
    ["l-cycle", "l-progress", "l-left", "r-y", "r-y-max", "r-y-min", "r-f", "r-f-max",
      "r-f-min", "r-v", "r-v-max", "r-v-min"].forEach((id) => { $(id).textContent = "-"; });
    $("l-progress-bar").style.width = "0";
    state.testId = testId;
    state.test = test;
    state.stopping = false;
    state.stoppingReason = "";
    state.faulted = "";
    this.renderMargins(true);
    this.dirty = true;
  }

  setProfile(test) {
    this.eq.setTest(this.testId, test);
    let profile = test && (test.profile || (test.scenario && test.scenario.profile));
    if (Array.isArray(profile)) profile = profile[0];
    this.offset = profile && profile.offset_m ? toDisplay("length", profile.offset_m) : 0;
  }

  onSamples(msg) {
    const cols = msg.columns;
    const ix = (name) => cols.indexOf(name);
    const it = ix("time_s"), ir = ix("target_m"), im = ix("model_m"), iy = ix("displacement_m");
    const iv = ix("voltage_v"), iF = ix("force_n"), ipl = ix("load_pressure_pa");
    const iar = ix("ar_hat"), iay = ix("ay_hat"), ias = ix("as_hat");
    const val = (v) => (v === null || v === undefined ? NaN : v);
    const b = this.buf;
    const a = b.a;
    const fx = factorIn("length", this.sys);
    const ff = factorIn("force", this.sys);
    const fp = factorIn("pressure", this.sys);
    const sc = this.adaptScale;
    this.eq.onSamples(msg, this.lastT);
    for (const row of msg.rows) {
      const t = row[it];
      if (!(t > this.lastT)) continue; // history replay after a reconnect: skip what we have
      if (b.len >= CAP) {
        const drop = b.compact();
        this.cycleStart = Math.max(0, this.cycleStart - drop);
        this.lastCyc = null;
        this.cyc = emptyExtremes(this.cycleStart);
        this.crossings = this.crossings.map((j) => j - drop).filter((j) => j > 0);
      }
      const k = b.len++;
      const r = val(row[ir]) * fx;
      const ym = val(row[im]) * fx;
      const y = val(row[iy]) * fx;
      a.t[k] = t;
      a.r[k] = r;
      a.ym[k] = ym;
      a.y[k] = y;
      a.v[k] = val(row[iv]);
      a.f[k] = val(row[iF]) * ff;
      a.pl[k] = ipl >= 0 ? val(row[ipl]) * fp : NaN;
      a.ar[k] = val(row[iar]) * sc.ar;
      a.ay[k] = val(row[iay]) * sc.ay;
      a.as[k] = val(row[ias]) * sc.as;
      a.e_ym[k] = y - ym;
      a.e_r[k] = y - r;
      const rr = r - this.offset;
      if (this.prevTarget <= 0 && rr > 0 && k > 0) this.crossings.push(k);
      this.prevTarget = rr;
      this.lastT = t;
    }
    metrics.samples += msg.rows.length;
    const now = performance.now();
    if (b.len) {
      this.arrivals.push([now, b.a.t[b.len - 1]]);
      while (this.arrivals.length > 2 && now - this.arrivals[0][0] > 2000) this.arrivals.shift();
      const [w0, s0] = this.arrivals[0];
      if (now - w0 > 400) {
        const est = (b.a.t[b.len - 1] - s0) / ((now - w0) / 1000);
        if (est > 0.05) this.rate = 0.7 * this.rate + 0.3 * est;
      }
    }
    this.dirty = true;
  }

  onStatus(msg) {
    const changedStatus = msg.status !== this.status;
    const firstLook = this.status === null; // this page's first status: how a test ended before it looked is no news
    this.status = msg.status;
    state.status = msg.status;
    state.reason = msg.reason || "";
    if (msg.status === "running") state.faulted = "";
    if (FINAL.has(msg.status)) {
      state.stopping = false;
      state.stoppingReason = "";
      this.noteEndCommand(); // how still the valve was at the end (window.__isorig)
    }
    if (msg.status === "failed") state.faulted = msg.reason || "the test failed";
    setStatusBadge(state.stopping && msg.status === "running" ? "stopping" : msg.status);
    if (msg.stability) this.eq.onStability(msg.stability);
    const none = this.noCycles();
    if (none) {
      $("l-cycle").textContent = none;
    } else if (msg.cycle !== undefined && msg.cycle !== null) {
      $("l-cycle").textContent = msg.cycles_total ? `${msg.cycle} / ${msg.cycles_total}` : String(msg.cycle);
    }
    if (typeof msg.progress === "number") {
      const pct = Math.max(0, Math.min(1, msg.progress)) * 100;
      $("l-progress").textContent = `${pct.toFixed(0)} %`;
      $("l-progress-bar").style.width = `${pct}%`;
    }
    if (typeof msg.time_left_s === "number" && !FINAL.has(msg.status)) {
      $("l-left").textContent = fmtDuration(msg.time_left_s);
    } else if (FINAL.has(msg.status)) {
      $("l-left").textContent = "-";
    }
    if (changedStatus && this.testId !== null) {
      // a move of the table (POST /api/rig/move, /zero), the rig's commissioning (POST /api/commissioning), a test
      const what = isMove(this.test) ? "Manual move" : isCommissioning(this.test) ? "Commissioning" : "Test";
      if (firstLook) {
        // no banner: the strip's last event and the status badge say how the last test ended
      } else if (BAD.has(msg.status)) {
        const trip = this.tripText();
        const reason = trip || msg.reason || ""; // the trip in words with its action, not the detector's internals
        showAlert(`${trip ? "LIMIT TRIP - " : ""}${what} ${this.testId} ${msg.status.toUpperCase()}` +
          `${reason ? ": " + reason : ""}`, "bad");
      } else if (FINAL.has(msg.status)) {
        showAlert(`${what} ${this.testId} ${msg.status}`, "info");
      }
      this.onTest(this.testId, msg.status);
      if (FINAL.has(msg.status)) this.refreshEvents(this.testId);
    }
    changed("status");
  }

  onHello(msg) {
    state.helloSeen = true;
    const test = msg.test || null;
    const id = msg.test_id === undefined ? (test ? test.id : null) : msg.test_id;
    if (id === null) {
      // nothing runs (e.g. after a service restart): keep the last test on screen and show how it ended
      if (this.testId !== null) this.refreshEnded(this.testId);
      else {
        setStatusBadge("idle");
        state.status = null;
        changed("status");
      }
      return;
    }
    const fresh = id !== this.testId;
    if (fresh) this.resetTest(id, test);
    else this.test = test || this.test;
    state.test = this.test;
    this.renderHead();
    for (const e of (test && test.events) || []) this.noteTrip(e); // the banner below says the trip in words
    if (test && test.status) this.onStatus({ status: test.status, test_id: id, reason: test.reason, ...cycleOf(test) });
    this.loadLastCycle(id);
    if (test) this.loadStoredLoops(id, test.cycles_done);
    if (test) this.mergeEvents(test.events);
    changed("test");
  }

  /** The stream has no test any more: ask for the last one's record (it may have ended interrupted). */
  refreshEnded(testId) {
    fetch(`/api/tests/${testId}`).then((r) => (r.ok ? r.json() : null)).then((rec) => {
      if (!rec || this.testId !== testId) return;
      this.test = rec;
      state.test = rec;
      this.mergeEvents(rec.events);
      // the record's cycles: the header said the last streamed cycle ("6 / 30") beside a record of 17 cycles
      this.onStatus({ status: rec.status, test_id: testId, reason: rec.reason, progress: rec.progress, ...cycleOf(rec) });
      this.renderHeadline();
      if (FINAL.has(rec.status)) this.showEndedLoops(testId);
      changed("test");
    }).catch(() => {});
  }

  /** The latest finished cycle's metrics of a test we join late (the stream only sends new ones). */
  loadLastCycle(testId) {
    fetch(`/api/tests/${testId}/cycles`).then((r) => (r.ok ? r.json() : [])).then((cycles) => {
      if (this.testId !== testId || !Array.isArray(cycles) || !cycles.length) return;
      if (this.lastCycle) return; // a live cycle came first
      const steady = lastSteady(cycles);
      if (steady) this.lastSteadyCycle = { cycle: steady.cycle, phase: "steady", metrics: steady };
      const last = cycles[cycles.length - 1];
      this.onCycle({ cycle: last.cycle, phase: last.phase, metrics: last });
    }).catch(() => {});
  }

  renderHead() {
    const t = this.test;
    $("l-test").textContent = this.testId === null ? "none" : `#${this.testId}`;
    const iso = t && (t.isolator || (t.scenario && t.scenario.isolator && t.scenario.isolator.name));
    $("l-isolator").textContent = typeof iso === "string" ? iso : iso && iso.name ? iso.name : "-";
    const load = t && (num(t.vertical_load_n) ? t.vertical_load_n
      : t.scenario && num(t.scenario.vertical_load_n) ? t.scenario.vertical_load_n : null);
    $("l-vertical-load").textContent = load === null ? "-" : fmtU("force", load, { sig: 4 });
    $("l-specimen").textContent = (t && t.specimen_id) || "-";
    $("l-operator").textContent = (t && t.operator_name) || "-";
    $("l-profile").textContent = t ? profileText(t) : "-";
    const notes = (t && t.notes) || "";
    $("l-notes").textContent = notes || "-";
    $("l-notes").title = notes;
    this.renderHeadline();
  }

  /** A run without cycles (a history, a move, a commissioning) says so in the header's cycle field; else null. */
  noCycles() {
    if (this.eq.kind) return `none (${this.eq.kind === "hybrid" ? "a hybrid simulation" : "a time history"})`;
    if (isMove(this.test) || isCommissioning(this.test)) return `none (a ${isMove(this.test) ? "manual move" : "commissioning"})`;
    return null;
  }

  /** A message of a test we have no record of (started after hello): fetch its record for the header. */
  followNew(testId) {
    this.resetTest(testId, null);
    this.renderHead();
    changed("test");
    fetch(`/api/tests/${testId}`).then((r) => (r.ok ? r.json() : null)).then((rec) => {
      if (!rec || this.testId !== testId) return;
      this.test = rec;
      state.test = rec;
      if (rec.speed > 0 && this.arrivals.length < 3) this.rate = rec.speed;
      this.setProfile(rec);
      this.setController(rec.controller);
      this.loadStoredLoops(testId, rec.cycles_done);
      this.mergeEvents(rec.events);
      this.renderHead();
      this.renderMargins(true);
      const none = this.noCycles(); // the record may come after the run's last status message
      if (none) $("l-cycle").textContent = none;
      changed("test");
    }).catch(() => {});
  }

  handle(msg) {
    metrics.messages++;
    metrics.lastMessageMs = performance.now();
    switch (msg.type) {
      case "hello": this.onHello(msg); break;
      case "samples":
        if (msg.test_id !== undefined && msg.test_id !== this.testId) this.followNew(msg.test_id);
        this.onSamples(msg);
        break;
      case "status":
        if (msg.test_id !== undefined && msg.test_id !== this.testId) this.followNew(msg.test_id);
        this.onStatus(msg);
        if (msg.link) this.onLink(msg);
        break;
      case "cycle": if (msg.test_id === this.testId) this.onCycle(msg); break;
      case "event": if (msg.test_id === this.testId || msg.test_id === null || msg.test_id === undefined) this.onEvent(msg); break;
      default: break; // unknown types are ignored (schema v1 may grow)
    }
  }
}

mixin(LiveView, PlotsPart, ReadoutsPart, EventsPart, ConnectionPart, HeadlinePart);

/** A readout of the rig now (between tests): the figure with its source in the tooltip, or a dash saying why not. */
function showReading(el, quantity, what, reading) {
  if (reading.value === null) {
    el.textContent = "-";
    el.title = `${what}: ${reading.why}`;
    el.dataset.source = "none";
    return;
  }
  el.textContent = fmtU(quantity, reading.value, { sign: true });
  el.title = `${what}: ${sourceWords(reading.source)}`;
  el.dataset.source = reading.source;
}
