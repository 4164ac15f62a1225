"""Reference checkpoints: trainings shipped with shapebench, used instead of training locally.

A trainable method's checkpoint is keyed by everything that changes its weights
(:func:`shapebench.train.ticket.checkpoint_key`: options, code, training data, epochs, precision,
devices, seed). For the built-in synthetic benchmark at the default (standard) and quick profiles,
shapebench ships the checkpoints its maintainers trained with ``scripts/reference_checkpoints.py``,
one folder per key::

    shapebench/reference_checkpoints/<family>/<key>/model.ckpt       weights (no optimiser state)
    shapebench/reference_checkpoints/<family>/<key>/reference.json   how it was made

``reference.json`` records the key, the exact ``shapebench train`` command, the package versions,
the machine, the wall time, the final loss terms and how the weights are stored: as trained
(``float32``) or rounded to half precision (``float16``, for a network whose file would exceed
the :data:`MAX_BYTES` a shipped file may take; installing turns them back into float32, so the
installed weights are the rounded ones, and the file's digest says so).

When ``run`` or ``sweep`` needs the checkpoint of a key that has a reference folder, the
reference is copied into the workspace (and logged as a training run tagged
``shapebench.reference``) instead of training; a key with no reference folder (other options,
edited code, another dataset or seed) trains as before.
``--retrain`` trains locally even when a reference exists.

Weights trained on another machine differ from a local training of the same key (floating-point
results depend on the hardware), so the origin of the weights is part of a cell's key and of its
leaderboard row: ``reference:<sha256 of the file>``, or nothing for a local training.
``$SHAPEBENCH_REFERENCE_CHECKPOINTS`` names another reference folder (``none`` turns them off).
"""

from __future__ import annotations

import functools
import hashlib
import json
import os
import shutil
from dataclasses import dataclass
from pathlib import Path
from typing import Any

ENV = "SHAPEBENCH_REFERENCE_CHECKPOINTS"
CHECKPOINT_FILE = "model.ckpt"
INFO_FILE = "reference.json"
#: Lightning's checkpoint entries a reference keeps: enough to rebuild and verify the module
#: (:func:`shapebench.train.checkpoints.build_module`), not to resume its training.
KEPT_ENTRIES = ("state_dict", "hyper_parameters", "shapebench", "pytorch-lightning_version")
#: How a reference's floating-point weights may be stored (``reference.json``'s ``storage``).
STORAGES = ("float32", "float16")
#: The largest file shapebench ships (the package and the repository stay small).
MAX_BYTES = 5_000_000


@dataclass(frozen=True)
class Reference:
    """One shipped checkpoint: its folder, file, description and the file's digest."""

    folder: Path
    info: dict[str, Any]

    @property
    def checkpoint(self) -> Path:
        return self.folder / CHECKPOINT_FILE

    @property
    def origin(self) -> str:
        """What cell keys and leaderboard rows record about these weights."""
        return f"reference:{self.info['sha256'][:16]}"


#: The references shipped inside the package.
SHIPPED = Path(__file__).resolve().parents[1] / "reference_checkpoints"


def root() -> Path | None:
    """The folder of reference checkpoints: ``$SHAPEBENCH_REFERENCE_CHECKPOINTS``, else the one
    inside the package; None when the variable says ``none``."""
    given = os.environ.get(ENV, "").strip()
    if given.lower() == "none":
        return None
    return Path(given) if given else SHIPPED


def find(family: str, key: str) -> Reference | None:
    """The reference checkpoint of ``family`` (a method's checkpoint family) for ``key``."""
    base = root()
    if base is None:
        return None
    folder = base / family / key
    try:
        info = json.loads((folder / INFO_FILE).read_text())
    except (OSError, ValueError):
        return None
    if not isinstance(info, dict) or info.get("key") != key or "sha256" not in info:
        return None
    if not (folder / CHECKPOINT_FILE).is_file():
        return None
    return Reference(folder, info)


def with_digest(sha256: str) -> Reference | None:
    """The shipped reference whose file has this digest (a checkpoint given by path that is a
    shipped reference, or a copy of one), if any."""
    base = root()
    if base is None:
        return None
    for info_file in sorted(base.glob(f"*/*/{INFO_FILE}")):
        ref = find(info_file.parent.parent.name, info_file.parent.name)
        if ref is not None and ref.info["sha256"] == sha256:
            return ref
    return None


