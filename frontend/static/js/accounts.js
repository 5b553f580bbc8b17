// The Accounts page (#/accounts): an admin adds accounts, sets their roles, resets passwords, disables and enables
// them and makes or revokes API tokens (backend/api/accounts.py: the rules of `isorig user`, enforced by the
// service). A password or token made by the service is shown once, here, and kept nowhere.

import { account, api, asAccount, NewestOnly, onAccount, refreshAccount } from "./api.js";
import { confirmDialog } from "./dialogs.js";
import { el, fmtTime } from "./ui.js";

const $ = (id) => document.getElementById(id);
const STATE_WORDS = { active: "active", disabled: "disabled", "token only": "tokens only" };

export class AccountsPage {
  constructor() {
    this.list = null;
    this.lists = new NewestOnly();
    this.visible = false;
    $("acct-form").addEventListener("submit", (ev) => {
      ev.preventDefault();
      this.add();
    });
    $("acct-secret-hide").addEventListener("click", () => this.showSecret(null));
    $("acct-login").addEventListener("click", () => asAccount("GET", "/api/accounts").then(() => this.load(), () => {}));
    onAccount(() => {
      $("nav-accounts").classList.toggle("hidden", account.role !== "admin");
      if (this.visible) this.load();
    });
  }

  show() {
    this.visible = true;
    this.load();
  }

  hide() {
    this.visible = false;
    this.showSecret(null); // a password or token shown once does not wait on a page nobody looks at
  }

  say(text, kind = "") {
    $("acct-message").textContent = text;
    $("acct-message").className = `message ${kind}`;
  }

  async load() {
    const stale = this.lists.ask();
    const admin = account.role === "admin";
    $("acct-admin").classList.toggle("hidden", !admin);
    $("acct-not-admin").classList.toggle("hidden", admin);
    $("acct-login").classList.toggle("hidden", Boolean(account.name));
    $("acct-who").textContent = account.name
      ? `You are logged in as ${account.name}, ${account.role}: only an admin manages accounts.`
      : "Only an admin manages accounts: log in as one.";
    if (!admin) {
      this.list = null;
      $("acct-table").querySelector("tbody").replaceChildren();
      return;
    }
    let answer;
    try {
      answer = await api.get("/api/accounts");
    } catch (e) {
      if (!stale()) this.say(`The accounts could not be read: ${e.message}`, "error");
      return;
    }
    if (stale()) return;
    this.list = answer;
    this.render();
  }

  render() {
    const { accounts, roles, you, password_min_chars: min } = this.list;
    $("acct-password").placeholder = "blank: one is made";
    $("acct-password").title = `at least ${min} characters; left blank, the service makes one and shows it once`;
    const roleSelect = $("acct-role");
    if (!roleSelect.options.length) {
      for (const r of roles) roleSelect.append(el("option", { value: r, text: r }));
      roleSelect.value = "operator";
    }
    const rows = accounts.map((a) => this.row(a, roles, you));
    $("acct-table").querySelector("tbody").replaceChildren(...rows);
    $("acct-table").dataset.count = String(accounts.length);
  }

  row(a, roles, you) {
    const self = a.name === you;
    const role = el("select", { "aria-label": `role of ${a.name}`, class: "acct-role-select" });
    for (const r of roles) role.append(el("option", { value: r, text: r }));
    role.value = a.role;
    role.disabled = self;
    role.title = self ? "your own role: another admin changes it (the console never locks you out)" : "";
    role.addEventListener("change", () => this.setRole(a, role));
    const state = el("span", { class: `pill acct-state acct-${a.state.replace(" ", "-")}`, text: STATE_WORDS[a.state] || a.state,
      title: a.state === "token only" ? "no password: it acts through API tokens only" : "" });
    const when = a.disabled_at ? `disabled ${fmtTime(a.disabled_at)}` : `since ${fmtTime(a.created_at)}`;
    const button = (text, fn, attrs = {}) => {
      const b = el("button", { type: "button", class: "ghost small", ...attrs, text });
      b.addEventListener("click", fn);
      return b;
    };
    const actions = el("td", { class: "actions" });
    actions.append(button("Password...", () => this.password(a), { "data-act": "password" }));
    if (a.state === "disabled") actions.append(button("Enable", () => this.enable(a), { "data-act": "enable" }));
    else if (!self) actions.append(button("Disable...", () => this.disable(a), { "data-act": "disable" }));
    if (a.state !== "disabled") actions.append(button("New API token...", () => this.token(a), { "data-act": "token" }));
    if (a.tokens) actions.append(button("Revoke tokens...", () => this.revoke(a), { "data-act": "revoke" }));
    const name = el("td", { class: "who" }, a.name);
    if (self) name.append(el("small", { class: "muted", text: " (you)" }));
    if (a.service_account) {
      name.append(el("small", { class: "muted", text: " (service)", title: "ISORIG_OPERATOR_TOKEN acts as this account" }));
    }
    const tr = el("tr", { "data-name": a.name, "data-state": a.state },
      name, el("td", {}, role), el("td", {}, state, el("small", { class: "muted", text: ` ${when}` })),
      el("td", { class: "num", text: String(a.logins) }), el("td", { class: "num", text: String(a.tokens) }), actions);
    return tr;
  }

