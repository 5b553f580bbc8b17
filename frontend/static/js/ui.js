// Small shared UI helpers: formatting, the status badge and the alert banner.

export function fmtDuration(s) {
  if (typeof s !== "number" || !isFinite(s)) return "-";
  s = Math.max(0, Math.round(s));
  const h = Math.floor(s / 3600);
  const m = Math.floor((s % 3600) / 60);
  const sec = s % 60;
  const two = (x) => String(x).padStart(2, "0");
  return h ? `${h}:${two(m)}:${two(sec)}` : `${m}:${two(sec)}`;
}

/** value * scale with `digits` significant digits and a unit, or "-" when missing. */
export function fmtMetric(value, scale, unit, digits = 4) {
  if (typeof value !== "number" || !isFinite(value)) return "-";
  return `${(value * scale).toPrecision(digits).replace(/\.?0+$/, (m) => (m.includes(".") ? "" : m))} ${unit}`;
}

export function setStatusBadge(status) {
  const el = document.getElementById("rig-status");
  const s = (status || "idle").toLowerCase();
  const stale = el.classList.contains("stale");
  el.className = `status-badge status-${s}${stale ? " stale" : ""}`;
  el.textContent = s.toUpperCase();
  el.dataset.status = s;
}

let alertTimer = null;

/** Prominent banner. kind: "bad" (stays until dismissed), "warn", "info" (fades after 8 s). */
export function showAlert(text, kind = "bad") {
  const el = document.getElementById("alert");
  document.getElementById("alert-text").textContent = text;
  el.className = `alert ${kind === "bad" ? "" : kind}`;
  el.dataset.kind = kind;
  clearTimeout(alertTimer);
  if (kind !== "bad") alertTimer = setTimeout(() => el.classList.add("hidden"), 8000);
}

export function hideAlert() {
  document.getElementById("alert").classList.add("hidden");
}

/** An ISO 8601 time of the service (UTC) as local "YYYY-MM-DD HH:MM:SS", or "" when missing. */
export function fmtTime(iso) {
  if (!iso) return "";
  const d = new Date(iso);
  if (isNaN(d.getTime())) return String(iso);
  const two = (x) => String(x).padStart(2, "0");
  return `${d.getFullYear()}-${two(d.getMonth() + 1)}-${two(d.getDate())} ` +
    `${two(d.getHours())}:${two(d.getMinutes())}:${two(d.getSeconds())}`;
}

export function eventLine(e) {
  const t = typeof e.time_s === "number" ? `t=${e.time_s.toFixed(2)} s ` : "";
  const when = e.created_at ? `${fmtTime(e.created_at)} ` : "";
  let vals = "";
  if (e.values && typeof e.values === "object" && Object.keys(e.values).length) {
    vals = " (" + Object.entries(e.values).map(([k, v]) => `${k}=${typeof v === "number" ? +v.toPrecision(4) : v}`)
      .join(", ") + ")";
  }
  return `${when}${t}[${e.kind || "event"}] ${e.message || ""}${vals}`;
}

export function el(tag, attrs = {}, ...children) {
  const node = document.createElement(tag);
  for (const [k, v] of Object.entries(attrs)) {
    if (k === "class") node.className = v;
    else if (k === "text") node.textContent = v;
    else node.setAttribute(k, v);
  }
  for (const c of children) node.append(c);
  return node;
}
