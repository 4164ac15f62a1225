#!/usr/bin/env bash
# The data-scaling sweep (configs/sweeps/data-scaling.yaml) on one lent GPU machine, in one time
# box, with what it finished packed for `shapebench merge` on another machine.
#
#   bash benchmarks/gpu_data_scaling.sh [SECONDS]          # default 480: the whole script's box
#
# 1. Installs carried wheels (.whl/, see benchmarks/README.md) when the machine lacks packages,
#    and puts the tree on PYTHONPATH ahead of them; .gpu/dist holds shapebench's dist-info (its
#    entry points) so that the plugins are found as on an installed machine.
# 2. Prepares the 2,200-shape training split and the test objects on every core, while
#    benchmarks/bench_training.py measures each method's step on the idle GPU (--device cuda).
# 3. Runs the sweep with --launcher local, one worker per (method entry, dataset) pair so that
#    every training starts at once, until the box is nearly spent, then stops it as Ctrl-C does:
#    finished cells and trainings stay, an interrupted training keeps its checkpoint. Entries
#    whose step budget is over MAX_STEPS (default 10,800: the 16x budgets cannot finish in a box
#    of minutes) are left out. The cells are the sweep file's: a cell's key does not depend on
#    the file that asked for it.
# 4. Prints the sweep's --status and the trainings' step times, and writes to $OUT (default
#    .gpu/out) the workspace without checkpoints, completion meshes or pictures (ws-meta.tgz.*: MLflow
#    store, per-object tables, logs) and the checkpoints of IGR, DeepSDF and MSC (ws-ckpt.tgz.*)
#    and, where room is left, OccNet's; each split into 15 MB parts.
#
# Locally: cat ws-meta.tgz.* | tar xz -C DIR; shapebench merge DIR/mlflow.db (docs/cluster.md).
# SWEEP= runs another sweep file and TRAIN_PER_CATEGORY= prepares another training split (a CPU
# dry run: a small one of each; SKIP_WHEELS=1 PYTHON=.venv/bin/python).
set -uo pipefail

box=${1:-480}
t0=$SECONDS
out=${OUT:-$PWD/.gpu/out}
mkdir -p "$out"
export SHAPEBENCH_WORKSPACE=${SHAPEBENCH_WORKSPACE:-/tmp/gpu-ws}
export SHAPEBENCH_CACHE_DIR=${SHAPEBENCH_CACHE_DIR:-/tmp/gpu-cache}
export MLFLOW_ENABLE_ARTIFACTS_PROGRESS_BAR=false PYTHONUNBUFFERED=1
sweep=${SWEEP:-configs/sweeps/data-scaling.yaml}
pairs=/tmp/sweep-pairs.yaml
py=${PYTHON:-python3}
stamp() { echo "== $(date -u +%H:%M:%S) +$((SECONDS - t0)) s: $*"; }

source benchmarks/gpu_machine.sh

stamp "prepare ($(nproc) workers) while the bench times each method's step on the idle GPU"
$py benchmarks/bench_training.py --device cuda --steps 60 --warmup 10 --rounds 1 \
    >/tmp/bench-gpu.txt 2>&1 &
bench=$!
$py -m shapebench prepare -d synthetic -D train_per_category="${TRAIN_PER_CATEGORY:-200}" \
    -m igr -m deepsdf -m msc -m occnet -m pcn -j "$(nproc)" -q 2>&1 | tail -3
$py -m shapebench prepare -d synthetic -m igr -m deepsdf -m msc -m occnet -m pcn \
    --split validation,trained,novel -j "$(nproc)" -q 2>&1 | tail -3
for _ in $(seq 45); do # the bench has the GPU to itself for at most 45 s more
    kill -0 $bench 2>/dev/null || break
    sleep 1
done
kill $bench 2>/dev/null
cat /tmp/bench-gpu.txt

$py benchmarks/sweep_pairs.py "$sweep" --max-steps "${MAX_STEPS:-10800}" --out "$pairs" || exit 1
jobs=$($py -c "import sys, yaml; print(len(yaml.safe_load(open(sys.argv[1]))['methods']))" "$pairs")
left=$((box - (SECONDS - t0) - 75))
stamp "sweep: $jobs workers for at most $left s"
timeout -s INT -k 60 "$left" $py -m shapebench sweep "$pairs" --launcher local -j "$jobs" -q \
    2>&1 | tail -15

stamp "packing"
$py -m shapebench sweep "$pairs" --status 2>&1 | tail -45
grep -h "training plan\|per optimiser step" "$SHAPEBENCH_WORKSPACE"/logs/*.log | sort -u | head -40
pack() { # pack NAME TAR-ARGS...: $out/NAME.tgz.NN, 15 MB parts
    local name=$1
    shift
    tar -C "$SHAPEBENCH_WORKSPACE" -czf "/tmp/$name.tgz" "$@"
    split -b 15m -d "/tmp/$name.tgz" "$out/$name.tgz."
    ls -l "$out/$name.tgz."*
}
pack ws-meta --exclude='*.ckpt' --exclude='*.ply' --exclude='*.png' .
(
    cd "$SHAPEBENCH_WORKSPACE" || exit 1
    find checkpoints -name '*.ckpt' -path '*/igr/*' >/tmp/ckpts
    find checkpoints -name '*.ckpt' -path '*/deepsdf/*' >>/tmp/ckpts
    find checkpoints -name '*.ckpt' -path '*/msc/*' >>/tmp/ckpts
    find checkpoints -name '*.ckpt' -path '*/occnet/*' >/tmp/ckpts-occnet
)
pack ws-ckpt -T /tmp/ckpts
# $OUT takes 64 MB: OccNet's checkpoints (6 MB each, optimiser state included) where room is left.
occnet_mb=$(cd "$SHAPEBENCH_WORKSPACE" && xargs -r -a /tmp/ckpts-occnet du -cm | tail -1 | cut -f1)
if [ "$(($(du -sm "$out" | cut -f1) + ${occnet_mb:-0}))" -lt 58 ]; then
    pack ws-ckpt-occnet -T /tmp/ckpts-occnet
fi
stamp "done"