@dataclass(frozen=True)
class GivenCheckpoint:
    """A checkpoint named by path (``run --checkpoint``): what keys and rows record about it."""

    #: The first 16 hex digits of the file's sha256: its identity in cell and row keys, so a
    #: copy elsewhere (a fresh clone, another machine) has the same keys and an edited file not.
    digest: str
    #: How rows name it: the shipped reference it is (``family/key``), else its file name.
    name: str


def given_checkpoint(path: str | Path) -> GivenCheckpoint:
    """The identity of the checkpoint file at ``path``."""
    file = Path(path).resolve()
    st = file.stat()
    sha256 = _file_sha256_cached(str(file), st.st_size, st.st_mtime_ns)
    ref = with_digest(sha256)
    name = f"{ref.folder.parent.name}/{ref.folder.name}" if ref is not None else file.name
    return GivenCheckpoint(sha256[:16], name)


@functools.lru_cache(maxsize=32)
def _file_sha256_cached(path: str, size: int, mtime_ns: int) -> str:
    # size and mtime in the arguments: a file rewritten in place is read again
    return file_sha256(Path(path))


def file_sha256(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def install(ref: Reference, workdir: Path) -> Path:
    """Copy ``ref``'s weights into a workspace's checkpoint folder, after checking that the file
    is the one described (digest) and holds its key; returns the copied file."""
    from shapebench.api.errors import ShapebenchError
    from shapebench.train.checkpoints import verify_checkpoint

    digest = file_sha256(ref.checkpoint)
    if digest != ref.info["sha256"]:
        raise ShapebenchError(
            f"reference checkpoint {ref.checkpoint} does not match its {INFO_FILE} "
            f"(sha256 {digest[:16]}, expected {ref.info['sha256'][:16]})",
            "reinstall shapebench, or pass --retrain to train this method locally",
        )
    verify_checkpoint(ref.checkpoint, ref.info["key"])
    workdir.mkdir(parents=True, exist_ok=True)
    target = workdir / CHECKPOINT_FILE
    tmp = target.with_name(target.name + ".tmp")
    if ref.info.get("storage", "float32") == "float16":
        import torch

        from shapebench.train.checkpoints import load_safely

        checkpoint = load_safely(ref.checkpoint)
        torch.save(_cast(checkpoint, "float16", "float32"), tmp)
    else:
        shutil.copyfile(ref.checkpoint, tmp)
    tmp.replace(target)
    return target


def _cast(checkpoint: dict[str, Any], from_dtype: str, to_dtype: str) -> dict[str, Any]:
    """``checkpoint`` with its ``from_dtype`` weights cast to ``to_dtype`` (the rest as is)."""
    import torch

    old, new = getattr(torch, from_dtype), getattr(torch, to_dtype)
    state = {
        name: value.to(new) if torch.is_tensor(value) and value.dtype == old else value
        for name, value in checkpoint["state_dict"].items()
    }
    return {**checkpoint, "state_dict": state}


def export(
    last_ckpt: Path, folder: Path, info: dict[str, Any], storage: str = "float32"
) -> Reference:
    """Write a reference folder from a finished training's ``last.ckpt``: the weights without
    the optimiser and loop state (``storage="float16"``: float32 weights rounded to half
    precision), and ``info`` completed with the storage and the file's digest."""
    import torch

    from shapebench.train.checkpoints import load_safely

    if storage not in STORAGES:
        raise ValueError(f"storage {storage!r} is not one of {', '.join(STORAGES)}")
    checkpoint = load_safely(last_ckpt)
    kept = {k: checkpoint[k] for k in KEPT_ENTRIES if k in checkpoint}
    if storage == "float16":
        kept = _cast(kept, "float32", "float16")
    folder.mkdir(parents=True, exist_ok=True)
    torch.save(kept, folder / CHECKPOINT_FILE)
    info = {
        **info,
        "storage": storage,
        "sha256": file_sha256(folder / CHECKPOINT_FILE),
        "bytes": (folder / CHECKPOINT_FILE).stat().st_size,
    }
    (folder / INFO_FILE).write_text(json.dumps(info, indent=1, sort_keys=True) + "\n")
    return Reference(folder, info)
