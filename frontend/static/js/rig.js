// Which rig the service drives and, for a real rig on UDP, the health of its link, in the top bar.
// The rig and its link settings come from GET /api/rig (`rig`); the link figures from the `link` of the
// websocket status messages while a test runs (every ~0.25 s), else from GET /api/rig/link every 2 s (one HELLO
// to the rig: connected or not, round trip).

import { api } from "./api.js";
import { el } from "./ui.js";

const POLL_MS = 2000;
const WS_FRESH_MS = 1500; // a status message's link younger than this: no need to ask the API
const RUNNING = new Set(["running", "stopping"]);

const $ = (id) => document.getElementById(id);
const num = (v) => typeof v === "number" && isFinite(v);

/** A latency in ms: 2 decimals below 10 ms, 1 below 100 ms, none above. */
export function fmtMs(v) {
  if (!num(v)) return "-";
  return `${v.toFixed(v < 10 ? 2 : v < 100 ? 1 : 0)} ms`;
}

/** A count as an integer. */
export function fmtCount(v) {
  return num(v) ? String(Math.round(v)) : "-";
}

/** A duration given in s: "1 ms", "50 ms", "2 s". */
export function fmtPeriod(s) {
  if (!num(s)) return "-";
  if (s < 1) return `${+(s * 1000).toPrecision(3)} ms`;
  return `${+s.toPrecision(3)} s`;
}

/** The kind of rig from a GET /api/rig answer (also from a service that predates its `rig` field). */
export function rigKind(rigAnswer) {
  const r = rigAnswer || {};
  if (r.rig && r.rig.kind) return r.rig.kind;
  if (r.driver === undefined || /sim/i.test(String(r.driver))) return "simulated";
  return /^udp:/i.test(String(r.driver)) ? "udp" : "other";
}

export class RigLink {
  constructor({ onChange } = {}) {
    this.onChange = onChange || (() => {});
    this.info = null; // GET /api/rig's `rig`
    this.kind = "unknown";
    this.link = null; // the latest link figures
    this.source = ""; // "test" (status messages) or "probe" (GET /api/rig/link)
    this.linkAt = 0; // performance.now() of the latest link figures
    this.wsAt = -Infinity; // ... of the latest figures from a status message of a running test
    this.lastRun = null; // the latest figures of a test, kept once it ends
    this.error = ""; // GET /api/rig/link failed (service down)
    this.polling = false;
    this.timer = null;
    this.open = false;
  }

  /** The answer of GET /api/rig (SetupPanel loads it). */
  setInfo(rigAnswer) {
    const r = rigAnswer || {};
    this.kind = rigKind(r);
    this.info = r.rig || (r.driver ? { kind: this.kind, name: r.driver, url: r.driver } : null);
    if (r.link && !(this.linkAt && this.source === "test")) this.setLink(r.link, "probe");
    this.render();
  }

  start() {
    const button = $("rig-link");
    button.addEventListener("click", (ev) => {
      ev.stopPropagation();
      this.toggle(!this.open);
    });
    document.addEventListener("click", (ev) => {
      if (this.open && !ev.target.closest("#rig-wrap")) this.toggle(false);
    });
    document.addEventListener("keydown", (ev) => {
      if (ev.key === "Escape" && this.open) this.toggle(false);
    });
    this.timer = setInterval(() => this.poll(), POLL_MS);
  }

  toggle(open) {
    this.open = open;
    $("rig-details").classList.toggle("hidden", !open);
    $("rig-link").setAttribute("aria-expanded", String(open));
    if (open) this.renderDetails();
  }

  /** A websocket status message: its `link` (a real rig's figures, while a test runs). */
  fromStatus(msg) {
    if (!msg || !msg.link || typeof msg.link !== "object") return;
    const link = { kind: "udp", connected: true, test_id: msg.test_id, ...msg.link };
    if (RUNNING.has(msg.status)) {
      link.armed = true;
      this.wsAt = performance.now();
      this.setLink(link, "test");
    } else {
      // a test's last figures (it ended, or a replay after a reconnect): kept, the probe says what is now
      this.lastRun = { ...link, status: msg.status };
      this.wsAt = -Infinity;
      this.render();
      this.poll();
    }
  }

  setLink(link, source) {
    this.link = link;
    this.source = source;
    this.linkAt = performance.now();
    this.error = "";
    if (source === "test" || link.test_id !== undefined) this.lastRun = { ...link };
    else if (link.last_test && !this.lastRun) this.lastRun = { ...link.last_test }; // a page opened after the test
    if (this.kind === "unknown" && link.kind) this.kind = link.kind;
    this.render();
  }

