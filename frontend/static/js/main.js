// Dashboard entry point: views (live, history, one test, commissioning), the status strip, the always-visible
// Abort, the login, the unit choice, the 3D view.

import { AccountsPage } from "./accounts.js";
import { account, api, askLogin, logOut, onAccount, refreshAccount } from "./api.js";
import { CommissionPage } from "./commission.js";
import { History } from "./history.js";
import { LabPage } from "./labpage.js";
import { LiveView } from "./live.js";
import { RigLink } from "./rig.js";
import { runningTestId, SetupPanel } from "./setup.js";
import { changed, onState, state, testRunning } from "./state.js";
import { StatusStrip } from "./strip.js";
import { el, hideAlert, showAlert } from "./ui.js";
import { onUnits, setSystem, system } from "./units.js";
import { watchLiveVerdict } from "./verdict.js";

const $ = (id) => document.getElementById(id);
// The embedded 3D view shares the page's renderer (same origin); its frame rate is capped so the plots stay
// fluid: 30/s with a GPU, 10/s where WebGL runs in software. /viewer/ opened on its own runs at full rate.
const VIEWER_MAX_FPS = { hardware: 30, software: 10 };

const rigLink = new RigLink({ onChange: (link) => setup.showRigLink(link) });
const live = new LiveView({
  onTest: (id, status) => {
    if (currentView === "history") historyView.showList();
    if (setup.refusal === null && (status === "completed" || status === "stopped" || status === "aborted")) {
      setup.message("", "");
    }
  },
  onLink: (msg) => rigLink.fromStatus(msg),
});
const setup = new SetupPanel({ live });
const historyView = new History();
const labPage = new LabPage();
const accountsPage = new AccountsPage();
const strip = new StatusStrip();
strip.nextLimits = () => setup.nextLimits();
const commission = new CommissionPage({ onApplied: () => reloadRig() });
let currentView = "";

