#!/usr/bin/env bash
# Set up (an install only when pyproject.toml or setup.sh changed since the last one) and run the main job on the
# embedded defaults: the isorig service (REST API, websockets, operator dashboard) with the simulated rig and a
# SQLite database in the user data directory.
# Open http://127.0.0.1:8000/ ; the first start says here which file (mode 0600, in the data directory) holds the
# admin account's password: log in as admin with it, then delete the file. Extra arguments go to
# `isorig serve` (e.g. --host 0.0.0.0 --port 8080 or --database-url postgresql+psycopg://...).
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
exec .venv/bin/isorig serve "$@"
