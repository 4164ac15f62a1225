#!/usr/bin/env bash
# configs/sweeps/data-scaling.yaml on a 2-core CPU, in parts across sessions of a few hours.
#
# The whole cross is about a day of CPU (the 16x budgets alone 16 hours), so it runs a part at a
# time (`shapebench sweep ... -m msc,msc-noopt`), and what a session computed travels in git
# between sessions: the workspace's MLflow store and per-object tables (no meshes, pictures or
# finished checkpoints: a training whose cells are all finished is not needed again), and the
# resumable checkpoint of a training that was still running when the session ended.
#
#   bash benchmarks/cpu_data_scaling.sh unpack     # the committed part -> $WS (before resuming)
#   SHAPEBENCH_WORKSPACE=$WS shapebench sweep configs/sweeps/data-scaling.yaml -m msc,msc-noopt
#   bash benchmarks/cpu_data_scaling.sh pack       # after it ends, or after Ctrl-C
#   SHAPEBENCH_WORKSPACE=$WS shapebench leaderboard -d synthetic --split validation \
#       --out leaderboards/data-scaling/cpu
#
# WS is /tmp/S/ws: the store records its artifacts' absolute paths, so it unpacks where it was
# made. The archive is leaderboards/data-scaling/cpu/workspace.tar.xz. Another store carries the
# same way with both set, e.g. the standard profile's trainings:
#   WS=/tmp/S/ws2 ARCHIVE=leaderboards/standard/workspace.tar.xz bash benchmarks/cpu_data_scaling.sh pack
set -euo pipefail
cd "$(dirname "$0")/.."
ws=${WS:-/tmp/S/ws}
archive=$(realpath -m "${ARCHIVE:-leaderboards/data-scaling/cpu/workspace.tar.xz}")

case "${1:-}" in
unpack)
    if [ -e "$ws/mlflow.db" ]; then
        echo "$ws already holds a store; move it away first" >&2
        exit 1
    fi
    mkdir -p "$ws"
    tar -xJf "$archive" -C "$ws"
    echo "unpacked into $ws: $(find "$ws/checkpoints" -name last.ckpt | wc -l) unfinished training(s)"
    ;;
pack)
    mkdir -p "$(dirname "$archive")"
    cd "$ws"
    # Checkpoints of unfinished trainings only (no done.json beside them), each at most
    # MAX_CKPT_MB (default 20) so git does not carry a large network's optimiser state: a larger
    # one is left out, and that training starts again from step 0 in the next session.
    unfinished=()
    max_mb=${MAX_CKPT_MB:-20}
    while IFS= read -r ckpt; do
        dir=$(dirname "$ckpt")
        [ -e "$dir/done.json" ] && continue
        mb=$(( $(stat -c %s "$ckpt") / 1048576 ))
        if [ "$mb" -gt "$max_mb" ]; then
            echo "left out $dir: its checkpoint is $mb MB (MAX_CKPT_MB=$max_mb); it retrains from step 0"
            continue
        fi
        unfinished+=("$dir")
    done < <(find checkpoints -name last.ckpt 2>/dev/null)
    list=$(mktemp)
    trap 'rm -f "$list"' EXIT
    find artifacts -name per_object.csv -o -name '*.json' -o -name '*.txt' >"$list"
    tar -cJf "$archive" mlflow.db -T "$list" "${unfinished[@]}"
    echo "packed $(du -h "$archive" | cut -f1) into $archive (unfinished trainings: ${#unfinished[@]})"
    ;;
*)
    echo "usage: bash benchmarks/cpu_data_scaling.sh unpack|pack   (WS=$ws)" >&2
    exit 2
    ;;
esac