  /** A change answered by the service: say it, show a secret it made (once), read the list again. */
  async act(method, path, body, said) {
    this.showSecret(null); // a secret shown for an earlier change is not this one's
    this.say("sending...");
    let answer;
    try {
      answer = await asAccount(method, path, body);
    } catch (e) {
      this.say(`Not done: ${e.message}`, "error");
      await this.load();
      return null;
    }
    this.say(said(answer), "ok");
    await this.load();
    return answer;
  }

  async add() {
    const name = $("acct-name").value.trim();
    const role = $("acct-role").value;
    const password = $("acct-password").value;
    if (!name) {
      this.say("Give the new account a name.", "error");
      return;
    }
    const answer = await this.act("POST", "/api/accounts", { name, role, password: password || null },
      (a) => `Added ${a.account.name} (${a.account.role}).`);
    if (!answer) return;
    $("acct-name").value = "";
    $("acct-password").value = "";
    if (answer.password) this.showSecret(`${answer.account.name}'s password`, answer.password);
  }

  async setRole(a, select) {
    const role = select.value;
    const ok = await confirmDialog({ title: `Make ${a.name} ${role}?`, ok: `Make ${role}`,
      body: `${a.name} is ${a.role} now; as ${role} the account may do what that role allows from its next request ` +
        "on (its logins and tokens stay)." });
    if (!ok) {
      select.value = a.role;
      return;
    }
    await this.act("PUT", `/api/accounts/${encodeURIComponent(a.name)}/role`, { role },
      (r) => `${r.account.name} is now ${r.account.role}.`);
  }

  async password(a) {
    const self = a.name === this.list.you;
    const ok = await confirmDialog({ title: `New password for ${a.name}`, ok: "Set the password",
      body: `${a.name}'s logins end now${self ? " (yours too: log in again with the new password)" : ""}; its API ` +
        `tokens stay. Leave the field blank and the service makes one, shown here once.`,
      fields: [{ name: "password", label: "New password", type: "password", maxLength: 1024,
        placeholder: `blank: one is made (or at least ${this.list.password_min_chars} characters)` }] });
    if (!ok) return;
    const answer = await this.act("POST", `/api/accounts/${encodeURIComponent(a.name)}/password`,
      { password: ok.values.password || null }, (r) => `New password set for ${r.account.name}; its logins have ended.`);
    if (answer && answer.password) this.showSecret(`${a.name}'s new password`, answer.password);
    if (answer && answer.logged_out) await refreshAccount();
  }

  async disable(a) {
    const ok = await confirmDialog({ title: `Disable ${a.name}?`, ok: "Disable", danger: true,
      body: `${a.name} can no longer log in, and its ${a.logins} login(s) and ${a.tokens} API token(s) end now. ` +
        "Its name stays in every record; Enable lets it log in again (tokens do not come back)." });
    if (!ok) return;
    await this.act("POST", `/api/accounts/${encodeURIComponent(a.name)}/disable`, undefined,
      (r) => `${r.account.name} is disabled: its logins and tokens have ended.`);
  }

  async enable(a) {
    await this.act("POST", `/api/accounts/${encodeURIComponent(a.name)}/enable`, undefined,
      (r) => `${r.account.name} may log in again.`);
  }

  async token(a) {
    const ok = await confirmDialog({ title: `A new API token for ${a.name}?`, ok: "Make the token",
      body: `A script that sends it (Authorization: Bearer <token>) acts as ${a.name}, ${a.role}, until the account's ` +
        "tokens are revoked or it is disabled. It is shown once, here: the service keeps only its hash." });
    if (!ok) return;
    const answer = await this.act("POST", `/api/accounts/${encodeURIComponent(a.name)}/tokens`, undefined,
      (r) => `New API token for ${r.account.name}.`);
    if (answer && answer.token) this.showSecret(`${a.name}'s new API token`, answer.token);
  }

  async revoke(a) {
    const ok = await confirmDialog({ title: `Revoke ${a.name}'s API tokens?`, ok: "Revoke", danger: true,
      body: `Every script using one of ${a.name}'s ${a.tokens} API token(s) is refused from now on.` });
    if (!ok) return;
    await this.act("DELETE", `/api/accounts/${encodeURIComponent(a.name)}/tokens`, undefined,
      (r) => `Revoked ${r.revoked} API token(s) of ${r.account.name}.`);
  }

  /** A password or token the service made: shown once, until dismissed or the page is left. */
  showSecret(what, secret) {
    $("acct-secret").classList.toggle("hidden", !secret);
    $("acct-secret-what").textContent = what || "";
    $("acct-secret-value").textContent = secret || "";
  }
}
