// The "operator" fields of the forms show the logged-in account: every record names the account that acted
// (backend/accounts.py), so the name is not typed. Read-only; "log in" until someone is.

import { account, onAccount } from "./api.js";

const bound = [];

function show(input) {
  if (input.dataset.following) return; // showing a running test's operator (setup.js followTest)
  input.value = account.name || "";
}

/** Make ``input`` show the logged-in account, now and after every login or logout. */
export function bindAccountField(input) {
  input.readOnly = true;
  input.placeholder = "log in: the account that acts";
  input.title = "the logged-in account: every record names the account that acted (the account button, top right)";
  bound.push(input);
  show(input);
}

onAccount(() => bound.forEach(show));
