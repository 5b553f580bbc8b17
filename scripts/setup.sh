#!/usr/bin/env bash
# Create .venv and install isorig with its test tools. Safe to run again: it installs only when the project's
# requirements changed since the last install, else it says so and returns within a second. Says what it installs
# as it goes: the first time takes 1-3 minutes (numpy, scipy, numba, matplotlib, fastapi, playwright ...).
#
# What "changed" means: .venv/isorig-setup.sha256 holds a hash of pyproject.toml (dependencies, and the packages
# of packages.find, e.g. a new top-level package) and of this script, written after a successful install. The
# install is editable (pip install -e), so a change to the sources needs none. ISORIG_SETUP_FORCE=1 installs anyway;
# `scripts/setup.sh --check` only says whether an install is needed (exit 0: up to date, 1: it is).
set -euo pipefail
cd "$(dirname "$0")/.."
PYTHON=${PYTHON:-python3}
start=$SECONDS
say() { echo "isorig setup: $*" >&2; }
stamp=.venv/isorig-setup.sha256
wanted=$(cat pyproject.toml scripts/setup.sh | sha256sum | cut -d' ' -f1)
up_to_date() {
  [ "${ISORIG_SETUP_FORCE:-0}" != 1 ] && [ -f "$stamp" ] && [ "$(cat "$stamp")" = "$wanted" ] \
    && [ -x .venv/bin/isorig ] && .venv/bin/python -c "import isorig.cli" >/dev/null 2>&1
}
if [ "${1:-}" = "--check" ]; then
  up_to_date
  exit
fi
if up_to_date; then
  say "up to date (pyproject.toml unchanged since the last install; ISORIG_SETUP_FORCE=1 installs anyway)"
  exit 0
fi
if [ ! -x .venv/bin/python ]; then
  say "creating .venv with $("$PYTHON" --version 2>&1)"
  "$PYTHON" -m venv .venv
fi
rm -f "$stamp"  # until this install has succeeded
.venv/bin/python -m pip install -q --upgrade pip >/dev/null 2>&1 || true
say "installing isorig and its Python packages into .venv (pip install -e \".[test]\") ..."
log=$(mktemp)
# pip's own lines for what it fetches and installs, shown as they come; the rest only if the install fails
if ! .venv/bin/python -m pip install --progress-bar off -e ".[test]" 2>&1 | tee "$log" \
    | { grep --line-buffered -E "^(Collecting|Installing collected packages|Successfully installed)" || true; } \
    | sed -u -e 's/^Collecting /  fetching /' -e 's/^Installing collected packages: /  installing: /' \
             -e 's/^Successfully installed /  installed: /' >&2; then
  cat "$log" >&2
  rm -f "$log"
  say "the install failed (pip's output above)"
  exit 1
fi
rm -f "$log"
.venv/bin/python -c "import sim, numba, fastapi" # fail loudly if the install did not work
echo "$wanted" >"$stamp"
say "ready in $((SECONDS - start)) s"
