#!/usr/bin/env bash
# The measurement of docs/compare.md, "Campaigns": the documented Monte Carlo campaign (1000 plants x servo, pid,
# 10 cycles) on the local dask cluster, then the same runs in one process, on the process pool and on the cluster
# again (isorig compare --compare-backends). Writes the CSV and the figure to OUT (default: a new temp directory).
# Usage: bash scripts/campaign_benchmark.sh [OUT_DIR] [extra isorig compare options]
set -euo pipefail
cd "$(dirname "$0")/.."
out=${1:-$(mktemp -d)}
shift || true
mkdir -p "$out"
# the campaign file is the one docs/compare.md shows (tests/test_campaign.py keeps it a valid campaign)
sed -n '/^### The campaign file/,$p' docs/compare.md | sed -n '/^```toml$/,/^```$/p' | sed '1d;$d' >"$out/lab_spread.toml"
uptime >&2
time .venv/bin/isorig compare --monte-carlo "$out/lab_spread.toml" --compare-backends --markdown \
  --csv "$out/lab_spread.csv" --figure "$out/lab_spread.png" "$@"
