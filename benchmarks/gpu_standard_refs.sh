#!/usr/bin/env bash
# The `standard` profile's reference trainings on one lent GPU machine, in one time box: the
# seeds a 2-core CPU has not trained yet and larger step budgets (issue 27 sections 4 and 5), all
# at once, exported as shipped references (weights only, under 5 MB each) to $OUT.
#
#   COMMIT=$(git rev-parse HEAD) bash benchmarks/gpu_standard_refs.sh [SECONDS]   # default 380
#
# 1. Installs carried wheels (.whl/, benchmarks/README.md "gpu_data_scaling.sh") and puts the
#    tree and .gpu/dist (shapebench's entry points) on PYTHONPATH, as gpu_data_scaling.sh does.
# 2. Prepares the training split of every method of JOBS on every core.
# 3. Starts every training of JOBS at once (`shapebench train ... --accelerator gpu --devices 1
#    --retrain`, one CPU thread each), and at SECONDS stops those still running as Ctrl-C does:
#    an interrupted training keeps its last checkpoint.
# 4. Exports each finished training with scripts/reference_checkpoints.py --export-only
#    (float16 storage for PCN, ConvONet and PoinTr, as their CPU-trained references) into the
#    tree's shapebench/reference_checkpoints/, and writes to $OUT: refs.tgz (the new reference
#    folders), ckpt.tgz.NN (the resumable checkpoints of unfinished trainings, in JOBS order,
#    while $OUT's 64 MB allow; 15 MB parts) and log.txt (plans, step times, summaries).
#
# Locally: tar xzf refs.tgz (from the repository root); an unfinished training resumes on the CPU
# with `cat ckpt.tgz.* | tar xz -C WORKSPACE`, then the same `shapebench train` command.
# The checkpoint key leaves the accelerator out (a GPU-trained reference serves CPU runs); each
# reference.json records the machine, versions and wall time, and its note the commit (the copy
# of the tree there has no .git, so the training records none).
# CPU dry run: SKIP_WHEELS=1 PYTHON=.venv/bin/python PROFILE=quick ACCEL=cpu \
#   JOBS="msc 2 steps=2;pcn 2 steps=2" bash benchmarks/gpu_standard_refs.sh 120
set -uo pipefail

box=${1:-380}
t0=$SECONDS
out=${OUT:-$PWD/.gpu/out}
mkdir -p "$out"
ws=${SHAPEBENCH_WORKSPACE:-/tmp/gpu-ws}
export SHAPEBENCH_CACHE_DIR=${SHAPEBENCH_CACHE_DIR:-/tmp/gpu-cache}
export MLFLOW_ENABLE_ARTIFACTS_PROGRESS_BAR=false PYTHONUNBUFFERED=1
profile=${PROFILE:-standard}
accel=${ACCEL:-gpu}
commit=${COMMIT:-unknown}
py=${PYTHON:-python3}
log=$out/log.txt
# "method seed [KEY=VALUE ...]" per training, ';'-separated, in the order of importance
# (what is packed first when room runs out). The 4x budgets are the longest: they start first.
jobs_default="pcn 0 steps=14400;occnet 0 steps=14400"
jobs_default+=";msc 2;occnet 2;convonet 2;pcn 2;igr 2;deepsdf 2;pcn 1;igr 1;deepsdf 1"
jobs_default+=";msc-hier 0;msc-hier 1;msc-hier 2;pointr 0;pointr 1;pointr 2"
IFS=';' read -ra jobs <<<"${JOBS:-$jobs_default}"
stamp() { echo "== $(date -u +%H:%M:%S) +$((SECONDS - t0)) s: $*"; }
exec > >(tee -a "$log") 2>&1 # everything printed is in log.txt too

source benchmarks/gpu_machine.sh

methods=()
for job in "${jobs[@]}"; do
    read -r name _ <<<"$job"
    methods+=(-m "$name")
done
stamp "prepare the training split on $(nproc) workers"
$py -m shapebench prepare -d synthetic --profile "$profile" "${methods[@]}" --split validation \
    -j "$(nproc)" -q 2>&1 | tail -3