  /** GET /api/rig/link, unless the status messages bring fresh figures (a UDP rig only). */
  async poll() {
    if (this.kind !== "udp") return;
    if (this.polling) { // one at a time; the one in flight may have been asked before what changed: ask again after
      this.pollAgain = true;
      return;
    }
    if (performance.now() - this.wsAt < WS_FRESH_MS) return;
    this.polling = true;
    try {
      const link = await api.get("/api/rig/link");
      if (performance.now() - this.wsAt >= WS_FRESH_MS) {
        this.setLink(link, link.test_id !== undefined && link.test_id !== null ? "test" : "probe");
      }
    } catch (e) {
      this.error = e.message || "no answer";
      this.render();
    } finally {
      this.polling = false;
      if (this.pollAgain) {
        this.pollAgain = false;
        this.poll();
      }
    }
  }

  /** "true", "false" or "unknown" (the service does not answer, or nothing heard yet). */
  connected() {
    if (this.kind === "simulated") return "true";
    if (this.error || !this.link) return "unknown";
    return this.link.connected ? "true" : "false";
  }

  name() {
    if (this.kind === "simulated") return "simulated rig";
    const i = this.info || {};
    return i.url || i.name || (this.link && this.link.rig) || "rig";
  }

  /** The one-line figures under the rig's name. */
  figures() {
    const l = this.link || {};
    if (this.kind === "simulated") {
      const plant = this.plantChanges();
      return plant ? [["plant", `plays a rig unlike its rig file (${plant})`]] : [["model", "rig model in the service, no link"]];
    }
    if (this.error) return [["error", `link unknown: the service does not answer (${this.error})`]];
    if (!this.link) return [["wait", "asking the rig..."]];
    if (!l.connected) return [["detail", l.detail || "no answer from the rig"]];
    if (this.source === "test") {
      return [
        ["rtt", `round trip p50 ${fmtMs(l.round_trip_p50_ms)}, p99 ${fmtMs(l.round_trip_p99_ms)}`],
        ["lost", `lost ${fmtCount(l.lost)}`],
        ["rejected", `rejected ${fmtCount(l.rejected)}`],
        ["missed", `rig missed ${fmtCount(l.rig_commands_missed)}`],
        ["seq", `seq ${fmtCount(l.last_sequence)}`],
      ];
    }
    const out = [["rtt", `round trip ${fmtMs(l.round_trip_ms)}`], ["armed", l.armed ? "ARMED" : "idle"]];
    const r = this.lastRun;
    if (r && num(r.test_id)) {
      out.push(["last", `test #${r.test_id}: lost ${fmtCount(r.lost)}, rejected ${fmtCount(r.rejected)}, ` +
        `missed ${fmtCount(r.rig_commands_missed)}, seq ${fmtCount(r.last_sequence)}`]);
    }
    return out;
  }

  /** The simulated plant's changes (isorig serve --plant-set) in a few words, or "". */
  plantChanges() {
    const p = (this.info && this.info.plant_changes) || {};
    return Object.entries(p).map(([k, v]) => `${k}=${+Number(v).toPrecision(4)}`).join(", ");
  }

  tooltip() {
    const i = this.info || {};
    if (this.kind === "simulated") {
      const plant = this.plantChanges();
      return `simulated rig: the rig model runs in the service (no link)${plant ? `; for demos and tests it plays a rig ` +
        `unlike its rig file: ${plant} (isorig serve --plant-set)` : ""}. Click for details.`;
    }
    const parts = [`${this.name()}`];
    if (i.host !== undefined) parts.push(`host ${i.host}, port ${i.port}`);
    if (num(i.control_period_s)) parts.push(`control period ${fmtPeriod(i.control_period_s)}`);
    if (num(i.link_timeout_s)) parts.push(`link timeout ${fmtPeriod(i.link_timeout_s)}`);
    if (num(i.arm_timeout_s)) parts.push(`arm timeout ${fmtPeriod(i.arm_timeout_s)}`);
    if (i.protocol) parts.push(i.protocol);
    return `${parts.join("\n")}\nClick for the link details.`;
  }