function route() {
  const hash = location.hash || "#/live";
  const m = hash.match(/^#\/tests\/(\d+)/);
  const c = hash.match(/^#\/commission(?:\/(\d+))?/);
  const view = m ? "test" : c ? "commission" : hash.startsWith("#/history") ? "history"
    : hash.startsWith("#/lab") ? "lab" : hash.startsWith("#/accounts") ? "accounts" : "live";
  currentView = view;
  for (const v of ["live", "history", "test", "commission", "lab", "accounts"]) $(`view-${v}`).classList.toggle("hidden", v !== view);
  document.querySelectorAll("nav a").forEach((a) => {
    a.classList.toggle("active", a.dataset.view === (view === "test" ? "history" : view));
  });
  live.visible = view === "live" && !document.hidden;
  live.dirty = true;
  if (view === "history") historyView.showList();
  if (view === "lab") labPage.load();
  if (view === "accounts") accountsPage.show();
  else accountsPage.hide();
  if (view === "test") historyView.showTest(Number(m[1]));
  if (view === "commission" && commissionReady) commission.show(c[1] ? Number(c[1]) : null);
  else commission.hide();
}

let commissionReady = false;

/** A rig file was made the service's rig (the Commissioning page): the set-up's envelope, limits and rig block
 * follow GET /api/rig again. */
async function reloadRig() {
  try {
    const rig = await api.get("/api/rig");
    setup.rig = rig;
    state.rig = rig;
    document.body.dataset.rigFile = (rig.rig_file && rig.rig_file.name) || "";
    setup.renderFieldMeta();
    setup.formChanged();
    rigLink.setInfo(rig);
    commission.setRig(rig);
    changed("rig");
  } catch { /* the next page load reads it */ }
}

/** A rig file applied from another console (or a script) changes what the set-up, the rig link and the
 * Commissioning page assume: the rig-state poll names the rig file in force, and a change of it reads /api/rig
 * again here too (before, only the console that applied it learnt of it; the others at their next reload). */
let rigFileSeen = null;
function followRigFile() {
  const rf = state.rigState && state.rigState.rig_file;
  if (!rf) return;
  const key = JSON.stringify([rf.name, rf.source, rf.how, rf.applied_at, rf.commissioning_id]);
  if (rigFileSeen !== null && key !== rigFileSeen) reloadRig();
  rigFileSeen = key;
}

async function abort() {
  const button = $("abort");
  button.disabled = true;
  try {
    const id = await runningTestId(live);
    if (id === null) {
      showAlert("Abort: no test is running.", "warn");
      return;
    }
    await api.endTest(`/api/tests/${id}/abort`);
    showAlert(`Test #${id} ABORTED by the operator.`, "bad");
  } catch (e) {
    showAlert(`Abort failed: ${e.message}`, "bad");
  } finally {
    button.disabled = false;
  }
}

const VIEWER_KEY = "isorig.viewer"; // "on" / "off": the operator's choice in this browser

/** Does this browser render WebGL in software (SwiftShader, llvmpipe)? Then the 3D view is costly. */
function softwareWebGL() {
  try {
    const gl = document.createElement("canvas").getContext("webgl");
    if (!gl) return true;
    const ext = gl.getExtension("WEBGL_debug_renderer_info");
    const renderer = String(gl.getParameter(ext ? ext.UNMASKED_RENDERER_WEBGL : gl.RENDERER));
    const lose = gl.getExtension("WEBGL_lose_context");
    if (lose) lose.loseContext();
    return /swiftshader|llvmpipe|softpipe|software/i.test(renderer);
  } catch {
    return true;
  }
}

/**
 * The 3D view: on unless the service has it off, the operator hid it in this browser, or WebGL runs in
 * software (then it waits for a click, since it slows the plots). ?viewer=on|off in the URL overrides.
 */
async function setupViewer() {
  const box = $("viewer-box");
  const toggle = $("viewer-toggle");
  let info = null;
  try {
    info = await api.get("/viewer/status");
  } catch {
    info = null;
  }
  if (!info || !info.enabled) {
    box.classList.add("off");
    box.innerHTML = "<p class=\"muted\">The 3D view is switched off on this service (ISORIG_VIEWER=0).</p>";
    toggle.classList.add("hidden");
    return;
  }
  const software = softwareWebGL();
  const maxFps = software ? VIEWER_MAX_FPS.software : VIEWER_MAX_FPS.hardware;
  const show = (on) => {
    box.innerHTML = "";
    box.classList.toggle("off", !on);
    toggle.textContent = on ? "hide 3D view" : "show 3D view";
    box.dataset.state = on ? "on" : "off";
    if (!on) {
      box.innerHTML = software && localStorage.getItem(VIEWER_KEY) === null
        ? "<p class=\"muted\">3D view paused: this browser renders WebGL in software, which slows the live " +
          "plots. Use \"show 3D view\" to see it anyway.</p>"
        : "<p class=\"muted\">3D view hidden in this browser.</p>";
      return;
    }
    const frame = document.createElement("iframe");
    frame.src = "/viewer/";
    frame.title = "3D rig view";
    frame.loading = "lazy";
    frame.addEventListener("load", () => capFrameRate(frame.contentWindow, maxFps));
    box.append(frame);
  };
  const param = new URLSearchParams(location.search).get("viewer");
  const stored = localStorage.getItem(VIEWER_KEY);
  let on = param ? param === "on" : stored ? stored === "on" : !software;
  toggle.addEventListener("click", () => {
    on = !on;
    localStorage.setItem(VIEWER_KEY, on ? "on" : "off");
    show(on);
  });
  show(on);
}

/** Let animation frames of window w through at most maxFps times per second (all callbacks of a frame together). */
function capFrameRate(w, maxFps) {
  if (!w || w.__isorigCapped) return;
  const raf = w.requestAnimationFrame.bind(w);
  const period = 1000 / maxFps;
  let next = 0;
  let openFrame = -1; // timestamp of the frame let through
  w.requestAnimationFrame = (cb) => raf(function tick(t) {
    if (t !== openFrame) {
      if (t < next) return raf(tick);
      openFrame = t;
      next = Math.max(next + period, t);
    }
    return cb(t);
  });
  w.__isorigCapped = true;
}

/** The account button: "log in", or who is logged in and their role (a click logs out). */
function showAccount() {
  const b = $("account-button");
  b.replaceChildren(...(account.name
    ? [el("span", { class: "acct-name", text: account.name }), el("span", { class: "acct-role", text: account.role })]
    : ["log in"]));
  b.title = account.name ? `logged in as ${account.name}, role ${account.role}: click to log out` : "log in to run "
    + "tests, move the rig or approve records (ABORT and Stop need no login)";
  b.dataset.role = account.role || "";
}

/** The live loop stays whole above the fold (at 1366x768 it was cut off below it during a test): its plot is at
 * most as tall as the window leaves below the test's header and readouts (at least 240 px). */
function fitLoopToWindow() {
  const box = $("plot-loop");
  const fit = () => {
    if (!box.offsetParent) return; // another view: measured when the live view shows again
    const top = box.getBoundingClientRect().top + window.scrollY;
    const room = Math.max(240, Math.floor(window.innerHeight - top - 18));
    document.documentElement.style.setProperty("--loop-room", `${room}px`);
  };
  const ro = new ResizeObserver(fit);
  for (const id of ["chrome", "live-head", "readouts", "view-live"]) ro.observe($(id));
  ro.observe($("loop-note").parentElement); // the loop's heading: its note may take a second line (a ramp-out cycle)
  window.addEventListener("resize", fit);
  fit();
}

/** The sticky block (top bar, strip, banner) has a height the panels below must leave free. */
function trackChromeHeight() {
  const chrome = $("chrome");
  const set = () => document.documentElement.style.setProperty("--chrome-h", `${Math.ceil(chrome.getBoundingClientRect().height)}px`);
  new ResizeObserver(set).observe(chrome);
  set();
}

/**
 * The rig's state as the service sees it (GET /api/rig/state, every 2 s): status, where the table is and where
 * that figure comes from, supply, vertical load, the limits in force, the last event; also when no test runs
 * and whatever another console did. A service without it (404) is not asked again.
 */
async function pollRigState() {
  const poll = async () => {
    const asked = ++state.rigStateAsked; // polls overlap (the timer, a reconnect, a run's end): the newest wins
    try {
      const answer = await api.get("/api/rig/state");
      if (asked <= state.rigStateSeq) return; // a later request has answered already
      state.rigState = answer;
      state.rigStateSeq = asked;
      changed("rigState");
    } catch (e) {
      if (e.status === 404) {
        clearInterval(timer);
        return;
      }
      /* the service is down: the strip keeps the last answer (and says NO CONNECTION) */
    }
  };
  const timer = setInterval(poll, 2000);
  let running = false;
  onState((what) => { if (what === "rigState") followRigFile(); });
  onState((what) => { // back in touch with the service (a reconnect, a restart), or a run ended: ask at once
    if (what === "conn" && state.conn) poll();
    if (what !== "status") return;
    const was = running;
    running = testRunning();
    if (was && !running) poll(); // the readouts show the rig now at once, not 2 s later
  });
  await poll();
}

async function main() {
  trackChromeHeight();
  fitLoopToWindow();
  const units = $("units");
  units.value = system();
  units.addEventListener("change", () => setSystem(units.value));
  onUnits((sys) => { units.value = sys; });
  window.addEventListener("hashchange", route);
  $("abort").addEventListener("click", abort);
  $("alert-close").addEventListener("click", hideAlert);
  $("alert-text").addEventListener("click", () => $("alert").classList.toggle("open"));
  onAccount(showAccount);
  $("account-button").addEventListener("click", async () => {
    if (account.name) await logOut();
    else await askLogin("");
  });
  showAccount();
  refreshAccount();
  labPage.load(); // the lab's default units apply to a browser that has not chosen its own

  live.createPlots();
  live.connect();
  live.startRenderLoop();
  // Reconnection timers run in a worker (not throttled in a hidden tab); focus/visibility/online retry at once.
  try {
    const ticker = new Worker("js/ticker.js");
    ticker.onmessage = () => live.tick();
  } catch {
    setInterval(() => live.tick(), 500);
  }
  document.addEventListener("visibilitychange", () => {
    live.visible = currentView === "live" && !document.hidden;
    if (!document.hidden) live.reconnectNow();
  });
  window.addEventListener("focus", () => live.reconnectNow());
  window.addEventListener("online", () => live.reconnectNow());

  route();
  strip.render();
  await setup.init();
  document.body.dataset.rigFile = (setup.rig && setup.rig.rig_file && setup.rig.rig_file.name) || "";
  rigLink.setInfo(setup.rig);
  rigLink.start();
  watchLiveVerdict();
  await commission.init(setup.rig);
  commissionReady = true;
  if (currentView === "commission") route();
  strip.render();
  pollRigState();
  await setupViewer();
  document.body.dataset.ready = "1";
}

main();
