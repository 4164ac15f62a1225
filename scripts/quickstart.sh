#!/usr/bin/env bash
# Install shapebench (scripts/setup.sh --runtime: without the test tools) and run the main job:
# the paper's methods on the built-in synthetic benchmark at context sizes 50, 100, 300 and 1000
# with the shipped (standard-profile) weights, logged to the embedded MLflow store, then the
# leaderboard tables and the HTML report.
# Rerunning skips finished cells; Ctrl-C and rerun resumes.
#
#   bash scripts/quickstart.sh          # 4 test objects per category (60), seed 0's weights,
#                                       # two workers: tables and report in
#                                       # shapebench-runs/leaderboards/
#   bash scripts/quickstart.sh --full   # the default sweep whole (10 per category, 150
#                                       # objects, three seeds, about 1.5 hours on 2 cores):
#                                       # the committed tables, rewritten in leaderboards/
set -euo pipefail
cd "$(dirname "$0")/.."
case "${1:-}" in
    "") size=(-D test_per_category=4 --seeds 0) out=shapebench-runs/leaderboards ;;
    --full) size=() out=leaderboards ;;
    *) echo "usage: bash scripts/quickstart.sh [--full]" >&2; exit 2 ;;
esac
bash scripts/setup.sh --runtime  # the tests' tools too: bash scripts/setup.sh
.venv/bin/shapebench sweep configs/sweeps/default.yaml "${size[@]}" --launcher local -j 2
.venv/bin/shapebench leaderboard --dataset synthetic --out "$out"
.venv/bin/shapebench report --dataset synthetic --out "$out"
echo
echo "Report: $out/synthetic-report.html   Tables: $out/synthetic-*.md"
echo "Compare runs: .venv/bin/shapebench ui"
