// The live view's connection: the websocket /ws/live, reconnected with a growing back-off (at most 2 s), and
// the connection shown in the strip.

import { metrics } from "./livemetrics.js";
import { changed, state } from "./state.js";

const $ = (id) => document.getElementById(id);

export class ConnectionPart {
  connect() {
    if (this.ws && (this.ws.readyState === WebSocket.OPEN || this.ws.readyState === WebSocket.CONNECTING)) return;
    const url = `${location.protocol === "https:" ? "wss" : "ws"}://${location.host}/ws/live`;
    let ws;
    try {
      ws = new WebSocket(url);
    } catch {
      this.scheduleRetry();
      return;
    }
    this.ws = ws;
    ws.onopen = () => {
      metrics.connects++;
      if (metrics.wsOpenMs === null) metrics.wsOpenMs = performance.now();
      this.backoffMs = 250;
      setConn(true);
    };
    ws.onmessage = (ev) => {
      let msg;
      try { msg = JSON.parse(ev.data); } catch { return; }
      this.handle(msg);
    };
    ws.onclose = () => {
      setConn(false);
      this.ws = null;
      this.scheduleRetry();
    };
    ws.onerror = () => { /* onclose follows */ };
  }

  scheduleRetry() {
    this.retryAt = Date.now() + this.backoffMs;
    this.backoffMs = Math.min(2000, this.backoffMs * 2);
  }

  /** Called by the worker tick (and on focus/visibility/online): reconnect when due. */
  tick() {
    if (!this.wsWanted) return;
    if (!this.ws && Date.now() >= this.retryAt) this.connect();
  }

  reconnectNow() {
    this.retryAt = 0;
    this.tick();
  }
}

function setConn(up) {
  const el = $("conn");
  el.className = `conn ${up ? "conn-up" : "conn-down"}`;
  el.textContent = up ? "live" : "CONNECTION LOST - reconnecting";
  // the rig status shown is the last one known: mark it as such while the stream is down
  const badge = $("rig-status");
  badge.classList.toggle("stale", !up);
  badge.title = up ? "what the rig does now" : "last known status: no connection to the service";
  state.conn = up;
  if (up) state.everConnected = true;
  else state.helloSeen = false;
  changed("conn");
}
