#!/usr/bin/env bash
# Create .venv and install isorig with its test tools. Safe to run again (seconds when up to date). Says what it
# installs as it goes: the first time takes 1-3 minutes (numpy, scipy, numba, matplotlib, fastapi, playwright ...).
set -euo pipefail
cd "$(dirname "$0")/.."
PYTHON=${PYTHON:-python3}
start=$SECONDS
say() { echo "isorig setup: $*" >&2; }
if [ ! -x .venv/bin/python ]; then
  say "creating .venv with $("$PYTHON" --version 2>&1)"
  "$PYTHON" -m venv .venv
fi
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
say "ready in $((SECONDS - start)) s"
