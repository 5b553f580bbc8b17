// What the console knows of the service and the rig, in one place. The live stream (hello, status, event), the
// rig block (link) and the set-up panel write here; the status strip, the set-up panel's buttons and the live
// view read it. listeners get the name of what changed.

export const state = {
  conn: false, // the live websocket is up
  everConnected: false,
  helloSeen: false, // the live stream said what runs (hello) since it last connected
  rig: null, // GET /api/rig
  linkConnected: "unknown", // "true" / "false" / "unknown" (RigLink.connected())
  linkArmed: false, // a UDP rig answered HELLO as armed
  rigState: null, // GET /api/rig/state (polled every 2 s)
  rigStateAsked: 0, // requests of GET /api/rig/state sent so far, numbered 1, 2, ...
  rigStateSeq: 0, // the number of the request whose answer rigState is (an older answer that comes later is dropped)
  testId: null, // the test in view (the live stream's)
  test: null, // its record
  status: null, // its status
  reason: "",
  stopping: false, // the running test is ending: a stop or abort was requested, or a limit tripped
  stoppingReason: "", // why, in words
  lastEvent: null, // {text, kind, at}
  position: null, // {m, testId, t, live}: the latest measured table position
  faulted: "", // why the rig is faulted (a test ended failed / rig fault), "" when not
};

const listeners = new Set();

export function onState(fn) {
  listeners.add(fn);
}

export function changed(what) {
  for (const fn of listeners) {
    try {
      fn(what);
    } catch (e) {
      console.warn("state listener failed", e); // eslint-disable-line no-console
    }
  }
}

/**
 * The record a position or force source names: "end of test 4 (completed)" or "end of move 7 (completed)" (a
 * manual move's end, as the service says it) -> {id, kind}, else null. Tests and moves share one numbering.
 */
export function endedRun(source) {
  const m = /^end of (test|move) (\d+)/.exec(source || "");
  return m ? { kind: m[1], id: Number(m[2]) } : null;
}

/** Is a test running now (as far as the console knows)? */
export function testRunning() {
  if (state.status === "running") return true;
  if (state.conn && state.helloSeen) return false; // the live stream is the truth while it is up
  const s = state.rigState && state.rigState.status;
  return s === "running" || s === "stopping";
}

/** A record of a manual move (POST /api/rig/move or /zero: profile kind "move"), not a test. */
export function isMove(t) {
  return Boolean(t && t.profile && !Array.isArray(t.profile) && t.profile.kind === "move");
}

/** A record of the rig's commissioning (POST /api/commissioning: profile kind "commissioning"), not a test. */
export function isCommissioning(t) {
  return Boolean(t && t.profile && !Array.isArray(t.profile) && t.profile.kind === "commissioning");
}

/** "manual move #7", "commissioning #7" or "test #7": what a record is, in words. */
export function runName(t, id) {
  return `${isMove(t) ? "manual move" : isCommissioning(t) ? "commissioning" : "test"} #${id ?? (t && t.id)}`;
}

/**
 * Where the table is, as far as the console knows: {m, source} or null. Live during a run (the stream's
 * latest sample); else GET /api/rig/state's figure (the end of the last run, a UDP rig's own reading), unless
 * the live stream has seen a later run end than that answer knows of (it comes within 2 s).
 */
export function tablePosition() {
  const num = (v) => typeof v === "number" && Number.isFinite(v);
  const running = testRunning();
  let rs = state.rigState || {};
  if (!running && (rs.status === "running" || rs.status === "stopping")) rs = {}; // an answer of before the end
  const p = state.position;
  if (running && p && p.live && num(p.m)) return { m: p.m, source: "live" };
  const ended = endedRun(rs.position_source);
  const newer = p && num(p.m) && ended && p.testId > ended.id;
  if (num(rs.table_position_m) && !newer) return { m: rs.table_position_m, source: rs.position_source || "" };
  if (p && num(p.m)) {
    const move = state.testId === p.testId && isMove(state.test);
    return { m: p.m, source: `end of ${move ? "move" : "test"} ${p.testId}` };
  }
  return null;
}

/**
 * The force and the valve command now, while no test runs: GET /api/rig/state's figures, each {value, source},
 * or {value: null, why} when the service has none (no test yet, a UDP rig that does not answer) or its answer
 * is of before the end of the last run the live stream saw (a new answer is asked at once).
 */
export function rigReadings() {
  const num = (v) => typeof v === "number" && Number.isFinite(v);
  const rs = state.rigState;
  const ended = endedRun(rs && rs.force_source);
  const p = state.position;
  const outdated = !rs || rs.status === "running" || rs.status === "stopping" ||
    (ended && p && p.testId > ended.id);
  const reading = (value, source) => {
    if (outdated) return { value: null, why: "no reading yet: waiting for the service's answer on the rig now" };
    return num(value) ? { value, source: source || "" } : { value: null, why: source || "no reading" };
  };
  return { force: reading(rs && rs.force_n, rs && rs.force_source),
    command: reading(rs && rs.command_v, rs && rs.command_source) };
}

/** Where a position figure comes from, in words: "live", "where test 4 left it", "the rig's reading". */
export function sourceWords(source) {
  if (source === "the rig (probe)") return "the rig's reading";
  const ended = endedRun(source);
  return ended ? `where ${ended.kind} ${ended.id} left it` : source || "unknown";
}