pids=()
for i in "${!jobs[@]}"; do
    read -r name seed opts <<<"${jobs[$i]}"
    args=(-m "$name" -d synthetic --profile "$profile" --seed "$seed" --devices 1
        --accelerator "$accel" --retrain -q --workspace "$ws" --checkpoint-every-epochs 5)
    for o in $opts; do args+=(-O "$o"); done
    OMP_NUM_THREADS=1 MKL_NUM_THREADS=1 $py -m shapebench train "${args[@]}" \
        >"/tmp/train-$i.log" 2>&1 &
    pids+=($!)
done
stamp "${#jobs[@]} trainings started; box ends at +$box s"
while [ $((SECONDS - t0)) -lt "$box" ]; do
    running=0
    for pid in "${pids[@]}"; do kill -0 "$pid" 2>/dev/null && running=$((running + 1)); done
    [ "$running" -eq 0 ] && break
    sleep 5
done
for pid in "${pids[@]}"; do kill -INT "$pid" 2>/dev/null; done
for pid in "${pids[@]}"; do wait "$pid"; done
stamp "trainings ended"

note="trained on $(nvidia-smi --query-gpu=name --format=csv,noheader 2>/dev/null | head -1) by \
benchmarks/gpu_standard_refs.sh ($((${#jobs[@]})) trainings sharing the GPU, one CPU thread each) \
from a copy of the tree at commit $commit (the copy has no .git: trained_at reads unknown)"
before=$(mktemp)
find shapebench/reference_checkpoints -mindepth 2 -maxdepth 2 -type d | sort >"$before"
: >/tmp/unfinished
exports=()
for i in "${!jobs[@]}"; do # the exports run at once: each writes a folder of its own
    read -r name seed opts <<<"${jobs[$i]}"
    storage=float32
    case $name in pcn | convonet | pointr) storage=float16 ;; esac
    export_args=(--profile "$profile" --methods "$name" --seeds "$seed" --workspace "$ws"
        --export-only --allow-dirty --keep-stale --storage "$storage" --note "$note")
    for o in $opts; do export_args+=(-O "$o"); done
    $py scripts/reference_checkpoints.py "${export_args[@]}" >"/tmp/export-$i.log" 2>&1 &
    exports+=($!)
done
for pid in "${exports[@]}"; do wait "$pid"; done # not a bare wait: it would wait for the tee
for i in "${!jobs[@]}"; do
    read -r name seed opts <<<"${jobs[$i]}"
    {
        echo "--- $name seed $seed ${opts}"
        grep -h "Error\|error" "/tmp/train-$i.log" | head -3
        tail -2 "/tmp/train-$i.log"
        tail -3 "/tmp/export-$i.log"
    } >>"$log"
    grep -q "MB), trained in" "/tmp/export-$i.log" || echo "$i" >>/tmp/unfinished
done
find shapebench/reference_checkpoints -mindepth 2 -maxdepth 2 -type d | sort |
    comm -13 "$before" - >/tmp/new-refs
stamp "new references: $(wc -l </tmp/new-refs)"
tar -czf "$out/refs.tgz" -T /tmp/new-refs && ls -l "$out/refs.tgz"

# Unfinished trainings: their checkpoint folders, in JOBS order, as room allows.
: >/tmp/ckpt-dirs
room=$((58 - $(du -sm "$out" | cut -f1)))
while read -r i; do
    # the export named the folder it looked in: "M: no finished training of key K in DIR; skipped"
    dir=$(sed -n 's/.*no finished training of key \([0-9a-f]*\) in \(.*\); skipped$/\2\/\1/p' \
        "/tmp/export-$i.log")
    [ -n "$dir" ] && [ -d "$dir" ] || continue
    mb=$(du -sm "$dir" | cut -f1)
    [ "$mb" -lt "$room" ] || continue
    room=$((room - mb))
    realpath --relative-to="$ws" "$dir" >>/tmp/ckpt-dirs
done </tmp/unfinished
if [ -s /tmp/ckpt-dirs ]; then
    tar -C "$ws" -czf /tmp/ckpt.tgz -T /tmp/ckpt-dirs
    split -b 15m -d /tmp/ckpt.tgz "$out/ckpt.tgz."
    cat /tmp/ckpt-dirs >>"$log"
fi
ls -l "$out"
stamp "done"
