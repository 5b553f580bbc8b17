// The set-up's limits: each limit's action (js/limits.js), the limits the next test gets, and the table of the
// limits in force with what each action does (the confirmation and a manual move show it).

import {
  ACTION_ORDER, actionHelp, actionName, actionOf, DEFAULT_ACTION, FOLLOW, followAction, followHelp, followThresholdsText,
  LIMITS, setActionHelp,
} from "./limits.js";
import { el } from "./ui.js";
import { fmtU } from "./units.js";

const $ = (id) => document.getElementById(id);
const num = (v) => typeof v === "number" && Number.isFinite(v);

export class LimitsPart {
  /** The action choices of every limit (GET /api/rig limit_actions; the default marked). */
  renderActions() {
    const rig = this.rig || {};
    setActionHelp(rig.limit_actions);
    const actions = rig.limit_actions ? ACTION_ORDER.filter((a) => a in rig.limit_actions) : ACTION_ORDER;
    const defaults = (rig.limits_default && rig.limits_default.actions) || {};
    for (const l of LIMITS) {
      const sel = this.actionSelect(l.key);
      const keep = sel.value;
      const def = defaults[l.key] || DEFAULT_ACTION;
      sel.innerHTML = "";
      for (const a of actions) sel.append(el("option", { value: a, text: actionName(a) }));
      sel.value = actions.includes(keep) ? keep : def;
      sel.dataset.default = def;
      sel.title = `default: ${actionName(def)}\n${actions.map((a) => `${actionName(a)}: ${actionHelp(a)}`).join("\n")}`;
    }
    // the follow detector: its own actions (controlled stop by default, or indicate) and its thresholds
    const follow = this.actionSelect(FOLLOW.key);
    const keepFollow = follow.value;
    follow.innerHTML = "";
    for (const a of FOLLOW.actions) follow.append(el("option", { value: a, text: actionName(a) }));
    follow.value = FOLLOW.actions.includes(keepFollow) ? keepFollow : FOLLOW.default;
    follow.dataset.default = FOLLOW.default;
    follow.title = `default: ${actionName(FOLLOW.default)}\n${FOLLOW.actions.map((a) => `${actionName(a)}: ${followHelp(a)}`).join("\n")}`;
    const thresholds = followThresholdsText(rig.limits_default);
    $("follow-thresholds").textContent = thresholds;
    $("follow-thresholds").title = thresholds;
    // what each action does, in the service's words, once under the limits
    const help = $("limit-actions-help");
    help.innerHTML = "";
    for (const a of actions) {
      const def = a === DEFAULT_ACTION ? " (the default)" : "";
      help.append(el("div", { "data-action": a }, el("b", { text: `${actionName(a)}${def}` }), ` ${actionHelp(a)}`));
    }
    help.append(el("div", { "data-action": "follow" }, el("b", { text: `${FOLLOW.name}:` }),
      ` ${FOLLOW.actions.map((a) => `${actionName(a)}${a === FOLLOW.default ? " (the default)" : ""}: ${followHelp(a)}`).join("; ")}`));
  }

  actionSelect(key) {
    return document.querySelector(`select[data-limit="${key}"]`);
  }

  /** Each limit's action: {key: action} (SI keys of the service). */
  actions() {
    return { ...Object.fromEntries(LIMITS.map((l) => [l.key, this.actionSelect(l.key).value || DEFAULT_ACTION])),
      [FOLLOW.key]: this.actionSelect(FOLLOW.key).value || FOLLOW.default };
  }

  /** Each limit row says its action (an action other than the default is marked). */
  showActionHelp() {
    for (const key of [...LIMITS.map((l) => l.key), FOLLOW.key]) {
      const sel = this.actionSelect(key);
      const row = sel.closest(".limit-row");
      row.dataset.action = sel.value;
      row.dataset.changed = sel.value !== (sel.dataset.default || DEFAULT_ACTION) ? "1" : "0";
    }
  }

  /** The limits the next test would get, with their actions: the form's, else the rig's defaults (SI). */
  nextLimits() {
    const def = (this.rig && this.rig.limits_default) || {};
    const out = { ...def };
    for (const [key, spec] of Object.entries(this.fields)) {
      if (spec.limit && num(this.values[key])) out[spec.limit] = this.values[key];
    }
    out.actions = this.actions();
    return out;
  }

  /** A table of the limits (the rig's defaults where `limits` names none), each with its action, explained. */
  /** The limits in force and what each action does; `what`: "test" or "move" (the record that ends aborted). */
  limitsBox(limits, what = "test") {
    const box = el("div", { class: "limits-box" });
    const lim = { ...((this.rig && this.rig.limits_default) || {}), ...(limits || {}) };
    const table = el("table", { class: "params summary-table limits-table" });
    table.append(el("tr", {}, el("th", { text: "limit" }), el("th", { text: "value" }), el("th", { text: "when exceeded" })));
    const used = new Set();
    for (const l of LIMITS) {
      if (!num(lim[l.key])) continue;
      const a = actionOf(lim, l.key);
      used.add(a);
      table.append(el("tr", { "data-limit": l.key, "data-action": a },
        el("td", { text: `${l.name} ${l.short}` }), el("td", {}, el("b", { text: fmtU(l.quantity, lim[l.key], { sig: 4 }) })),
        el("td", {}, el("b", { text: actionName(a) }))));
    }
    if (what === "test") { // a move follows no test target: the follow detector is a test's
      const fa = followAction(lim);
      table.append(el("tr", { "data-limit": FOLLOW.key, "data-action": fa },
        el("td", { text: FOLLOW.name }), el("td", { class: "follow-thresholds", text: followThresholdsText(lim) }),
        el("td", {}, el("b", { text: actionName(fa) }))));
    }
    box.append(table);
    box.append(el("p", { class: "actions-help" }, ...ACTION_ORDER.filter((a) => used.has(a))
      .map((a) => el("span", {}, el("b", { text: actionName(a) }), `: ${actionHelp(a).replace("the test ends", `the ${what} ends`)}. `)),
    ...(what === "test" ? [el("span", {}, el("b", { text: `${FOLLOW.name}, ${actionName(followAction(lim))}` }),
      `: ${followHelp(followAction(lim))}.`)] : [])));
    return box;
  }
}
