#!/usr/bin/env bash
# What a lent GPU machine needs from here, made before the device call (run here, not there).
#
#   bash benchmarks/gpu_carry.sh fetch     # .whl/ and .gpu/dist/, then the carry's size
#   bash benchmarks/gpu_carry.sh aside     # shipped references out of the tree for the call
#   bash benchmarks/gpu_carry.sh back      # ... and back (git checkout)
#   bash benchmarks/gpu_carry.sh size      # what the call would carry, against its 64 MiB
#
# fetch: the GPU image (Python 3.12, torch, Lightning, numpy, pandas, scikit-image, ...) lacks the
# packages of WHEELS below; their cp312 manylinux wheels are downloaded at the versions .venv
# holds (so the machine runs what the tests here ran), and .gpu/dist/ gets shapebench's dist-info
# (its entry points, which find the built-in plugins on PYTHONPATH). Both are listed in
# .git/info/exclude and named in the call's `carry`: [".whl", ".gpu"].
# The MLflow server (`mlflow`, 12 MB of web UI) stays behind: `mlflow-skinny` is the client, and
# its sqlite store works (checked here with the skinny wheel alone on the path). embreex must
# travel: without it every object's preparation casts its rays about 1,000 times slower.
# aside: the tracked tree is 44 MB, 31 MB of it shipped references that trainings with --retrain
# never read; with them in the tree the wheels do not fit the 64 MiB a call carries.
set -euo pipefail
cd "$(dirname "$0")/.."

# Names as pip lists them in .venv; the versions come from there.
WHEELS="alembic annotated-types blinker cachetools cffi databricks-sdk embreex fastapi Flask
flask-cors gitdb GitPython google-auth graphene graphql-core graphql-relay importlib_metadata
itsdangerous Mako manifold3d mlflow-skinny mlflow-tracing opentelemetry-api opentelemetry-proto
opentelemetry-sdk opentelemetry-semantic-conventions prettytable pyasn1 pyasn1_modules pycparser
pydantic pydantic_core pykdtree python-dotenv rtree smmap SQLAlchemy sqlparse starlette submitit
trimesh typing-inspection uvicorn wcwidth"
LIMIT=$((64 * 1024 * 1024))
refs=shapebench/reference_checkpoints

size() {
    local tree extra
    # files deleted from the working tree (aside) do not travel; du skips them
    tree=$( (git ls-files -z | xargs -0 du -cb 2>/dev/null || true) | tail -1 | cut -f1)
    extra=$(git ls-files -z --others --exclude-standard | xargs -0 -r du -cb | tail -1 | cut -f1)
    local carried
    carried=$(du -cb .whl .gpu 2>/dev/null | tail -1 | cut -f1)
    local total=$((tree + ${extra:-0} + ${carried:-0}))
    echo "carry: tree $((tree / 1000000)) MB, untracked $((${extra:-0} / 1000000)) MB," \
        ".whl + .gpu $((${carried:-0} / 1000000)) MB: $((total / 1000000)) of" \
        "$((LIMIT / 1000000)) MB"
    [ "$total" -le "$LIMIT" ] || echo "over the limit: bash benchmarks/gpu_carry.sh aside" >&2
}

case ${1:-} in
fetch)
    grep -qx "/.whl/" .git/info/exclude 2>/dev/null || echo "/.whl/" >>.git/info/exclude
    grep -qx "/.gpu/" .git/info/exclude 2>/dev/null || echo "/.gpu/" >>.git/info/exclude
    mkdir -p .whl
    freeze=$(.venv/bin/python -m pip list --format=freeze)
    for name in $WHEELS; do
        pin=$(grep -i "^${name}==" <<<"$freeze" || true)
        [ -n "$pin" ] || { echo "$name is not in .venv: skipped" >&2; continue; }
        python3 -m pip download -q --no-deps --only-binary=:all: --python-version 3.12 \
            --implementation cp --platform manylinux_2_28_x86_64 --platform manylinux_2_27_x86_64 \
            --platform manylinux_2_24_x86_64 --platform manylinux_2_17_x86_64 \
            --platform manylinux2014_x86_64 --platform manylinux1_x86_64 -d .whl "$pin"
    done
    site=$(.venv/bin/python -c "import sysconfig; print(sysconfig.get_paths()['purelib'])")
    rm -rf .gpu/dist && mkdir -p .gpu/dist
    cp -r "$site"/shapebench-*.dist-info .gpu/dist/
    rm -f .gpu/dist/shapebench-*.dist-info/{RECORD,direct_url.json}
    echo "$(find .whl -name '*.whl' | wc -l) wheels in .whl/"
    size
    ;;
aside)
    [ -d "$refs" ] || { echo "$refs is already aside" >&2; exit 1; }
    if [ -n "$(git status --porcelain -- "$refs")" ]; then
        echo "$refs has uncommitted changes: commit them first (back restores the commit)" >&2
        exit 1
    fi
    rm -rf "$refs" && size
    echo "after the call: bash benchmarks/gpu_carry.sh back (then tar xzf the call's refs.tgz)"
    ;;
back) git checkout -- "$refs" && git status --short "$refs" ;;
size) size ;;
*)
    sed -n '2,8p' "$0"
    exit 2
    ;;
esac
