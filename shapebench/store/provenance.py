"""Where a result came from, for run tags: the code version (:func:`git_commit`), and the
process and machine that computed it (:func:`run_context_tags`: user, command line, library
versions, host, torch threads), on every run shapebench starts."""

from __future__ import annotations

import functools
import os
import subprocess
from pathlib import Path
from typing import Any

from shapebench.store import records as rec


@functools.lru_cache(maxsize=1)
def git_commit() -> str:
    """The commit of the shapebench source tree (``-dirty`` if modified), or ``unknown``."""
    src = Path(__file__).resolve().parents[2]
    try:
        sha = subprocess.run(
            ["git", "-C", str(src), "rev-parse", "HEAD"], capture_output=True, text=True, timeout=5
        )
        if sha.returncode != 0:
            return "unknown"
        dirty = subprocess.run(
            ["git", "-C", str(src), "status", "--porcelain", "--untracked-files=no"],
            capture_output=True,
            text=True,
            timeout=5,
        )
        return sha.stdout.strip() + ("-dirty" if dirty.stdout.strip() else "")
    except (OSError, subprocess.SubprocessError):
        return "unknown"


def run_context_tags() -> dict[str, str]:
    """MLflow's standard tags and this process's provenance, on every run shapebench starts:
    the torch thread count and CPU kernels too once torch is loaded (they decide whether two
    computations of a cell agree bitwise or to the key's tolerance)."""
    import sys

    tags = dict(_process_tags())
    torch = sys.modules.get("torch")
    if torch is not None and hasattr(torch, "get_num_threads"):
        tags[rec.HOST_TORCH_THREADS_TAG] = str(torch.get_num_threads())
        capability = getattr(getattr(torch.backends, "cpu", None), "get_cpu_capability", None)
        if capability is not None:
            tags[rec.HOST_TORCH_CPU_CAPABILITY_TAG] = str(capability())
    return tags


@functools.lru_cache(maxsize=1)
def _process_tags() -> dict[str, str]:
    """The tags of :func:`run_context_tags` that cannot change while the process runs."""
    import getpass
    import platform
    import sys

    from shapebench import __version__

    commit = git_commit()
    tags = {
        rec.USER_TAG: _safe(getpass.getuser),
        rec.SOURCE_TYPE_TAG: "LOCAL",
        rec.SOURCE_NAME_TAG: " ".join(["shapebench", *sys.argv[1:]])[:500],
        rec.SHAPEBENCH_VERSION_TAG: __version__,
        rec.VERSIONS_PREFIX + "python": platform.python_version(),
        rec.HOST_PLATFORM_TAG: platform.platform(),
        rec.HOST_CPUS_TAG: str(os.cpu_count() or 0),
    }
    if commit != "unknown":
        tags[rec.GIT_COMMIT_TAG] = commit.removesuffix("-dirty")
        tags[rec.GIT_DIRTY_TAG] = str(commit.endswith("-dirty"))
    # Versions from the installed metadata: importing torch here would cost seconds per command.
    for dist in ("mlflow", "numpy", "torch", "pytorch-lightning", "trimesh"):
        version = _dist_version(dist)
        if version:
            tags[rec.VERSIONS_PREFIX + dist] = version
    cpu = _cpu_model()
    if cpu:
        tags[rec.HOST_CPU_TAG] = cpu
    memory = _memory_gb()
    if memory:
        tags[rec.HOST_MEMORY_TAG] = f"{memory:.0f}"
    gpus = _gpu_names()
    if gpus:
        tags[rec.HOST_GPUS_TAG] = gpus
    return tags


def _safe(fn: Any) -> str:
    try:
        return str(fn())
    except Exception:  # no user name in a container without passwd entry: not worth failing
        return "unknown"


def _dist_version(dist: str) -> str:
    from importlib import metadata

    try:
        return metadata.version(dist)
    except metadata.PackageNotFoundError:
        return ""


def _cpu_model() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    import platform

    return platform.processor()


def _memory_gb() -> float:
    try:
        return os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES") / 2**30
    except (ValueError, OSError, AttributeError):
        return 0.0


def _gpu_names() -> str:
    """The GPUs of this machine, from the NVIDIA driver's files (no CUDA initialisation)."""
    names = []
    for info in sorted(Path("/proc/driver/nvidia/gpus").glob("*/information")):
        try:
            for line in info.read_text().splitlines():
                if line.startswith("Model:"):
                    names.append(line.split(":", 1)[1].strip())
        except OSError:
            continue
    return ", ".join(names)
