"""``shapebench export``: the exact contexts of a set of cells, as files a model anywhere can read.

The contexts are those every method of a run completes: :meth:`ContextStore.context
<shapebench.api.contexts.ContextStore.context>` draws them (the same stored orders, crops,
cameras and noise), so an exported context is bitwise the one a ``shapebench run`` of the same
dataset, protocol, size and seed hands to a method. Per context, below ``<out>/contexts/``:
``<split>/<category>/<object>/n<size>-s<seed>.npy`` (float32 ``(k, 3)``), the same points as an
ASCII ``.ply``, and with ``--context-normals`` ``...-normals.npy``; ``<out>/manifest.json``
describes them (:mod:`shapebench.exchange.manifest`). Every file is written whole from the
arrays alone (no time stamp, sorted keys, fixed number formats), so exporting twice gives
byte-identical files. The ground truth is not exported: it stays with the scorer.
"""

from __future__ import annotations

import os
import tempfile
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from shapebench.api.contexts import ContextStore
from shapebench.api.dataset import Dataset, ObjectLoadError
from shapebench.api.errors import ShapebenchError
from shapebench.api.protocol import Protocol
from shapebench.api.types import Context
from shapebench.exchange.manifest import (
    COMPLETIONS_DIR,
    CONTEXTS_DIR,
    MANIFEST,
    Entry,
    Manifest,
    entry_stem,
)
from shapebench.hashing import array_digest


@dataclass(frozen=True)
class ExportReport:
    """What an export wrote."""

    out: Path
    manifest: Manifest

    def summary(self) -> str:
        m = self.manifest
        objects = len({(e.split, e.object) for e in m.entries})
        line = (
            f"exported {len(m.entries)} contexts ({objects} objects of {m.dataset}/"
            f"{','.join(m.splits)}, sizes {','.join(map(str, m.contexts))}, seeds "
            f"{','.join(map(str, m.seeds))}, {m.protocol.name}) to {self.out}; completions go "
            f"to {self.out / COMPLETIONS_DIR} as {self.out / MANIFEST} says"
        )
        if m.failed:
            line += f"; {len(m.failed)} object(s) could not be loaded (listed in the manifest)"
        return line


def check_request(
    dataset: Dataset, protocol: Protocol, splits: list[str] | None, contexts: list[int]
) -> list[str]:
    """The splits to export, after refusing what a run would refuse: an unknown or empty
    split, no or non-positive sizes, crop or depth contexts without ground truth, normals the
    dataset does not have."""
    if not contexts or any(not isinstance(c, int) or c <= 0 for c in contexts):
        raise ShapebenchError(
            f"context sizes must be positive integers, got {contexts}",
            "e.g. --contexts 50,100,300,1000",
        )
    allowed = [*dataset.eval_splits, *dataset.validation_splits]
    splits = list(splits or dataset.eval_splits)
    unknown = [s for s in splits if s not in allowed]
    if unknown:
        raise ShapebenchError(
            f"dataset {dataset.name!r} has no evaluation split {', '.join(unknown)}",
            f"use one of: {', '.join(allowed)}",
        )
    if protocol.context in ("crop", "depth") and not dataset.has_ground_truth:
        raise ShapebenchError(
            f"{protocol.context} contexts are cut from the ground truth, and dataset "
            f"{dataset.name!r} has none",
            "use --protocol sparse",
        )
    if protocol.context_normals and not dataset.has_normals:
        raise ShapebenchError(
            f"dataset {dataset.name!r} has points without normals: --context-normals cannot be "
            "given",
            "drop --context-normals",
        )
    return splits


