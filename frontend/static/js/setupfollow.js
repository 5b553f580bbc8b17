// What the form holds: this operator's draft (kept in the browser, restored after a reload), and while a test
// runs, that test's set-up (locked), also after a reload or in a second browser.

import { account } from "./api.js";
import { actionOf, FOLLOW, followAction, LIMITS } from "./limits.js";
import { BAR } from "./setupfields.js";
import { isCommissioning, isMove } from "./state.js";
import { el } from "./ui.js";
import { fmt } from "./units.js";

const $ = (id) => document.getElementById(id);
const num = (v) => typeof v === "number" && Number.isFinite(v);

const DRAFT_KEY = "isorig.setup_draft";

export class FollowPart {
  /** A test runs: show its set-up (locked) so this page says what the rig does, also after a reload. */
  followTest(t) {
    if (this.locked && this.lockedTestId === t.id) return;
    this.locked = true;
    this.lockedTestId = t.id;
    $("f-specimen_id").value = t.specimen_id || "";
    $("f-operator_name").dataset.following = "1";
    $("f-operator_name").value = t.operator_name || "";
    $("f-notes").value = t.notes || "";
    $("f-label").value = t.label || "";
    if (t.isolator && this.isolators.some((i) => i.name === t.isolator)) $("f-isolator").value = t.isolator;
    if (num(t.supply_bar)) this.setField("supply", t.supply_bar * BAR);
    if (num(t.vertical_load_n)) $("f-vertical_load").value = fmt("force", t.vertical_load_n); // the console's digits
    if (num(t.speed)) this.setField("speed", t.speed);
    const p = t.profile || {};
    if (p.kind === "protocol" && p.name) {
      if (![...$("f-profile").options].some((o) => o.value === `protocol:${p.name}`)) {
        $("f-profile").append(el("option", { value: `protocol:${p.name}`, text: `protocol ${p.name}` }));
      }
      $("f-profile").value = `protocol:${p.name}`;
      this.setField("design_displacement", num(p.design_displacement_m) ? p.design_displacement_m : null);
      this.setField("design_frequency", num(p.frequency_hz) ? p.frequency_hz : null);
    } else if (p.kind === "history" || p.kind === "hybrid") {
      this.eq.follow(p);
    } else if (p.kind === "sine") {
      $("f-profile").value = "sine";
      this.setField("amplitude", p.amplitude_m);
      this.setField("frequency", p.frequency_hz);
      this.setField("cycles", p.cycles);
      this.setField("taper_cycles", p.taper_cycles);
      this.setField("offset", num(p.offset_m) && p.offset_m !== 0 ? p.offset_m : null);
      this.offsetTakenM = num(p.start_m) && p.start_m !== 0 && p.start_m === p.offset_m ? p.start_m : null;
      this.renderOffsetNote(`where test #${t.id} started`);
    }
    if (t.controller && [...$("f-controller").options].some((o) => o.value === t.controller)) {
      $("f-controller").value = t.controller;
      this.showControllerOptions();
      const opts = (t.scenario && t.scenario.controller_options) || {};
      for (const [k, v] of Object.entries(opts)) {
        const input = document.querySelector(`#controller-options-fields [data-option="${k}"]`);
        if (input) input.value = typeof v === "boolean" ? String(v) : String(v);
      }
    }
    const lim = t.limits || {};
    const def = (this.rig && this.rig.limits_default) || {};
    for (const [key, spec] of Object.entries(this.fields)) {
      if (!spec.limit) continue;
      const v = lim[spec.limit];
      this.setField(key, num(v) && v !== def[spec.limit] ? v : null);
    }
    for (const l of LIMITS) this.actionSelect(l.key).value = actionOf(lim, l.key);
    this.actionSelect(FOLLOW.key).value = followAction(lim);
    this.showActionHelp();
    this.showIsolator();
    this.showProfile();
    this.readAll();
    $("setup-fields").disabled = true;
    $("iso-delete").disabled = true;
    const lock = $("form-lock");
    lock.textContent = isMove(t)
      ? `Manual move #${t.id} is running: the form is locked until it ends.`
      : isCommissioning(t) ? `Commissioning #${t.id} is running (see the Commissioning page): the form is locked until it ends.`
        : `The form shows test #${t.id}, which is running: locked until it ends.`;
    lock.classList.remove("hidden");
    this.scheduleCheck(0);
  }

  unlock() {
    const mine = this.lockedTestId !== null && this.lockedTestId === this.startedId;
    this.locked = false;
    this.lockedTestId = null;
    $("setup-fields").disabled = false;
    delete $("f-operator_name").dataset.following; // back to the logged-in account
    $("f-operator_name").value = account.name || "";
    // a test started elsewhere (another console, a script) does not replace this operator's set-up
    if (!mine) {
      this.restoreDraft();
      this.readAll();
    }
    $("form-lock").classList.add("hidden");
    this.showIsolator();
    this.saveDraft();
    this.scheduleCheck(0);
  }

  saveDraft() {
    if (this.locked) return;
    const draft = { values: {}, isolator: $("f-isolator").value, profile: $("f-profile").value,
      controller: $("f-controller").value, specimen_id: $("f-specimen_id").value,
      notes: $("f-notes").value, label: $("f-label").value, actions: this.actions(),
      eq: { source: $("f-eq_source").value, preset: $("f-eq_preset").value, unit: $("f-eq_acc_unit").value,
        storeys: this.eq.storeys } }; // a record file is not kept: it is chosen again after a reload
    for (const [key, v] of Object.entries(this.values)) if (num(v) || v === null) draft.values[key] = v;
    try { localStorage.setItem(DRAFT_KEY, JSON.stringify(draft)); } catch { /* not kept */ }
  }

  restoreDraft() {
    let draft = null;
    try { draft = JSON.parse(localStorage.getItem(DRAFT_KEY) || "null"); } catch { draft = null; }
    if (!draft) return;
    if (draft.isolator && this.isolators.some((i) => i.name === draft.isolator)) $("f-isolator").value = draft.isolator;
    if (draft.profile && [...$("f-profile").options].some((o) => o.value === draft.profile)) $("f-profile").value = draft.profile;
    if (draft.controller && [...$("f-controller").options].some((o) => o.value === draft.controller)) {
      $("f-controller").value = draft.controller;
      this.showControllerOptions();
    }
    for (const k of ["specimen_id", "notes", "label"]) if (typeof draft[k] === "string") $(`f-${k}`).value = draft[k];
    const eq = draft.eq || {};
    for (const [id, v] of [["f-eq_source", eq.source], ["f-eq_preset", eq.preset], ["f-eq_acc_unit", eq.unit]]) {
      if (v && [...$(id).options].some((o) => o.value === v)) $(id).value = v;
    }
    if (Number.isInteger(eq.storeys) && eq.storeys > 0) this.eq.setStoreys(eq.storeys);
    for (const [key, v] of Object.entries(draft.values || {})) {
      if (this.fields[key] && !(key === "speed" && this.realTimeOnly)) this.setField(key, v);
    }
    for (const key of [...LIMITS.map((l) => l.key), FOLLOW.key]) {
      const a = draft.actions && draft.actions[key];
      const sel = this.actionSelect(key);
      if (a && [...sel.options].some((o) => o.value === a)) sel.value = a;
    }
    this.showActionHelp();
    this.showIsolator();
  }
}
