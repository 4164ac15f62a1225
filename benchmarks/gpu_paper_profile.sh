#!/usr/bin/env bash
# The `paper` profile on one GPU, in time boxes: what one epoch costs at the paper's scale, and
# the rows a training of EPOCHS epochs gives beside Gauss densification.
#
#   bash benchmarks/gpu_paper_profile.sh timing METHOD [TIMING_EPOCHS]
#   bash benchmarks/gpu_paper_profile.sh rows METHOD EPOCHS
#
# Both first prepare the synthetic benchmark at the paper profile (200 training shapes per
# category, 200k surface samples each; all CPU cores; cached, so the second call is quick).
# timing: TIMING_EPOCHS epochs (default 3) in 32-true, then in bf16-mixed, each in a workspace of
#   its own: the time per epoch in both precisions and their loss terms side by side.
# rows: EPOCHS epochs in 32-true (the paper trains 5000), the evaluation at every context size
#   on both splits (msc: with and without the post-encoder optimisation), Gauss densification on
#   the same context points, and the paired comparison (benchmarks/paired_vs_reference.py).
#
# Evaluation uses 2 test objects per category (the quick profile's 30 objects; the paper
# profile's 20 per category cost 10x the test time) through `-D test_per_category=2`, which is
# part of every key and of the rows' dataset config. Everything is written under
# $SHAPEBENCH_WORKSPACE (default .gpu/ws) and $SHAPEBENCH_CACHE_DIR (default .gpu/cache).
# For a CPU dry run, shrink the scale with EXTRA_OPTS (method options, e.g. "-O width=32") and
# EXTRA_DATA (dataset options, e.g. "-D train_per_category=1").
set -euo pipefail

usage="usage: gpu_paper_profile.sh timing METHOD [TIMING_EPOCHS] | rows METHOD EPOCHS"
mode=${1:?$usage}
method=${2:?$usage}
sb=${SHAPEBENCH:-shapebench}
py=${PYTHON:-python3}
root=$(pwd)
ws=${SHAPEBENCH_WORKSPACE:-$root/.gpu/ws}
export SHAPEBENCH_CACHE_DIR=${SHAPEBENCH_CACHE_DIR:-$root/.gpu/cache}
export SHAPEBENCH_PROFILE=paper  # paired_vs_reference.py reads the profile from here
export MLFLOW_ENABLE_ARTIFACTS_PROGRESS_BAR=false
data=(-d synthetic -D test_per_category=2 ${EXTRA_DATA:-})
opts=(${EXTRA_OPTS:-})

stamp() { echo "== $(date -u +%H:%M:%S) $*"; }
timed() {
    local t0=$SECONDS
    "$@"
    echo "   ($((SECONDS - t0)) s: $*)"
}

stamp "prepare"
timed $sb prepare "${data[@]}" -m "$method" ${opts[@]+"${opts[@]}"} -j "$(nproc)" -q

case $mode in
timing)
    epochs=${3:-3}
    for precision in 32-true bf16-mixed; do
        stamp "timing: $epochs epochs, $precision"
        timed $sb train -m "$method" "${data[@]}" ${opts[@]+"${opts[@]}"} --max-epochs "$epochs" \
            --precision "$precision" --retrain --workspace "$ws-timing-$precision"
    done
    ;;
rows)
    epochs=${3:?$usage}
    stamp "training: $epochs epochs, 32-true"
    timed $sb train -m "$method" "${data[@]}" ${opts[@]+"${opts[@]}"} --max-epochs "$epochs" --retrain \
        --workspace "$ws"
    stamp "evaluation"
    rows=("$method")
    [ "$method" = msc ] && rows+=(msc-noopt)
    for row in "${rows[@]}"; do
        timed $sb run -m "$row" "${data[@]}" ${opts[@]+"${opts[@]}"} --max-epochs "$epochs" -q --workspace "$ws"
    done
    timed $sb run -m gauss "${data[@]}" -q --workspace "$ws"
    stamp "paired against gauss"
    for split in trained novel; do
        $py benchmarks/paired_vs_reference.py -d synthetic --split "$split" \
            --reference "gauss[profile=paper]" --workspace "$ws"
    done
    ;;
*)
    echo "$usage" >&2
    exit 2
    ;;
esac
stamp "done"
