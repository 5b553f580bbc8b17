// The set-up's isolator: the list (GET /api/isolators), the chosen one's parameters, and a user isolator added
// (its values checked against what isolators usually are) or deleted.

import { api, operatorPost } from "./api.js";
import { confirmDialog } from "./dialogs.js";
import { parseNumber } from "./parse.js";
import { implausible, ISO_PARAMS, listOf } from "./setupfields.js";
import { el, showAlert } from "./ui.js";
import { fmt, fmtU, toSI, unit } from "./units.js";

const $ = (id) => document.getElementById(id);
const num = (v) => typeof v === "number" && Number.isFinite(v);

export class IsolatorsPart {
  async loadIsolators(select) {
    let data = [];
    try {
      data = listOf(await api.get("/api/isolators"), "isolators");
    } catch (e) {
      showAlert(`Could not load isolators: ${e.message}`, "warn");
    }
    this.isolators = data;
    const sel = $("f-isolator");
    const keep = select || sel.value || "IUT_b";
    sel.innerHTML = "";
    const groups = { preset: el("optgroup", { label: "presets" }), user: el("optgroup", { label: "user-defined" }) };
    for (const iso of data) {
      groups[iso.source === "user" ? "user" : "preset"].append(el("option", { value: iso.name, text: iso.name }));
    }
    sel.append(groups.preset);
    if (groups.user.children.length) sel.append(groups.user);
    if (data.some((i) => i.name === keep)) sel.value = keep;
    this.showIsolator();
    const hsel = $("h-isolator");
    const hkeep = hsel.value;
    hsel.innerHTML = "";
    hsel.append(el("option", { value: "", text: "any" }));
    for (const iso of data) hsel.append(el("option", { value: iso.name, text: iso.name }));
    hsel.value = hkeep;
  }

  selectedIsolator() {
    return this.isolators.find((i) => i.name === $("f-isolator").value) || null;
  }

  showIsolator() {
    const iso = this.selectedIsolator();
    const table = $("isolator-params");
    table.innerHTML = "";
    const del = $("iso-delete");
    const user = Boolean(iso && iso.source === "user");
    del.disabled = !user || this.locked;
    del.title = user ? `delete the user isolator ${iso.name}` : "presets cannot be deleted";
    if (!iso) return;
    for (const [key, label, quantity] of ISO_PARAMS) {
      table.append(el("tr", {}, el("td", { text: `${label} (${unit(quantity)})` }),
        el("td", { text: fmt(quantity, iso[key], { sig: 4 }) })));
    }
    if (num(iso.design_vertical_load_n)) {
      table.append(el("tr", {}, el("td", { text: `design load (${unit("force")})` }),
        el("td", { text: fmt("force", iso.design_vertical_load_n) })));
    }
    if (iso.description) table.append(el("tr", {}, el("td", { text: "note" }), el("td", { text: iso.description })));
    table.append(el("tr", {}, el("td", { text: "source" }), el("td", { text: iso.source === "user" ? "user-defined" : "preset" })));
    this.renderFieldMeta();
  }

  readIsoField(input) {
    const entry = ISO_PARAMS.find(([key]) => `iso-${key}` === input.id);
    if (!entry) return null;
    const [key, , quantity] = entry;
    const r = parseNumber(input.value);
    const msg = input.closest(".field").querySelector(".msg");
    let si = null;
    let text = "";
    let cls = "msg";
    if (!r.empty && !r.ok) {
      text = r.error;
      cls += " bad";
      si = undefined;
    } else if (r.ok) {
      si = toSI(quantity, r.value);
      const warn = implausible(key, si);
      if (warn) {
        text = warn;
        cls += " warn";
      } else if (r.comma) {
        text = `read as ${fmtU(quantity, si, { sig: 8 })}`;
        cls += " info";
      }
    }
    if (num(si)) input.dataset.si = String(si);
    else delete input.dataset.si;
    msg.textContent = text;
    msg.className = cls;
    input.classList.toggle("invalid", si === undefined);
    return si;
  }

  async saveIsolator() {
    const out = $("iso-error");
    out.textContent = "";
    const body = { name: $("iso-name").value.trim(), description: $("iso-description").value.trim() };
    const warnings = [];
    for (const [key] of ISO_PARAMS) {
      const input = $(`iso-${key}`);
      const si = this.readIsoField(input);
      if (si === undefined) {
        out.textContent = `${key}: ${input.closest(".field").querySelector(".msg").textContent}`;
        return;
      }
      body[key] = si;
      const w = implausible(key, si);
      if (w) warnings.push(w);
    }
    if (warnings.length) {
      const ok = await confirmDialog({
        title: `Save isolator ${body.name || "(no name)"} with unusual values?`,
        body: "These values are far outside what isolators usually have. Check the units before saving.",
        warnings, ok: "Save anyway",
      });
      if (!ok) {
        this.message("Isolator not saved: check the values.", "");
        return;
      }
    }
    try {
      const saved = await operatorPost("/api/isolators", body);
      await this.loadIsolators(saved && saved.name ? saved.name : body.name);
      this.formChanged();
      out.textContent = "";
      this.message(`Isolator ${body.name} saved.`, "ok");
    } catch (e) {
      out.textContent = e.message;
    }
  }

  async deleteIsolator() {
    const iso = this.selectedIsolator();
    if (!iso || iso.source !== "user") return;
    const ok = await confirmDialog({
      title: `Delete the user isolator ${iso.name}?`,
      body: "It disappears from the list. Records of tests that used it keep their own copy of its parameters.",
      ok: "Delete isolator", danger: true,
    });
    if (!ok) return;
    try {
      await api.del(`/api/isolators/${encodeURIComponent(iso.name)}`);
      await this.loadIsolators("IUT_b");
      this.formChanged();
      this.message(`Isolator ${iso.name} deleted.`, "ok");
    } catch (e) {
      this.message(`Isolator ${iso.name} not deleted: ${e.message}`, "error");
    }
  }
}
