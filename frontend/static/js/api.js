// REST client: same-origin fetch, the operator token kept in localStorage and asked for once.

const TOKEN_KEY = "isorig.operator_token";

export class ApiError extends Error {
  constructor(status, detail, message) {
    super(message);
    this.status = status;
    this.detail = detail;
  }
}

export function getToken() {
  return localStorage.getItem(TOKEN_KEY) || "";
}

export function setToken(token) {
  if (token) localStorage.setItem(TOKEN_KEY, token);
  else localStorage.removeItem(TOKEN_KEY);
}

/** Ask the operator for the token in a modal dialog; resolves to the token or "" if cancelled. */
export function askToken(reason) {
  const dialog = document.getElementById("token-dialog");
  const input = document.getElementById("token-input");
  const cancel = document.getElementById("token-cancel");
  const form = document.getElementById("token-form");
  document.getElementById("token-reason").textContent = reason || "";
  input.value = "";
  return new Promise((resolve) => {
    const done = (value) => {
      form.removeEventListener("submit", onSubmit);
      cancel.removeEventListener("click", onCancel);
      dialog.close();
      resolve(value);
    };
    const onSubmit = (ev) => {
      ev.preventDefault();
      const token = input.value.trim();
      if (!token) return;
      setToken(token);
      done(token);
    };
    const onCancel = () => done("");
    form.addEventListener("submit", onSubmit);
    cancel.addEventListener("click", onCancel);
    dialog.showModal();
    input.focus();
  });
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

async function request(method, path, body, { auth = false, retryAuth = true } = {}) {
  // X-Isorig-Client: the service refuses a browser request that changes state without JSON or this header (a
  // foreign page cannot send it without a CORS preflight, which the service never grants): docs/backend.md
  const headers = { Accept: "application/json", "X-Isorig-Client": "console" };
  if (body !== undefined) headers["Content-Type"] = "application/json";
  const token = getToken();
  if (auth && token) headers.Authorization = `Bearer ${token}`;
  const res = await fetch(path, {
    method,
    headers,
    body: body === undefined ? undefined : JSON.stringify(body),
  });
  if ((res.status === 401 || res.status === 403) && auth && retryAuth) {
    const fresh = await askToken(token ? "the stored token was refused" : "");
    if (fresh) return request(method, path, body, { auth, retryAuth: false });
  }
  let data = null;
  const text = await res.text();
  if (text) {
    try { data = JSON.parse(text); } catch { data = text; }
  }
  if (!res.ok) throw new ApiError(res.status, data, describeError(res.status, data));
  return data;
}

export const api = {
  get: (path) => request("GET", path),
  post: (path, body) => request("POST", path, body, { auth: true }),
  /** POST that never asks for the token (read-only checks). */
  postQuiet: (path, body) => request("POST", path, body),
  /** Stop and abort: the token goes along if this browser has one, but is never asked for: the service ends a
   * test for anyone (like an emergency stop) and records who asked. */
  endTest: (path) => request("POST", path, undefined, { auth: true, retryAuth: false }),
  del: (path) => request("DELETE", path, undefined, { auth: true }),
};

/** Operator commands always carry the token; ask for it first if this browser has none. */
export async function operatorPost(path, body) {
  if (!getToken()) {
    const token = await askToken("");
    if (!token) throw new ApiError(0, null, "no operator token given");
  }
  return api.post(path, body);
}
