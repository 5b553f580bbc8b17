// Numbers typed by the operator: text inputs with explicit parsing, never the browser's type=number (which may
// drop a decimal comma: "3,5" must never become 35). A decimal comma or point is read as such; anything that
// could be read two ways ("1,000": a thousand or one?) is refused with a message, never guessed.

/** The decimal separator of the browser's locale ("." or ","). */
export function localeDecimal() {
  try {
    const parts = new Intl.NumberFormat(navigator.language || "en").formatToParts(1.5);
    const d = parts.find((p) => p.type === "decimal");
    return d && d.value === "," ? "," : ".";
  } catch {
    return ".";
  }
}

const NUMBER = /^([+-]?)(\d*)(?:([.,])(\d*))?(?:[eE]([+-]?\d+))?$/;

/**
 * Parse an operator's number. Returns {empty: true} for blank text, else {ok: true, value, comma} or
 * {ok: false, error}. opts.integer: a whole number only.
 */
export function parseNumber(text, { integer = false } = {}) {
  const raw = String(text === undefined || text === null ? "" : text).trim();
  if (raw === "") return { empty: true, ok: false };
  const compact = raw.replace(/\u2212/g, "-"); // a typographic minus
  if (/\s|'|\u00a0|\u202f|_/.test(compact)) {
    return { ok: false, error: `"${raw}": no spaces or digit-group separators, please (write e.g. 1500)` };
  }
  if ((compact.match(/[.,]/g) || []).length > 1) {
    return { ok: false, error: `"${raw}": one decimal separator only, no thousands separators (write e.g. 1500 or 3.5)` };
  }
  const m = compact.match(NUMBER);
  if (!m || (m[2] === "" && (m[4] === undefined || m[4] === ""))) {
    return { ok: false, error: `"${raw}" is not a number` };
  }
  const [, sign, intPart, sep, frac = "", exp] = m;
  const local = localeDecimal();
  // "1,000" or "12.500": a digit group of the other convention or a decimal? Ask instead of guessing.
  if (sep && sep !== local && frac.length === 3 && exp === undefined && /^[1-9]\d{0,2}$/.test(intPart)) {
    const asDecimal = `${intPart}.${frac.replace(/0+$/, "") || "0"}`;
    return {
      ok: false,
      error: `"${raw}" could be read as ${intPart}${frac} or as ${asDecimal}: write ${intPart}${frac} or ${asDecimal}`,
    };
  }
  const value = Number(`${sign}${intPart || "0"}${sep ? `.${frac || "0"}` : ""}${exp !== undefined ? `e${exp}` : ""}`);
  if (!Number.isFinite(value)) return { ok: false, error: `"${raw}" is not a finite number` };
  if (integer && !Number.isInteger(value)) return { ok: false, error: `"${raw}": a whole number, please` };
  return { ok: true, value, comma: sep === "," };
}
