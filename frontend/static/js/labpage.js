// The Lab page (#/lab): the lab's name, address, logo and default units, as every report prints them
// (backend/lab.py). Anyone reads them; an admin changes them.

import { account, api, asAccount, onAccount } from "./api.js";
import { fmtTime } from "./ui.js";
import { applyLabDefault } from "./units.js";

const $ = (id) => document.getElementById(id);
const LOGO_MAX_BYTES = 1024 * 1024;

export class LabPage {
  constructor() {
    this.lab = null;
    $("lab-form").addEventListener("submit", (ev) => {
      ev.preventDefault();
      this.save();
    });
    $("lab-logo-file").addEventListener("change", () => this.upload());
    $("lab-logo-remove").addEventListener("click", () => this.removeLogo());
    onAccount(() => this.render());
  }

  /** Read the lab (at start: its default units apply to a browser that has not chosen). */
  async load() {
    const written = this.written || 0;
    let lab;
    try {
      lab = await api.get("/api/lab");
    } catch {
      return;
    }
    if ((this.written || 0) !== written) return; // saved meanwhile: this answer is older than what the page has
    this.lab = lab;
    applyLabDefault(this.lab.units);
    this.render(true);
  }

  /** The lab as the service answered a change of it; `fields`: draw the fields too (a logo change keeps them). */
  changed(lab, fields = true) {
    this.written = (this.written || 0) + 1;
    this.lab = lab;
    this.render(fields);
  }

  say(text, kind = "") {
    $("lab-message").textContent = text;
    $("lab-message").className = `message ${kind}`;
  }

  /** Draw the lab; the fields only with `fields` (a load or a save), so an account change keeps what is typed. */
  render(fields = false) {
    const lab = this.lab;
    if (!lab) return;
    const admin = account.role === "admin";
    $("lab-fields").disabled = !admin;
    $("lab-who").textContent = admin ? "You are an admin: changes apply to every report from now on."
      : "An admin changes these (log in as one).";
    if (fields) {
      $("lab-name").value = lab.name;
      $("lab-address").value = lab.address;
      $("lab-units").value = lab.units;
    }
    $("lab-updated").textContent = lab.updated_by ? `last changed by ${lab.updated_by} on ${fmtTime(lab.updated_at)}` : "never changed in the console";
    const img = $("lab-logo");
    img.classList.toggle("hidden", lab.logo !== "stored");
    if (lab.logo === "stored") img.src = `/api/lab/logo?t=${encodeURIComponent(lab.updated_at || "")}`;
    $("lab-logo-none").textContent = lab.logo === "file" ? "the logo file of the service's settings (ISORIG_LAB_LOGO_FILE)"
      : lab.logo === "stored" ? "" : "no logo";
    $("lab-logo-remove").classList.toggle("hidden", lab.logo !== "stored");
  }

  async save() {
    this.say("saving...");
    try {
      this.changed(await asAccount("PUT", "/api/lab", { name: $("lab-name").value, address: $("lab-address").value,
        units: $("lab-units").value }));
      this.say("Saved: every report uses it from now on.", "ok");
    } catch (e) {
      this.say(`Not saved: ${e.message}`, "error");
    }
  }

  async upload() {
    const file = $("lab-logo-file").files[0];
    if (!file) return;
    if (file.size > LOGO_MAX_BYTES) {
      this.say(`The logo has ${file.size} bytes; at most ${LOGO_MAX_BYTES} are taken.`, "error");
      return;
    }
    const data = await new Promise((resolve, reject) => {
      const reader = new FileReader();
      reader.onload = () => resolve(String(reader.result).split(",", 2)[1] || "");
      reader.onerror = () => reject(reader.error);
      reader.readAsDataURL(file);
    });
    try {
      this.changed(await asAccount("PUT", "/api/lab/logo", { data_base64: data }), false);
      this.say("Logo saved.", "ok");
    } catch (e) {
      this.say(`Logo not saved: ${e.message}`, "error");
    }
    $("lab-logo-file").value = "";
  }

  async removeLogo() {
    try {
      this.changed(await asAccount("PUT", "/api/lab/logo", { data_base64: null }), false);
      this.say("Logo removed.", "ok");
    } catch (e) {
      this.say(`Logo not removed: ${e.message}`, "error");
    }
  }
}
