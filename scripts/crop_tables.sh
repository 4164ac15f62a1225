#!/usr/bin/env bash
# The committed crop tables (leaderboards/synthetic-*-crop-0_*.md): the default sweep's methods on
# ShapeNet-55-style partial shapes at 2,048 context points, crops of 0.25, 0.5 and 0.75, then a
# table per crop. Reference checkpoints are used where shipped; rerunning skips finished cells.
set -euo pipefail
cd "$(dirname "$0")/.."
for f in 25 50 75; do
    .venv/bin/shapebench sweep "configs/sweeps/crop-$f.yaml" -q
done
for f in 0.25 0.5 0.75; do
    .venv/bin/shapebench leaderboard -d synthetic --protocol crop --crop-fraction "$f"
done
