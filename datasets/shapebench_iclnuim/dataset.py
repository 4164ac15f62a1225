"""The ``icl-nuim`` dataset: ICL-NUIM living-room and office scenes (the paper's Table 3).

Each sequence (a folder with ``depth/`` and its ground-truth trajectory, see
:mod:`shapebench_iclnuim.sequence`) is one test scene of the ``all`` split, in the category
``living-room`` or ``office``. The scene is every ``frame_stride``-th depth frame back-projected
into the world frame, thinned to one point per voxel, normalised like ShapeNet (centre of mass of
the points at the origin, largest distance 1) and given PCA normals oriented towards the camera
that saw each point (:mod:`shapebench_iclnuim.fusion`). There is no mesh: the ground truth is the
fused cloud itself (``gt_points`` of it) and the visible surface points are the same cloud with
normals (``surface_candidates`` of it). It covers only what the cameras saw, hence the paper's
asymmetric Chamfer distance (``chamfer-l2-asym``: ground truth to completion only).

Arrays are cached like :class:`shapebench.dataset.MeshDataset` caches them: one atomically
written ``.npz`` per scene under ``<cache_dir>/icl-nuim/<fingerprint>/objects/``, and a failed
scene's reason next to it, so a preparation resumes and a broken scene is not retried.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import ClassVar

import numpy as np

from shapebench.dataset import Dataset, ObjectLoadError, save_npz_atomic
from shapebench.errors import ConfigError, DataNotFoundError
from shapebench.hashing import stable_hash, stable_seed
from shapebench.types import Category, ObjectData, ObjectRef, Supervision
from shapebench_iclnuim import fusion
from shapebench_iclnuim.sequence import OBTAIN, Sequence, discover, read_frames, signature

ALL = "all"


@dataclass(frozen=True)
class ICLNUIMOptions:
    frame_stride: int = field(
        default=10, metadata={"help": "fuse every n-th depth frame that has a pose"}
    )
    voxel_size: float = field(
        default=0.02, metadata={"help": "voxel edge (metres) of the fused cloud's thinning"}
    )
    normal_neighbors: int = field(
        default=20, metadata={"help": "nearest neighbours of the PCA normal estimate"}
    )
    max_depth: float = field(
        default=0.0, metadata={"help": "ignore depths beyond this many metres (0: keep all)"}
    )
    surface_candidates: int = field(
        default=20_000, metadata={"help": "visible points (with normals) kept per scene"}
    )
    gt_points: int = field(default=30_000, metadata={"help": "ground-truth points per scene"})
    seed: int = field(default=0, metadata={"help": "seed of the subsampling"})
    fx: float = field(default=481.20, metadata={"help": "focal length x (pixels)"})
    fy: float = field(
        default=-480.00,
        metadata={"help": "focal length y (pixels); negative in ICL-NUIM's convention"},
    )
    cx: float = field(default=319.50, metadata={"help": "principal point x (pixels)"})
    cy: float = field(default=239.50, metadata={"help": "principal point y (pixels)"})
    depth_scale: float = field(default=5000.0, metadata={"help": "depth PNG value per metre"})


class ICLNUIMDataset(Dataset):
    name = "icl-nuim"
    display_name = "ICL-NUIM"
    description = "ICL-NUIM living-room and office scenes fused from depth frames (local copy)"
    Options: ClassVar[type] = ICLNUIMOptions
    provides = frozenset({Supervision.SURFACE_POINTS})
    default_metric = "chamfer-l2-asym"
    eval_splits = (ALL,)
    needs_data_root = True
    obtain_hint: ClassVar[str] = OBTAIN

    def __init__(self, options, cache_dir, data_root=None) -> None:
        super().__init__(options, cache_dir, data_root)
        o = options
        if o.frame_stride < 1 or o.normal_neighbors < 3 or o.voxel_size <= 0:
            raise ConfigError(
                "icl-nuim needs frame_stride >= 1, normal_neighbors >= 3 and voxel_size > 0, got "
                f"{o.frame_stride}, {o.normal_neighbors}, {o.voxel_size}"
            )
        if o.fx == 0 or o.fy == 0 or o.depth_scale <= 0:
            raise ConfigError("icl-nuim needs non-zero fx, fy and a positive depth_scale")
        self._sequences: dict[str, Sequence] | None = None
        self._version: str | None = None

    # ------------------------------------------------------------------ listing

    @property
    def sequences(self) -> dict[str, Sequence]:
        if self._sequences is None:
            root = self.data_root
            if root is None or not Path(root).is_dir():
                raise DataNotFoundError(
                    f"ICL-NUIM data root {root} does not exist"
                    if root
                    else "dataset 'icl-nuim' needs a local copy of ICL-NUIM",
                    OBTAIN,
                )
            found = discover(Path(root))
            if not found:
                raise DataNotFoundError(
                    f"no ICL-NUIM sequence under {root}: expected folders holding depth/ (16-bit "
                    "PNGs), associations.txt and a ground-truth trajectory *.gt.freiburg",
                    OBTAIN,
                )
            self._sequences = {s.id: s for s in found}
        return self._sequences

    @property
    def version(self) -> str:
        # The frames and trajectory of each sequence identify its data, so a sample and the full
        # sequence under the same folder name never share cached arrays.
        if self._version is None:
            listing = [signature(s) for s in self.sequences.values()]
            self._version = f"icl1-{stable_hash(listing)}"
        return self._version

    def categories(self) -> list[Category]:
        return [Category(c, ALL) for c in sorted({s.category for s in self.sequences.values()})]

    def objects(self, split: str) -> list[ObjectRef]:
        if split != ALL:
            return []  # every scene is a test scene; there is no training split
        return [ObjectRef(s.id, s.category) for s in self.sequences.values()]

    def max_context_size(self) -> int | None:
        return self.options.surface_candidates

    # ------------------------------------------------------------------ arrays

    def load(self, ref: ObjectRef, need: frozenset[Supervision] = frozenset()) -> ObjectData:
        """The scene's arrays (``need`` is ignored: scenes only have surface points)."""
        path = self.cache_path(ref)
        failed = path.with_suffix(".error.txt")
        if failed.exists():  # this exact data version already failed: do not fuse it again
            raise ObjectLoadError(failed.read_text())
        arrays = _read_npz(path)
        if arrays is None:
            try:
                arrays = self.build(ref)
            except Exception as exc:
                reason = (
                    str(exc)
                    if isinstance(exc, ObjectLoadError)
                    else f"cannot fuse scene {ref.id}: {type(exc).__name__}: {exc}"
                )
                failed.parent.mkdir(parents=True, exist_ok=True)
                failed.write_text(reason)
                raise ObjectLoadError(reason) from exc
            save_npz_atomic(path, arrays)
        return ObjectData(
            ref, arrays["surface_points"], arrays["surface_normals"], arrays["gt_points"]
        )

    def build(self, ref: ObjectRef) -> dict[str, np.ndarray]:
        """Fuse, normalise and subsample one scene (no caching)."""
        o = self.options
        seq = self.sequences.get(ref.id)
        if seq is None:
            raise ObjectLoadError(f"no ICL-NUIM sequence {ref.id!r} under {self.data_root}")
        frames, _ = read_frames(seq)
        frames = frames[:: o.frame_stride]
        k = fusion.Intrinsics(o.fx, o.fy, o.cx, o.cy, o.depth_scale)
        cloud = fusion.fuse(frames, k, o.voxel_size, o.max_depth)
        normals = fusion.estimate_normals(cloud.points, o.normal_neighbors)
        normals = fusion.orient_towards(normals, cloud.points, cloud.cameras[cloud.camera])
        center = cloud.points.mean(axis=0)
        scale = float(np.linalg.norm(cloud.points - center, axis=1).max())
        if not np.isfinite(scale) or scale <= 0:
            raise ObjectLoadError(f"scene {ref.id} is degenerate (all points at one place)")
        unit = (cloud.points - center) / scale
        rng = np.random.default_rng(stable_seed("preprocess", self.data_fingerprint(), ref.id))
        surface = _subset(len(unit), o.surface_candidates, rng)
        gt = _subset(len(unit), o.gt_points, rng)
        return {
            "surface_points": unit[surface].astype(np.float32),
            "surface_normals": normals[surface].astype(np.float32),
            "gt_points": unit[gt].astype(np.float32),
            "center": center.astype(np.float64),
            "scale": np.array(scale, dtype=np.float64),
            "frames": np.array(len(frames)),
        }


def _subset(n: int, size: int, rng: np.random.Generator) -> np.ndarray:
    """``size`` distinct indices of ``n`` (all of them, shuffled, when there are fewer)."""
    return rng.permutation(n) if size >= n else rng.choice(n, size=size, replace=False)


def _read_npz(path: Path) -> dict[str, np.ndarray] | None:
    """The arrays of ``path``, or None if it is missing or truncated (then it is rebuilt)."""
    if not path.exists():
        return None
    try:
        with np.load(path) as z:
            return {name: z[name] for name in z.files}
    except Exception:
        return None
