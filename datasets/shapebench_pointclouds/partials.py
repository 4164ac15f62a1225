"""The ``partials`` dataset: a folder of real partial scans with no ground truth (KITTI-style).

Every ``.pcd``, ``.ply``, ``.xyz`` (or ``.txt``: x y z per line, further columns ignored) and
``.npy`` file below ``--data-root`` is one object; each top-level sub-folder is a category (files
directly in the folder form ``misc``), an object's id is its path without the suffix. Every
category is *novel*: nothing here trains a method; pass ``--checkpoint`` or use shipped weights.

A scan is centred on its mean and scaled to a largest distance of 1 (there is no complete shape
to normalise by, so the frame is the scan's own). The scan is the pool contexts are drawn from.
There is no ground truth: completions are pictured, and only metrics that compare a completion
with its input apply (``fidelity`` by default); a metric that needs the ground truth is refused
by name, ``--protocol crop`` too. Methods are asked for ``completion_points`` points.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import ClassVar

import numpy as np

from shapebench.api.dataset import Dataset, ObjectLoadError
from shapebench.api.errors import DataNotFoundError
from shapebench.api.types import NOVEL, Category, ObjectData, ObjectRef
from shapebench.exchange.pcd import read_pcd
from shapebench.hashing import stable_hash

SCAN_SUFFIXES = (".pcd", ".ply", ".xyz", ".txt", ".npy")
ROOT_CATEGORY = "misc"
OBTAIN_HINT = (
    "pass --data-root DIR, a folder of partial scans (" + ", ".join(SCAN_SUFFIXES) + "); each "
    "sub-folder of DIR is a category, files directly in DIR form the category 'misc'"
)


@dataclass(frozen=True)
class PartialsOptions:
    completion_points: int = field(
        default=16384,
        metadata={"help": "points each method is asked for (PCN's output: 16384)"},
    )


def read_scan(path: Path) -> np.ndarray:
    """The ``(n, 3)`` float32 points of one scan file; :class:`ObjectLoadError` naming it."""
    suffix = path.suffix.lower()
    try:
        if suffix == ".pcd":
            return read_pcd(path)
        if suffix == ".npy":
            points = np.load(path, allow_pickle=False)
        elif suffix in (".xyz", ".txt"):
            points = np.loadtxt(path, ndmin=2, usecols=(0, 1, 2))
        else:  # .ply: a point cloud, or a mesh whose vertices are the points
            import trimesh

            points = np.asarray(trimesh.load(str(path), process=False).vertices)
    except ObjectLoadError:
        raise
    except Exception as exc:  # numpy's and trimesh's parsers raise what they hit
        raise ObjectLoadError(f"cannot read scan {path}: {type(exc).__name__}: {exc}") from exc
    points = np.asarray(points, dtype=np.float64)
    if points.ndim != 2 or points.shape[1] < 3:
        raise ObjectLoadError(f"scan {path} has shape {points.shape}, not (n, 3)")
    points = points[:, :3][np.isfinite(points[:, :3]).all(axis=1)]
    if len(points) == 0:
        raise ObjectLoadError(f"scan {path} holds no valid points")
    return points.astype(np.float32)


class PartialsDataset(Dataset):
    name = "partials"
    display_name = "Partial scans (no ground truth)"
    description = (
        "every .pcd/.ply/.xyz/.npy scan below --data-root is an object, sub-folders are "
        "categories; no ground truth: completions are pictured and scored by fidelity"
    )
    Options: ClassVar[type] = PartialsOptions
    eval_splits = (NOVEL,)
    has_normals = False
    has_ground_truth = False
    needs_data_root = True
    default_metric = "fidelity"
    obtain_hint: ClassVar[str] = OBTAIN_HINT

    def __init__(self, options, cache_dir, data_root=None) -> None:
        super().__init__(options, cache_dir, data_root)
        self._files: dict[str, str] | None = None

    @property
    def files(self) -> dict[str, str]:
        """Object id -> path relative to the data root, in a stable order."""
        if self._files is None:
            if self.data_root is None or not Path(self.data_root).is_dir():
                raise DataNotFoundError(f"scan folder {self.data_root} does not exist", OBTAIN_HINT)
            root = Path(self.data_root)
            found: dict[str, str] = {}
            for dirpath, dirnames, filenames in os.walk(root, followlinks=True):
                dirnames[:] = sorted(d for d in dirnames if not d.startswith("."))
                for name in sorted(filenames):
                    if name.startswith(".") or Path(name).suffix.lower() not in SCAN_SUFFIXES:
                        continue
                    rel = (Path(dirpath) / name).relative_to(root).as_posix()
                    stem = rel.rsplit(".", 1)[0]
                    found[stem if stem not in found else rel] = rel
            if not found:
                raise DataNotFoundError(f"no scans found below {root}", OBTAIN_HINT)
            self._files = dict(sorted(found.items()))
        return self._files

    @property
    def version(self) -> str:
        root = Path(self.data_root) if self.data_root else Path()
        listing = [(k, rel, (root / rel).stat().st_size) for k, rel in self.files.items()]
        return f"scans-{stable_hash(listing)}"

    def _category(self, object_id: str) -> str:
        return object_id.split("/")[0] if "/" in object_id else ROOT_CATEGORY

    def categories(self) -> list[Category]:
        return [Category(c, NOVEL) for c in sorted({self._category(i) for i in self.files})]

    def objects(self, split: str) -> list[ObjectRef]:
        if split not in ("train", NOVEL):
            raise ValueError(f"unknown split {split!r}; partial scans form the novel split")
        if split != NOVEL:
            return []
        return [ObjectRef(i, self._category(i)) for i in self.files]

    def max_context_size(self) -> int | None:
        return None  # scans differ in size: read per object before any cell

    def points_to_complete(self, data: ObjectData) -> int:
        return self.options.completion_points

    def load(self, ref: ObjectRef, need=frozenset()) -> ObjectData:
        rel = self.files.get(ref.id)
        if rel is None:
            raise ObjectLoadError(f"no scan for object {ref.id!r} under {self.data_root}")
        scan = read_scan(Path(self.data_root) / rel).astype(np.float64)
        scan -= scan.mean(axis=0)
        radius = float(np.linalg.norm(scan, axis=1).max())
        if radius <= 0:
            raise ObjectLoadError(f"scan {rel}: every point is the same")
        points = (scan / radius).astype(np.float32)
        none = np.zeros((0, 3), dtype=np.float32)
        return ObjectData(ref, points, np.zeros_like(points), none)
