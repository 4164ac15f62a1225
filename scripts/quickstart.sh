#!/usr/bin/env bash
# Set everything up and run the main job: the paper's methods on the built-in synthetic
# benchmark at context sizes 50, 100, 300 and 1000, logged to the embedded MLflow store, then
# the leaderboard tables and the HTML report. Rerunning skips finished cells.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
.venv/bin/shapebench sweep configs/sweeps/default.yaml
.venv/bin/shapebench leaderboard --dataset synthetic
.venv/bin/shapebench report --dataset synthetic
echo
echo "Report: leaderboards/synthetic-report.html   Tables: leaderboards/synthetic-*.md"
echo "Compare runs: .venv/bin/shapebench ui"