def export_contexts(
    dataset: Dataset,
    protocol: Protocol,
    splits: list[str] | None,
    contexts: list[int],
    seeds: list[int],
    out: Path | str,
    quiet: bool = True,
    echo: Callable[[str], None] = print,
) -> ExportReport:
    """Write the contexts of every (split, object, size, seed) and the manifest to ``out``.

    An object that cannot be loaded is named (``echo``) and listed in the manifest's
    ``failed``; a size an object cannot provide is refused before anything is written."""
    from shapebench.progress import progress_bar

    splits = check_request(dataset, protocol, splits, contexts)
    contexts, seeds = sorted(set(contexts)), sorted(set(seeds))
    out = Path(out)
    store = ContextStore(dataset.cache_root, dataset.data_fingerprint())
    drawn: list[tuple[Entry, Context]] = []
    failed: list[dict[str, str]] = []
    for split in splits:
        refs = dataset.objects(split)
        if not refs:
            raise ShapebenchError(f"split {split} of dataset {dataset.name!r} has no objects")
        with progress_bar(len(refs), f"contexts of {dataset.name}/{split}", quiet) as bar:
            for ref in refs:
                try:
                    data = dataset.load(ref)
                except ObjectLoadError as exc:
                    failed.append({"split": split, "object": ref.id, "reason": str(exc)})
                    echo(f"  {dataset.name}/{split}: {ref.id} could not be loaded: {exc}")
                    bar.update()
                    continue
                n_points = int(dataset.points_to_complete(data))
                for seed in seeds:
                    for size in contexts:
                        try:
                            ctx = store.context(data, size, seed, protocol=protocol)
                        except ValueError as exc:  # a size this object cannot provide
                            raise ShapebenchError(
                                f"object {ref.id!r} of {dataset.name}/{split}: {exc}",
                                "export smaller --contexts",
                            ) from None
                        stem = entry_stem(split, ref.category, ref.id, size, seed)
                        normals = f"{CONTEXTS_DIR}/{stem}-normals.npy"
                        entry = Entry(
                            split=split,
                            category=ref.category,
                            object=ref.id,
                            size=size,
                            seed=seed,
                            context_seed=int(ctx.seed),
                            n_points=n_points,
                            digest=array_digest(ctx.points),
                            context=f"{CONTEXTS_DIR}/{stem}.npy",
                            completion=f"{COMPLETIONS_DIR}/{stem}",
                            normals=normals if ctx.normals is not None else None,
                        )
                        drawn.append((entry, ctx))
                bar.update()
    manifest = Manifest.for_dataset(
        dataset, protocol, splits, contexts, seeds, [e for e, _ in drawn], failed
    )
    for entry, ctx in drawn:
        _write_context(out, entry, ctx)
    (out / COMPLETIONS_DIR).mkdir(parents=True, exist_ok=True)
    _write_atomic(out / MANIFEST, manifest.text().encode())
    return ExportReport(out, manifest)


def _write_context(out: Path, entry: Entry, ctx: Context) -> None:
    points = np.ascontiguousarray(ctx.points, dtype=np.float32)
    _write_atomic(out / entry.context, _npy_bytes(points))
    normals = None
    if entry.normals:
        normals = np.ascontiguousarray(ctx.normals, dtype=np.float32)
        _write_atomic(out / entry.normals, _npy_bytes(normals))
    comment = f"shapebench context {entry.object} k={entry.size} seed={entry.seed}"
    _write_atomic(out / entry.as_json()["context_ply"], ply_bytes(points, normals, comment))


def _npy_bytes(array: np.ndarray) -> bytes:
    import io

    buf = io.BytesIO()
    np.save(buf, array, allow_pickle=False)
    return buf.getvalue()


def ply_bytes(points: np.ndarray, normals: np.ndarray | None = None, comment: str = "") -> bytes:
    """An ASCII PLY of ``points`` (and their normals): every reader takes it, and ``%.9g``
    gives float32 values back exactly."""
    lines = ["ply", "format ascii 1.0"]
    if comment:
        lines.append(f"comment {comment}")
    lines += [f"element vertex {len(points)}"]
    lines += [f"property float {axis}" for axis in ("x", "y", "z")]
    columns = [np.asarray(points, dtype=np.float32)]
    if normals is not None:
        lines += [f"property float {axis}" for axis in ("nx", "ny", "nz")]
        columns.append(np.asarray(normals, dtype=np.float32))
    lines.append("end_header")
    rows = np.concatenate(columns, axis=1) if columns else np.empty((0, 3))
    body = [" ".join(f"{float(v):.9g}" for v in row) for row in rows]
    return ("\n".join(lines + body) + "\n").encode("ascii")


def _write_atomic(path: Path, data: bytes) -> None:
    """Write ``data`` to ``path`` through a temporary file and a rename: an interrupted export
    leaves whole files (rerun it to finish)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, suffix=".tmp")
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(data)
        os.chmod(tmp, 0o644)
        os.replace(tmp, path)
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)
