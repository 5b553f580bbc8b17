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
  rigStateSeq: 0, // answers of GET /api/rig/state received so far
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

/** Is a test running now (as far as the console knows)? */
export function testRunning() {
  if (state.status === "running") return true;
  if (state.conn && state.helloSeen) return false; // the live stream is the truth while it is up
  const s = state.rigState && state.rigState.status;
  return s === "running" || s === "stopping";
}
