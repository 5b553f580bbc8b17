// REST client: same-origin fetch; who acts is the login session (a cookie the service sets, HttpOnly).

export class ApiError extends Error {
  constructor(status, detail, message) {
    super(message);
    this.status = status;
    this.detail = detail;
  }
}

/** Who is logged in on this console (GET /api/session): {name, role} or {name: null}. */
export const account = { name: null, role: null };
const accountListeners = [];

/**
 * Requests of one kind, numbered as they are sent, so that a page draws only the newest answer: `const stale =
 * this.lists.ask();` before the request, `if (stale()) return;` after each await (an older answer that comes later
 * is dropped).
 */
export class NewestOnly {
  constructor() { this.asked = 0; }

  ask() {
    const n = ++this.asked;
    return () => n !== this.asked;
  }
}

export function onAccount(fn) { accountListeners.push(fn); }

function setAccount(who) {
  account.name = (who && who.name) || null;
  account.role = (who && who.role) || null;
  for (const fn of accountListeners) fn(account);
}

/** Ask the service who this browser is logged in as (the login cookie is HttpOnly: no script reads it). */
export async function refreshAccount() {
  try {
    setAccount(await request("GET", "/api/session"));
  } catch {
    /* the service is down: keep what we knew */
  }
  return account;
}

/**
 * Ask for a name and password in a modal dialog and log in (POST /api/session sets the login cookie).
 * Resolves true once logged in, false if cancelled; a refusal is shown in the dialog, which stays open.
 */
export function askLogin(reason) {
  const dialog = document.getElementById("login-dialog");
  const name = document.getElementById("login-name");
  const password = document.getElementById("login-password");
  const why = document.getElementById("login-reason");
  const cancel = document.getElementById("login-cancel");
  const form = document.getElementById("login-form");
  why.textContent = reason || "";
  password.value = "";
  return new Promise((resolve) => {
    const done = (value) => {
      form.removeEventListener("submit", onSubmit);
      cancel.removeEventListener("click", onCancel);
      dialog.close();
      resolve(value);
    };
    const onSubmit = async (ev) => {
      ev.preventDefault();
      if (!name.value.trim() || !password.value) return;
      try {
        setAccount(await request("POST", "/api/session", { name: name.value.trim(), password: password.value }));
        password.value = "";
        done(true);
      } catch (e) {
        why.textContent = e.message;
        password.value = "";
        password.focus();
      }
    };
    const onCancel = () => done(false);
    form.addEventListener("submit", onSubmit);
    cancel.addEventListener("click", onCancel);
    dialog.showModal();
    (name.value ? password : name).focus();
  });
}

export async function logOut() {
  await request("DELETE", "/api/session");
  setAccount(null);
}

/** Turn a FastAPI error body into one readable sentence (422 lists carry field, value and limit). */
export function describeError(status, body) {
  if (!body) return `HTTP ${status}`;
  const detail = body.detail !== undefined ? body.detail : body;
  if (typeof detail === "string") {
    if (body.limit && !detail.includes(String(body.limit))) return `${detail} (limit: ${body.limit})`;
    return detail;
  }
  if (Array.isArray(detail)) {
    return detail.map((d) => {
      if (typeof d === "string") return d;
      const loc = Array.isArray(d.loc) ? d.loc.filter((x) => x !== "body").join(".") : d.field || "";
      const msg = d.msg || d.message || JSON.stringify(d);
      return loc ? `${loc}: ${msg}` : msg;
    }).join("; ");
  }
  if (typeof detail === "object") {
    if (detail.message) return detail.message;
    if (detail.field) return `${detail.field} = ${detail.value}: limit ${detail.limit}`;
  }
  return JSON.stringify(detail);
}

/** The field a 422 answer blames (for highlighting an input), or "". */
export function errorField(detail) {
  if (detail && detail.field) return detail.field;
  const d = detail && detail.detail !== undefined ? detail.detail : detail;
  if (!d) return "";
  if (d.field) return d.field;
  if (Array.isArray(d) && d.length) {
    const first = d[0];
    if (first.field) return first.field;
    if (Array.isArray(first.loc)) return String(first.loc[first.loc.length - 1]);
  }
  return "";
}

