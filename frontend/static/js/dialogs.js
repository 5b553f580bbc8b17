// One modal confirmation dialog for every action that moves the rig or changes a record: what will happen,
// warnings that need an explicit tick, and fields the action needs (who, why). Cancel is the default button.

const $ = (id) => document.getElementById(id);

/**
 * confirmDialog({title, body, ok, danger, warnings, fields}) -> Promise of null (cancelled) or {values}.
 * body: a Node or text; warnings: texts, each must be ticked before OK; fields: [{name, label, value,
 * minLength, maxLength, placeholder, multiline, type}] (type "password": hidden as typed, not trimmed).
 */
export function confirmDialog({ title, body, ok = "OK", danger = false, warnings = [], fields = [] }) {
  const dialog = $("confirm-dialog");
  const form = $("confirm-form");
  const okButton = $("confirm-ok");
  const cancel = $("confirm-cancel");
  $("confirm-title").textContent = title;
  const box = $("confirm-body");
  box.innerHTML = "";
  if (body instanceof Node) box.append(body);
  else if (body) box.append(Object.assign(document.createElement("p"), { textContent: body }));
  const ticks = [];
  if (warnings.length) {
    const list = document.createElement("div");
    list.className = "warnings";
    for (const text of warnings) {
      const label = document.createElement("label");
      const tick = document.createElement("input");
      tick.type = "checkbox";
      tick.className = "warning-tick";
      label.append(tick, ` ${text}`);
      list.append(label);
      ticks.push(tick);
    }
    box.append(list);
  }
  const inputs = {};
  for (const f of fields) {
    const label = document.createElement("label");
    label.className = "field";
    label.textContent = f.label;
    const input = document.createElement(f.multiline ? "textarea" : "input");
    input.name = f.name;
    input.id = `confirm-${f.name}`;
    input.value = f.value || "";
    if (f.type && !f.multiline) input.type = f.type;
    if (f.type === "password") input.autocomplete = "new-password";
    if (f.placeholder) input.placeholder = f.placeholder;
    if (f.maxLength) input.maxLength = f.maxLength;
    label.append(input);
    box.append(label);
    inputs[f.name] = { input, min: f.minLength || 0 };
  }
  const error = document.createElement("p");
  error.className = "field-error";
  error.id = "confirm-error";
  box.append(error);
  okButton.textContent = ok;
  okButton.className = danger ? "danger" : "primary";
  const refresh = () => {
    const unticked = ticks.some((t) => !t.checked);
    const short = Object.values(inputs).find(({ input, min }) => input.value.trim().length < min);
    okButton.disabled = unticked || Boolean(short);
    error.textContent = unticked ? "Tick each warning to confirm you have checked it." : short
      ? `${short.input.closest("label").firstChild.textContent.trim()}: at least ${short.min} characters.` : "";
  };
  box.addEventListener("input", refresh);
  box.addEventListener("change", refresh);
  refresh();
  return new Promise((resolve) => {
    const done = (value) => {
      form.removeEventListener("submit", onSubmit);
      cancel.removeEventListener("click", onCancel);
      dialog.removeEventListener("cancel", onCancel);
      if (dialog.open) dialog.close();
      resolve(value);
    };
    const onSubmit = (ev) => {
      ev.preventDefault();
      refresh();
      if (okButton.disabled) return;
      const values = {};
      for (const [name, { input }] of Object.entries(inputs)) {
        values[name] = input.type === "password" ? input.value : input.value.trim();
      }
      done({ values });
    };
    const onCancel = (ev) => {
      if (ev) ev.preventDefault();
      done(null);
    };
    form.addEventListener("submit", onSubmit);
    cancel.addEventListener("click", onCancel);
    dialog.addEventListener("cancel", onCancel);
    dialog.showModal();
    const first = Object.values(inputs).find(({ input }) => !input.value);
    (first ? first.input : cancel).focus();
  });
}

/** A definition list for dialog bodies: [[term, value, note?], ...]. */
export function summaryTable(rows) {
  const table = document.createElement("table");
  table.className = "params summary-table";
  for (const [k, v, note] of rows) {
    const tr = document.createElement("tr");
    const th = document.createElement("td");
    th.textContent = k;
    const td = document.createElement("td");
    const b = document.createElement("b");
    b.textContent = v;
    td.append(b);
    if (note) {
      const s = document.createElement("small");
      s.textContent = ` ${note}`;
      td.append(s);
    }
    tr.append(th, td);
    table.append(tr);
  }
  return table;
}
