#!/usr/bin/env bash
# Create (or update) the project's virtual environment and install shapebench into it.
#
# Every other dependency is installed at the version constraints.txt pins (scripts/lock.sh
# refreshes it), so two installs of one commit resolve the same versions; SHAPEBENCH_UNLOCKED=1
# installs the newest versions pyproject.toml allows instead.
#
# torch is kept at whatever version the environment already has: a GPU user installs the torch
# build for their platform first, and this script pins it with a constraints file so that no
# dependency can replace it (an unpinned torch would pull a newer release with CUDA wheels).
# Without torch, the CPU build torch==2.13.0 is installed.
#
#   bash scripts/setup.sh             # shapebench, its dependencies and the test extras (CI's)
#   bash scripts/setup.sh --runtime   # without the test extras (pytest, linters, docs site):
#                                     # what running shapebench needs; scripts/quickstart.sh
set -euo pipefail
cd "$(dirname "$0")/.."
EXTRAS="[test]"
case "${1:-}" in
    "") ;;
    --runtime) EXTRAS="" ;;
    *) echo "usage: bash scripts/setup.sh [--runtime]" >&2; exit 2 ;;
esac
VENV="${SHAPEBENCH_VENV:-.venv}"
PY="${PYTHON:-python3}"

if [ ! -x "$VENV/bin/python" ]; then
  echo "[setup] creating virtual environment $VENV"
  "$PY" -m venv "$VENV"
fi
pip_() { "$VENV/bin/python" -m pip --disable-pip-version-check "$@"; }

if ! "$VENV/bin/python" -c "import torch" 2>/dev/null; then
  echo "[setup] no torch in $VENV: installing the CPU build torch==2.13.0"
  pip_ install -q "torch==2.13.0"
fi
CONSTRAINTS="$VENV/shapebench-constraints.txt"
# Read without importing torch: a fresh environment has no numpy yet, and torch's import then
# warns "Failed to initialize NumPy".
"$VENV/bin/python" - > "$CONSTRAINTS" <<'PY'
from importlib.metadata import version
print(f"torch=={version('torch')}")
PY
echo "[setup] keeping $(cat "$CONSTRAINTS")"
LOCK=(-c constraints.txt)
if [ "${SHAPEBENCH_UNLOCKED:-0}" = 1 ]; then
  LOCK=()
  echo "[setup] SHAPEBENCH_UNLOCKED=1: newest versions allowed by pyproject.toml, not constraints.txt"
fi
pip_ install -q -c "$CONSTRAINTS" "${LOCK[@]}" -e ".$EXTRAS"
echo "[setup] done: activate with 'source $VENV/bin/activate'"