  render() {
    const button = $("rig-link");
    if (!button) return;
    const connected = this.connected();
    button.dataset.kind = this.kind;
    button.dataset.connected = connected;
    button.dataset.source = this.source;
    const l = this.link || {};
    // figures as data attributes too (tests, scripts)
    const set = (key, v) => {
      if (num(v)) button.dataset[key] = String(v);
      else delete button.dataset[key];
    };
    set("lastSequence", this.source === "test" ? l.last_sequence : undefined);
    set("roundTripMs", this.source === "test" ? l.round_trip_p50_ms : l.round_trip_ms);
    $("rig-name").textContent = this.name();
    const state = $("rig-state");
    if (this.kind === "simulated") state.textContent = "";
    else state.textContent = connected === "true" ? "connected" : connected === "false" ? "NOT CONNECTED" : "link unknown";
    const figs = $("rig-figs");
    figs.innerHTML = "";
    this.figures().forEach(([key, text, title], k) => {
      if (k) figs.append(el("span", { class: "sep", text: " \u00b7 " }));
      figs.append(el("span", { class: `fig fig-${key}`, "data-key": key, text, ...(title ? { title } : {}) }));
    });
    button.title = this.tooltip();
    if (this.open) this.renderDetails();
    this.onChange(this);
  }

  renderDetails() {
    const box = $("rig-details");
    const i = this.info || {};
    const l = this.link || {};
    box.innerHTML = "";
    const table = el("table", { class: "params" });
    const row = (k, v) => table.append(el("tr", {}, el("td", { text: k }), el("td", { text: v })));
    const head = (text) => table.append(el("tr", {}, el("th", { colspan: "2", text })));
    head("Rig");
    row("rig", this.name());
    if (this.kind === "simulated") {
      row("kind", "simulated: the rig model runs in the service's worker");
      if (i.detail) row("note", i.detail);
      if (this.plantChanges()) row("plant unlike its rig file", this.plantChanges());
      row("link", "none (always connected)");
      box.append(table);
      return;
    }
    row("kind", this.kind === "udp" ? "real-time rig over UDP" : this.kind);
    if (i.host !== undefined) row("host", String(i.host));
    if (i.port !== undefined) row("port", String(i.port));
    row("control period", fmtPeriod(i.control_period_s));
    row("link timeout", fmtPeriod(i.link_timeout_s));
    row("arm timeout", fmtPeriod(i.arm_timeout_s));
    if (i.protocol) row("protocol", i.protocol);
    if (i.authenticated === false) row("authentication", "link not authenticated");
    head(this.source === "test" ? `Link: test #${l.test_id} running` : "Link: probe (GET /api/rig/link)");
    row("connected", this.error ? `unknown (${this.error})` : l.connected ? "yes" : "NO");
    if (l.detail) row("detail", l.detail);
    if (this.source === "test") {
      row("round trip p50 / p99", `${fmtMs(l.round_trip_p50_ms)} / ${fmtMs(l.round_trip_p99_ms)}`);
      if (num(l.round_trip_max_ms)) row("round trip max", fmtMs(l.round_trip_max_ms));
      if (num(l.answer_p99_ms)) row("rig answer p99", fmtMs(l.answer_p99_ms));
      row("measurements received", fmtCount(l.received));
      row("measurements lost", fmtCount(l.lost));
      row("packets rejected", fmtCount(l.rejected));
      row("rig missed commands", fmtCount(l.rig_commands_missed));
      if (num(l.rig_packets_rejected)) row("rig rejected packets", fmtCount(l.rig_packets_rejected));
      row("last sequence", fmtCount(l.last_sequence));
      if (num(l.host_stall_max_ms)) row("longest host stall", fmtMs(l.host_stall_max_ms));
      if (l.authenticated === false) row("authentication", "link not authenticated");
    } else if (l.connected) {
      row("round trip", fmtMs(l.round_trip_ms));
      row("armed", l.armed ? "yes" : "no");
      if (l.status) row("rig status", String(l.status));
      if (num(l.period_s)) row("rig's period", fmtPeriod(l.period_s));
      if (num(l.protocol_version)) row("rig's protocol version", fmtCount(l.protocol_version));
      if (l.authenticated === false) row("authentication", "link not authenticated");
      const r = this.lastRun;
      if (r && num(r.test_id)) {
        head(`Last test #${r.test_id}${r.status ? ` (${r.status})` : ""}`);
        row("round trip p50 / p99", `${fmtMs(r.round_trip_p50_ms)} / ${fmtMs(r.round_trip_p99_ms)}`);
        row("lost / rejected / rig missed", `${fmtCount(r.lost)} / ${fmtCount(r.rejected)} / ` +
          `${fmtCount(r.rig_commands_missed)}`);
        row("last sequence", fmtCount(r.last_sequence));
      }
    }
    box.append(table);
    box.append(el("p", { class: "muted", text: this.source === "test"
      ? "Figures of the running test, from its status messages (every 0.25 s)."
      : "One HELLO to the rig every 2 s while no test runs." }));
  }
}
