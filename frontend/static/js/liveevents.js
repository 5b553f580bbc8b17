// The live view's events: those of the stream and of the record, each shown once in order; a stop, abort or
// limit trip marks the test as ending (the strip says STOPPING), a trip is kept in words for the banner.

import { actionName, LIMITS } from "./limits.js";
import { FINAL } from "./livebuffer.js";
import { changed, state } from "./state.js";
import { eventLine, eventWords, setStatusBadge, showAlert } from "./ui.js";

const $ = (id) => document.getElementById(id);

export class EventsPart {
  /** An event of the stream (live, no id) or of the record; shown once, in the order they happened. */
  onEvent(msg, alert = true) {
    const e = { ...msg };
    if (!e.created_at && !e.receivedAt) e.receivedAt = Date.now();
    const key = eventKey(e);
    if (this.events.some((x) => x.key === key)) return;
    this.events.push({ key, e, arrived: e.created_at ? "record" : "stream" });
    if (this.events.length > 300) this.events.shift();
    this.noteEnding(e);
    if (e.kind === "rig_fault") state.faulted = e.message || "rig fault";
    this.eq.onEvent(e);
    this.renderEvents();
    if (e.kind === "limit_indicate") this.renderMargins(false);
    if (e.kind === "limit_trip" && alert) showAlert(`LIMIT TRIP (test ${e.test_id ?? this.testId}): ${this.tripText()}`, "bad");
  }

  /**
   * An event that ends the running test early: a stop or abort asked from any console (streamed at once), a
   * limit trip (its action). The strip says STOPPING with the reason until the test ends.
   */
  noteEnding(e) {
    const v = e.values || {};
    this.noteTrip(e);
    const operator = e.kind === "operator" && (v.action === "stop" || v.action === "abort");
    if (!(operator || e.kind === "limit_trip") || this.status !== "running") return;
    state.stopping = true;
    if (e.kind === "limit_trip") {
      const l = LIMITS.find((x) => x.key === v.limit_name);
      state.stoppingReason = `limit trip${l ? ` (${l.name})` : ""}: ${actionName(v.escalation ? "valve_close" : v.action)}`;
    } else if (/requested by/.test(e.message || "")) { // the request, from this or another console
      state.stoppingReason = e.message;
    } else if (!state.stoppingReason) { // the worker's own note of the ramp-out or abort
      state.stoppingReason = v.action === "stop" ? "ramping out" : "aborting";
    }
    setStatusBadge("stopping");
    changed("stopping");
  }

  /** A limit trip, kept in words with the action taken for the banner (each once). */
  noteTrip(e) {
    if (e.kind !== "limit_trip") return;
    const key = eventKey(e);
    if (this.trips.some((t) => t.key === key)) return;
    const words = eventWords(e).text.replace(/^LIMIT TRIP( during the controlled stop)?: /, "");
    this.trips.push({ key, words: e.values && e.values.escalation ? `then, during the controlled stop: ${words}` : words });
  }

  /** The limit trips of this test in words, with the action taken ("" when none tripped). */
  tripText() {
    return this.trips.map((t) => t.words).join("; ");
  }

  /**
   * The record's events (ordered by the service): they replace what the stream gave, the rest follows. An event
   * keeps how this page first learned of it (live from the stream, or from the record).
   */
  mergeEvents(list) {
    const arrived = new Map(this.events.map((x) => [x.key, x.arrived]));
    const fromRecord = (list || []).map((e) => {
      const key = eventKey(e);
      return { key, e, arrived: arrived.get(key) || "record" };
    });
    const keys = new Set(fromRecord.map((x) => x.key));
    const live = this.events.filter((x) => !keys.has(x.key));
    this.events = [...fromRecord, ...live].slice(-300);
    for (const { e } of fromRecord) {
      this.noteEnding(e);
      this.eq.onEvent(e);
    }
    this.renderEvents();
    this.renderMargins(false);
  }

  renderEvents() {
    const list = $("live-events");
    const atEnd = list.scrollTop + list.clientHeight >= list.scrollHeight - 4;
    list.innerHTML = "";
    for (const { e, arrived } of this.events) {
      const li = document.createElement("li");
      li.className = e.kind || "";
      li.dataset.source = arrived; // "stream": this page learned of it live, before the record had it
      li.textContent = eventLine(e);
      list.append(li);
    }
    if (!this.events.length) list.append(Object.assign(document.createElement("li"), { className: "muted", textContent: "no events yet" }));
    if (atEnd || this.events.length < 8) list.scrollTop = list.scrollHeight;
    const last = this.events.length ? this.events[this.events.length - 1].e : null;
    const lastText = last ? eventLine(last) : "";
    if (!state.lastEvent || state.lastEvent.text !== lastText) {
      state.lastEvent = last ? { text: lastText, kind: last.kind } : null;
      changed("event");
    }
  }

  /** Fetch the test's record: its events (those of before this page joined) and its figures (the summary). */
  refreshEvents(testId) {
    return fetch(`/api/tests/${testId}`).then((r) => (r.ok ? r.json() : null)).then((rec) => {
      if (!rec || this.testId !== testId) return;
      this.test = { ...this.test, ...rec };
      state.test = this.test;
      this.eq.onRecord(rec);
      this.mergeEvents(rec.events);
      this.renderHead();
      if (FINAL.has(this.status)) this.showEndedLoops(testId); // the last steady loop bold, not the ramp-out
      changed("test");
    }).catch(() => {});
  }
}

export function eventKey(e) {
  const t = typeof e.time_s === "number" ? e.time_s.toFixed(3) : "";
  return `${e.kind}|${e.message}|${t}`;
}
