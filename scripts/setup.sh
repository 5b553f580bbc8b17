#!/usr/bin/env bash
# Create .venv and install isorig with its test tools. Safe to run again (fast when up to date).
set -euo pipefail
cd "$(dirname "$0")/.."
PYTHON=${PYTHON:-python3}
if [ ! -x .venv/bin/python ]; then
  "$PYTHON" -m venv .venv
fi
.venv/bin/python -m pip install -q --upgrade pip >/dev/null 2>&1 || true
log=$(mktemp)
if ! .venv/bin/python -m pip install -q -e ".[test]" >"$log" 2>&1; then
  cat "$log" >&2  # pip's output only when the install failed
  rm -f "$log"
  exit 1
fi
rm -f "$log"
.venv/bin/python -c "import sim, numba, fastapi" # fail loudly if the install did not work
