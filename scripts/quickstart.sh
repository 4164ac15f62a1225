#!/usr/bin/env bash
# Set everything up and run the main job: every installed method on the built-in synthetic
# benchmark at context sizes 50, 100, 300 and 1000, logged to the embedded MLflow store, then
# the leaderboard tables. Rerunning skips finished cells.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
.venv/bin/shapebench sweep configs/sweeps/default.yaml
.venv/bin/shapebench leaderboard --dataset synthetic
echo
echo "Tables: leaderboards/synthetic-*.md   Compare runs: .venv/bin/shapebench ui"
