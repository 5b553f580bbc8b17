// Dashboard entry point: views (live, history, one test), the always-visible Abort, the token, the 3D view.

import { api, askToken, getToken, operatorPost } from "./api.js";
import { History } from "./history.js";
import { LiveView } from "./live.js";
import { runningTestId, SetupPanel } from "./setup.js";
import { hideAlert, showAlert } from "./ui.js";

const $ = (id) => document.getElementById(id);
// The embedded 3D view shares the page's main thread (same origin); capping its frame rate keeps the plots
// fluid when WebGL is slow (software rendering). /viewer/ opened on its own runs at full rate.
const VIEWER_MAX_FPS = 15;

const live = new LiveView({
  onTest: (id, status) => {
    if (currentView === "history") historyView.showList();
    if (status === "completed" || status === "stopped" || status === "aborted") setup.message("", "");
  },
});
const setup = new SetupPanel({ live });
const historyView = new History();
let currentView = "";

function route() {
  const hash = location.hash || "#/live";
  const m = hash.match(/^#\/tests\/(\d+)/);
  const view = m ? "test" : hash.startsWith("#/history") ? "history" : "live";
  currentView = view;
  for (const v of ["live", "history", "test"]) $(`view-${v}`).classList.toggle("hidden", v !== view);
  document.querySelectorAll("nav a").forEach((a) => {
    a.classList.toggle("active", a.dataset.view === (view === "test" ? "history" : view));
  });
  live.visible = view === "live" && !document.hidden;
  live.dirty = true;
  if (view === "history") historyView.showList();
  if (view === "test") historyView.showTest(Number(m[1]));
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
    await operatorPost(`/api/tests/${id}/abort`);
    showAlert(`Test #${id} ABORTED by the operator.`, "bad");
  } catch (e) {
    showAlert(`Abort failed: ${e.message}`, "bad");
  } finally {
    button.disabled = false;
  }
}

const VIEWER_KEY = "isorig.viewer"; // "off" hides the 3D view in this browser

/** The 3D view is shown unless the service has it off, this browser hid it, or the URL says ?viewer=off. */
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
  const urlOff = new URLSearchParams(location.search).get("viewer") === "off";
  const show = (on) => {
    box.innerHTML = "";
    box.classList.toggle("off", !on);
    toggle.textContent = on ? "hide 3D view" : "show 3D view";
    if (!on) {
      box.innerHTML = "<p class=\"muted\">3D view hidden in this browser.</p>";
      return;
    }
    const frame = document.createElement("iframe");
    frame.src = "/viewer/";
    frame.title = "3D rig view";
    frame.loading = "lazy";
    frame.addEventListener("load", () => capFrameRate(frame.contentWindow, VIEWER_MAX_FPS));
    box.append(frame);
  };
  let on = !urlOff && localStorage.getItem(VIEWER_KEY) !== "off";
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

function updateTokenButton() {
  $("token-button").textContent = getToken() ? "token set" : "set token";
}

async function main() {
  window.addEventListener("hashchange", route);
  $("abort").addEventListener("click", abort);
  $("alert-close").addEventListener("click", hideAlert);
  $("token-button").addEventListener("click", async () => {
    await askToken("");
    updateTokenButton();
  });
  updateTokenButton();
  window.addEventListener("storage", updateTokenButton);

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
  await setup.init();
  setupViewer();
  document.body.dataset.ready = "1";
}

main();
