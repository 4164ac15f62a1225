#!/usr/bin/env bash
# System packages the test suite drives for real, installed from Debian when missing:
#   chromium          the browser tests (MLflow UI, HTML report) through playwright
#   slurm-wlm, munge  a one-node SLURM cluster on 127.0.0.1 for the --launcher slurm test
# Measured on the CI machine (2 cores): slurm-wlm + munge 13 s, chromium 25 s.
set -euo pipefail
need=()
command -v chromium >/dev/null || need+=(chromium)
command -v slurmctld >/dev/null || need+=(slurm-wlm)
command -v munged >/dev/null || need+=(munge)
if [ ${#need[@]} -eq 0 ]; then
  echo "[system] chromium, slurm-wlm and munge are installed"
  exit 0
fi
if [ "$(id -u)" != 0 ] && ! command -v sudo >/dev/null; then
  echo "[system] cannot install ${need[*]} (not root, no sudo): their tests will skip" >&2
  exit 0
fi
SUDO=""; [ "$(id -u)" = 0 ] || SUDO="sudo"
echo "[system] installing ${need[*]}"
$SUDO apt-get update -qq
DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq "${need[@]}" >/dev/null
