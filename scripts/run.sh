#!/usr/bin/env bash
# Set up and run the main job on the embedded defaults (simulated rig): a demo simulation of the
# paper's IUT_a scenario with the paper's MRAC, written to out/demo/.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
.venv/bin/isorig simulate --isolator IUT_a --supply-bar 100 --amplitude-m 0.02 --frequency-hz 1 --cycles 30 \
  --controller mrac --out out/demo "$@"
