"""The Dataset interface, and :class:`MeshDataset` for anything made of triangle meshes.

A dataset plugin subclasses :class:`Dataset` (usually :class:`MeshDataset`, which adds the paper's
preprocessing and an on-disk cache) and registers it through ``shapebench_register_datasets``.

A dataset has categories, each either *trained* (methods may train on it) or *novel* (never seen
in training), and three splits of objects: ``train`` (training objects of trained categories),
``trained`` (test objects of trained categories) and ``novel`` (test objects of novel categories).
``load`` returns an object's preprocessed arrays; contexts are drawn from them by the core
(:mod:`shapebench.contexts`), never by the dataset or the method, so every method sees the same
points.
"""

from __future__ import annotations

import os
import tempfile
from abc import ABC, abstractmethod
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, ClassVar

import numpy as np

from shapebench.hashing import stable_hash, stable_seed
from shapebench.options import NoOptions
from shapebench.preprocess import PreprocessError, PreprocessParams, prepare_mesh
from shapebench.types import EVAL_SPLITS, Category, ObjectData, ObjectRef, Supervision


class ObjectLoadError(RuntimeError):
    """One object could not be loaded or preprocessed; the others are unaffected."""


class Dataset(ABC):
    """A collection of objects to complete.

    Class attributes: ``name`` (public name), ``display_name``, ``description`` (one line),
    ``Options`` (a dataclass, see :mod:`shapebench.options`), ``provides`` (the supervision kinds it
    can produce for training), ``default_metric`` (what leaderboards rank by), ``eval_splits``
    (the splits a run evaluates by default) and ``needs_data_root`` (whether ``--data-root`` is
    required, for datasets read from a user's local copy).
    """

    name: ClassVar[str] = ""
    display_name: ClassVar[str] = ""
    description: ClassVar[str] = ""
    Options: ClassVar[type] = NoOptions
    provides: ClassVar[frozenset[Supervision]] = frozenset({Supervision.SURFACE_POINTS})
    default_metric: ClassVar[str] = "chamfer-l2"
    eval_splits: ClassVar[tuple[str, ...]] = EVAL_SPLITS
    needs_data_root: ClassVar[bool] = False

    def __init__(self, options: Any, cache_dir: Path, data_root: Path | None = None) -> None:
        self.options = options
        self.cache_dir = Path(cache_dir)
        self.data_root = data_root

    @property
    def version(self) -> str:
        """The data/protocol version; change it whenever the produced arrays change."""
        return "1"

    def fingerprint(self) -> str:
        """Identifies the exact data this instance produces (cache keys, run tags)."""
        opts = asdict(self.options) if self.options is not None else {}
        return stable_hash({"name": self.name, "version": self.version, "options": opts})

    @abstractmethod
    def categories(self) -> list[Category]:
        """Every category with its ``trained``/``novel`` split."""

    @abstractmethod
    def objects(self, split: str) -> list[ObjectRef]:
        """The objects of ``split`` (``train``, ``trained`` or ``novel``), in a stable order."""

    @abstractmethod
    def load(self, ref: ObjectRef) -> ObjectData:
        """The preprocessed arrays of one object; raise :class:`ObjectLoadError` if impossible."""

    def max_context_size(self) -> int | None:
        """An upper bound on any object's visible points, known without loading (or None)."""
        return None


@dataclass(frozen=True)
class MeshOptions:
    """Options every mesh dataset shares: how many points preprocessing produces."""

    surface_candidates: int = field(
        default=20_000,
        metadata={"help": "surface samples tested for visibility (the paper: 200k)"},
    )
    gt_points: int = field(
        default=30_000, metadata={"help": "ground-truth points per object (the paper: 30k)"}
    )
    viewpoints: int = field(
        default=100, metadata={"help": "viewpoints around each object for visibility"}
    )
    seed: int = field(default=0, metadata={"help": "seed of the object split and sampling"})


class MeshDataset(Dataset):
    """A dataset whose objects are triangle meshes; preprocessing and caching are done here.

    Subclasses implement :meth:`categories`, :meth:`objects` and :meth:`mesh`. Arrays are cached in
    ``<cache_dir>/<name>/<fingerprint>/<object>.npz``, written atomically, so an interrupted
    preparation resumes where it stopped.
    """

    Options: ClassVar[type] = MeshOptions

    @abstractmethod
    def mesh(self, ref: ObjectRef):  # -> trimesh.Trimesh
        """The raw mesh of one object, in its source frame."""

    def max_context_size(self) -> int | None:
        return self.options.surface_candidates

    def preprocess_params(self) -> PreprocessParams:
        o = self.options
        return PreprocessParams(
            surface_candidates=o.surface_candidates, gt_points=o.gt_points, viewpoints=o.viewpoints
        )

    @property
    def cache_root(self) -> Path:
        return self.cache_dir / self.name / self.fingerprint()

    def cache_path(self, ref: ObjectRef) -> Path:
        return self.cache_root / "objects" / (ref.id.replace("/", "__") + ".npz")

    def load(self, ref: ObjectRef) -> ObjectData:
        path = self.cache_path(ref)
        failed = path.with_suffix(".error.txt")
        if failed.exists():  # preprocessing already failed for this exact data version
            raise ObjectLoadError(failed.read_text())
        if path.exists():
            try:
                with np.load(path) as z:
                    arrays = {k: z[k] for k in z.files}
            except Exception:  # a truncated file from a crash: rebuild it
                arrays = self._build(ref, path)
        else:
            arrays = self._build(ref, path)
        extra = {
            k: v
            for k, v in arrays.items()
            if k not in ("surface_points", "surface_normals", "gt_points")
        }
        return ObjectData(
            ref, arrays["surface_points"], arrays["surface_normals"], arrays["gt_points"], extra
        )

    def _build(self, ref: ObjectRef, path: Path) -> dict[str, np.ndarray]:
        try:
            mesh = self.mesh(ref)
            rng = np.random.default_rng(stable_seed("preprocess", self.fingerprint(), ref.id))
            arrays = prepare_mesh(mesh, self.preprocess_params(), rng)
        except Exception as exc:
            reason = (
                str(exc)
                if isinstance(exc, (ObjectLoadError, PreprocessError))
                else (f"cannot read or preprocess mesh: {type(exc).__name__}: {exc}")
            )
            path.parent.mkdir(parents=True, exist_ok=True)
            path.with_suffix(".error.txt").write_text(reason)
            raise ObjectLoadError(reason) from exc
        save_npz_atomic(path, arrays)
        return arrays


def save_npz_atomic(path: Path, arrays: dict[str, np.ndarray]) -> None:
    """Write ``arrays`` to ``path`` so that a crash never leaves a half-written file."""
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, suffix=".tmp.npz")
    os.close(fd)
    try:
        np.savez(tmp, **arrays)
        os.replace(tmp, path)
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)
