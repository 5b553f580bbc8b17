#!/usr/bin/env bash
# Set up (venv, Python packages) and run the whole test suite: lint, then pytest.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
# Debian packages the tests need: chromium for the dashboard's browser tests (tests/e2e; Playwright drives it,
# its own browser download is not used), poppler-utils for pdftoppm, which renders report pages to PNG, and
# postgresql: the PostgreSQL tests start a server of their own from its binaries (tests/backend/pg_server.py).
missing=""
[ -x /usr/bin/chromium ] || missing="$missing chromium"
command -v pdftoppm >/dev/null 2>&1 || missing="$missing poppler-utils"
ls /usr/lib/postgresql/*/bin/initdb >/dev/null 2>&1 || command -v initdb >/dev/null 2>&1 || missing="$missing postgresql"
if [ -n "$missing" ]; then
  SUDO=""
  if [ "$(id -u)" -ne 0 ] && command -v sudo >/dev/null 2>&1; then SUDO="sudo"; fi
  echo "installing Debian packages:$missing"
  $SUDO apt-get update -q >/dev/null
  # shellcheck disable=SC2086
  $SUDO apt-get install -y -q $missing >/dev/null
fi
.venv/bin/ruff check .
# the slowest tests named at the end: what to trim when the suite grows (CI has 90 minutes; we keep it well under 15);
# every test's time in artifacts/pytest.xml (JUnit XML)
mkdir -p artifacts
.venv/bin/python -m pytest -q --durations=20 --junitxml=artifacts/pytest.xml "$@"
