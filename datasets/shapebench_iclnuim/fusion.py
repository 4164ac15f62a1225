"""From depth frames and poses to one oriented point cloud of the scene (the paper's §4.1).

Every depth pixel is back-projected with the pinhole model (``x = (u - cx) z / fx``,
``y = (v - cy) z / fy``, ``z`` the depth), moved into the world frame by its frame's
camera-to-world pose, and the union is thinned to one measured point per voxel (the first frame
to see a voxel keeps it, so every kept point is a real measurement, never an average across an
edge). Normals come from a local PCA of the k nearest neighbours and are then turned towards the
camera that observed the point: PCA alone leaves their sign arbitrary (the paper corrects
Open3D's inconsistent orientations the same way).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

from shapebench.dataset import ObjectLoadError

_VOXEL_OFFSET = 1 << 20  # voxel indices in [-2^20, 2^20) on each axis, 21 bits each
_COMPACT_EVERY = 4_000_000  # merge the per-frame voxels once this many points have accumulated
_NORMAL_CHUNK = 65_536


@dataclass(frozen=True)
class Intrinsics:
    fx: float
    fy: float
    cx: float
    cy: float
    depth_scale: float  # PNG value per metre


def read_depth(path: Path, depth_scale: float) -> np.ndarray:
    """Depth in metres (0 where the sensor has no measurement) from a 16-bit PNG."""
    import imageio.v3 as iio

    try:
        raw = iio.imread(path, plugin="pillow")  # no probing of every format on bad files
    except Exception as exc:
        raise ObjectLoadError(f"cannot read depth image {path}: {exc}") from exc
    if raw.ndim != 2 or not np.issubdtype(raw.dtype, np.integer):
        raise ObjectLoadError(
            f"depth image {path} is {raw.dtype} {raw.shape}, expected a single-channel 16-bit PNG"
        )
    return raw.astype(np.float64) / depth_scale


def backproject(depth: np.ndarray, k: Intrinsics, max_depth: float = 0.0) -> np.ndarray:
    """Camera-frame points of the valid pixels of ``depth`` (``(n, 3)``)."""
    v, u = np.nonzero((depth > 0) & ((depth <= max_depth) if max_depth > 0 else True))
    z = depth[v, u]
    return np.stack([(u - k.cx) * z / k.fx, (v - k.cy) * z / k.fy, z], axis=1)


def voxel_keys(points: np.ndarray, voxel: float) -> np.ndarray:
    """One int64 per voxel containing each point (points beyond +-2^20 voxels are clipped)."""
    idx = np.floor(points / voxel).astype(np.int64) + _VOXEL_OFFSET
    idx = np.clip(idx, 0, 2 * _VOXEL_OFFSET - 1)
    return (idx[:, 0] << 42) | (idx[:, 1] << 21) | idx[:, 2]


@dataclass
class FusedCloud:
    points: np.ndarray  # (n, 3) world frame
    camera: np.ndarray  # (n,) index into ``cameras`` of the frame that kept the point
    cameras: np.ndarray  # (m, 3) camera centres


def fuse(frames: Sequence, k: Intrinsics, voxel: float, max_depth: float = 0.0) -> FusedCloud:
    """Back-project ``frames`` (with ``depth_path``, ``rotation``, ``position``) into the world
    and keep one point per voxel of size ``voxel``."""
    keys: list[np.ndarray] = []
    points: list[np.ndarray] = []
    cams: list[np.ndarray] = []
    pending = 0
    for i, frame in enumerate(frames):
        local = backproject(read_depth(frame.depth_path, k.depth_scale), k, max_depth)
        if len(local) == 0:
            continue
        world = local @ frame.rotation.T + frame.position
        key = voxel_keys(world, voxel)
        _, first = np.unique(key, return_index=True)
        keys.append(key[first])
        points.append(world[first])
        cams.append(np.full(len(first), i, dtype=np.int32))
        pending += len(first)
        if pending > _COMPACT_EVERY:
            merged = _compact(keys, points, cams)
            keys, points, cams = [merged[0]], [merged[1]], [merged[2]]
            pending = len(merged[0])
    if not points:
        raise ObjectLoadError("no frame has a valid depth measurement")
    _, pts, cam = _compact(keys, points, cams)
    positions = np.array([f.position for f in frames], dtype=np.float64)
    return FusedCloud(pts, cam, positions)


def _compact(keys, points, cams):
    """One entry per voxel over everything accumulated; earlier entries win."""
    key = np.concatenate(keys)
    _, first = np.unique(key, return_index=True)
    return key[first], np.concatenate(points)[first], np.concatenate(cams)[first]


def estimate_normals(points: np.ndarray, neighbours: int) -> np.ndarray:
    """Unit normals by local PCA: the direction of least variance of the ``neighbours`` nearest
    points (sign arbitrary; see :func:`orient_towards`)."""
    n = len(points)
    if n < 3:
        raise ObjectLoadError(f"only {n} points: too few to estimate normals")
    k = min(neighbours, n)
    tree = cKDTree(points)
    normals = np.empty_like(points)
    for start in range(0, n, _NORMAL_CHUNK):
        chunk = points[start : start + _NORMAL_CHUNK]
        _, idx = tree.query(chunk, k=k, workers=-1)
        nb = points[idx]
        nb -= nb.mean(axis=1, keepdims=True)
        cov = np.einsum("nki,nkj->nij", nb, nb)
        _, vectors = np.linalg.eigh(cov)
        normals[start : start + len(chunk)] = vectors[:, :, 0]
    return normals


def orient_towards(normals: np.ndarray, points: np.ndarray, viewpoints: np.ndarray) -> np.ndarray:
    """``normals`` flipped where needed so each points towards its own viewpoint."""
    facing = np.einsum("ij,ij->i", normals, viewpoints - points) < 0
    out = normals.copy()
    out[facing] *= -1.0
    return out