/** Seconds to wait before asking again a service whose check pool (backend.checks) answered 503: the answer's
 * Retry-After, kept within 1-10 s (2 s if it has none). */
function busyWaitS(res) {
  return Math.min(Math.max(Number(res.headers.get("Retry-After")) || 2, 1), 10);
}

/** Send (a function that returns a fetch's Response) again while the service's check pool is busy (503): after its
 * Retry-After, at most `tries` times. `onBusy(seconds)` tells the page it waits; `wanted()` false stops asking (the
 * page moved on). The last Response; a fetch error throws. */
async function askWhenFree(send, { tries = 10, onBusy = () => {}, wanted = () => true } = {}) {
  for (let i = 1; ; i++) {
    const res = await send();
    if (res.status !== 503 || i >= tries || !wanted()) return res;
    const waitS = busyWaitS(res);
    onBusy(waitS);
    await new Promise((resolve) => { setTimeout(resolve, waitS * 1000); });
    if (!wanted()) return res;
  }
}

/** `whenBusy` ({tries, onBusy, wanted}): ask again while the check pool is busy (askWhenFree). An error answer
 * throws ApiError; a 503 carries `retryAfterS`, for a caller that asks again in its own way. */
async function request(method, path, body, { auth = false, retryAuth = true, whenBusy = null } = {}) {
  // X-Isorig-Client: the service refuses a browser request that changes state without JSON or this header (a
  // foreign page cannot send it without a CORS preflight, which the service never grants): docs/backend.md.
  // Who acts is the login cookie (HttpOnly, SameSite=Strict), sent by the browser itself.
  const headers = { Accept: "application/json", "X-Isorig-Client": "console" };
  if (body !== undefined) headers["Content-Type"] = "application/json";
  const send = () => fetch(path, {
    method,
    headers,
    credentials: "same-origin",
    body: body === undefined ? undefined : JSON.stringify(body),
  });
  const res = await (whenBusy ? askWhenFree(send, whenBusy) : send());
  if (res.status === 401 && auth && retryAuth) {
    const wasIn = account.name;
    setAccount(null);
    if (await askLogin(wasIn ? "your login has ended: log in again" : "this needs an account with the right role")) {
      return request(method, path, body, { auth, retryAuth: false, whenBusy });
    }
  }
  let data = null;
  const text = await res.text();
  if (text) {
    try { data = JSON.parse(text); } catch { data = text; }
  }
  if (!res.ok) {
    const error = new ApiError(res.status, data, describeError(res.status, data));
    if (res.status === 503) error.retryAfterS = busyWaitS(res);
    throw error;
  }
  return data;
}

/** GET a view that the service builds in its check pool (backend.checks), e.g. an earthquake test's figures, asking
 * again while the pool is busy (askWhenFree: `tries`, `onBusy`, `wanted`). The last Response; a fetch error throws. */
export function fetchWhenFree(url, whenBusy = {}) {
  return askWhenFree(() => fetch(url, { headers: { Accept: "application/json" }, credentials: "same-origin" }), whenBusy);
}

export const api = {
  get: (path) => request("GET", path),
  post: (path, body) => request("POST", path, body, { auth: true }),
  /** POST that never asks for a login (read-only checks). */
  postQuiet: (path, body) => request("POST", path, body),
  /** postQuiet to a route that runs in the service's check pool: asked again while the pool is busy (503). */
  postWhenFree: (path, body, whenBusy = {}) => request("POST", path, body, { whenBusy }),
  /** Stop and abort: never ask for a login: the service ends a test for anyone (like an emergency stop) and
   * records who asked (the logged-in account, else the console's address). */
  endTest: (path) => request("POST", path, undefined, { auth: true, retryAuth: false }),
  del: (path) => request("DELETE", path, undefined, { auth: true }),
};

/** A request that needs an account (operator commands, an admin's settings): ask for a login first if nobody is
 * logged in on this console. */
export async function asAccount(method, path, body) {
  if (!account.name) {
    await refreshAccount();
    if (!account.name && !(await askLogin(""))) throw new ApiError(0, null, "not logged in: nothing was sent");
  }
  return request(method, path, body, { auth: true });
}

export const operatorPost = (path, body) => asAccount("POST", path, body);
