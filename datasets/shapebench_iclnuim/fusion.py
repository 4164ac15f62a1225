"""From depth frames and poses to one oriented point cloud of the scene (the paper's §4.1).

Pixels holding a depth sensor's "no measurement" codes (0, and 65535, the largest 16-bit value)
are dropped before scaling: scaled, 65535 would become a point 13 m (depth scale 5000) or 65 m
(depth scale 1000) away and blow up the scene's normalisation. So are depths beyond ``max_depth``.
Every remaining depth pixel is back-projected with the pinhole model (``x = (u - cx) z / fx``,
``y = (v - cy) z / fy``, ``z`` the depth), moved into the world frame by its frame's
camera-to-world pose, and the union is thinned to one measured point per voxel (the first frame
to see a voxel keeps it, so every kept point is a real measurement, never an average across an
edge). Normals come from a local PCA of the k nearest neighbours and are then turned towards the
camera that observed the point: PCA alone leaves their sign arbitrary (the paper corrects
Open3D's inconsistent orientations the same way).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

from shapebench.api.dataset import ObjectLoadError

_VOXEL_OFFSET = 1 << 20  # voxel indices in [-2^20, 2^20) on each axis, 21 bits each
_COMPACT_EVERY = 4_000_000  # merge the per-frame voxels once this many points have accumulated
_NORMAL_CHUNK = 65_536
#: Raw depth values that mean "no measurement": 0, and 65535 (saturated / invalid) in 16-bit PNGs.
INVALID_DEPTH_CODES = (0, 65535)


@dataclass(frozen=True)
class Intrinsics:
    fx: float
    fy: float
    cx: float
    cy: float
    depth_scale: float  # PNG value per metre
    width: int = 0  # image size the intrinsics belong to (0: not checked)
    height: int = 0


def read_depth(path: Path, depth_scale: float) -> np.ndarray:
    """Depth in metres from a 16-bit PNG, 0 where the sensor has no measurement (the raw codes
    :data:`INVALID_DEPTH_CODES`, and anything outside them)."""
    import imageio.v3 as iio

    try:
        raw = iio.imread(path, plugin="pillow")  # no probing of every format on bad files
    except Exception as exc:
        raise ObjectLoadError(f"cannot read depth image {path}: {exc}") from exc
    if raw.ndim != 2 or not np.issubdtype(raw.dtype, np.integer):
        raise ObjectLoadError(
            f"depth image {path} is {raw.dtype} {raw.shape}, expected a single-channel 16-bit PNG"
        )
    low, high = INVALID_DEPTH_CODES
    valid = (raw > low) & (raw < high)  # 32-bit PNGs: values past 65535 are no depth either
    return np.where(valid, raw.astype(np.float64) / depth_scale, 0.0)


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
class FusionReport:
    """What happened to the frames given to :func:`fuse`."""

    frames: int  # frames given
    fused: int = 0  # frames that contributed points
    empty: int = 0  # readable frames without a valid depth within max_depth
    unreadable: list[str] = field(default_factory=list)  # one reason per frame that failed
    measured: int = 0  # pixels with a valid depth code
    far: int = 0  # of those, beyond max_depth (dropped)


@dataclass
class FusedCloud:
    points: np.ndarray  # (n, 3) world frame
    camera: np.ndarray  # (n,) index into ``cameras`` of the frame that kept the point
    cameras: np.ndarray  # (m, 3) camera centres
    report: FusionReport


def fuse(frames: Sequence, k: Intrinsics, voxel: float, max_depth: float = 0.0) -> FusedCloud:
    """Back-project ``frames`` (with ``depth_path``, ``rotation``, ``position``) into the world
    and keep one point per voxel of size ``voxel``.

    A frame that cannot be read, or whose size is not the camera's, is skipped and its reason
    kept in the report; only when no frame gives a point is it an :class:`ObjectLoadError`.
    """
    keys: list[np.ndarray] = []
    points: list[np.ndarray] = []
    cams: list[np.ndarray] = []
    report = FusionReport(len(frames))
    pending = 0
    for i, frame in enumerate(frames):
        try:
            depth = _checked_depth(frame.depth_path, k)
        except ObjectLoadError as exc:
            report.unreadable.append(str(exc))
            continue
        report.measured += int(np.count_nonzero(depth))
        if max_depth > 0:
            report.far += int((depth > max_depth).sum())
        local = backproject(depth, k, max_depth)
        if len(local) == 0:
            report.empty += 1
            continue
        report.fused += 1
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
        raise ObjectLoadError(_nothing_fused(report, max_depth))
    _, pts, cam = _compact(keys, points, cams)
    positions = np.array([f.position for f in frames], dtype=np.float64)
    return FusedCloud(pts, cam, positions, report)


def _checked_depth(path: Path, k: Intrinsics) -> np.ndarray:
    """The depth of ``path`` in metres, refused if its size is not the one ``k`` is for."""
    depth = read_depth(path, k.depth_scale)
    if k.width and k.height and depth.shape != (k.height, k.width):
        raise ObjectLoadError(
            f"depth image {path} is {depth.shape[1]}x{depth.shape[0]} but the camera is "
            f"{k.width}x{k.height}: set fx, fy, cx, cy for this camera"
        )
    return depth


def _nothing_fused(report: FusionReport, max_depth: float) -> str:
    """Why no frame gave a point, in one line."""
    if report.unreadable and len(report.unreadable) == report.frames:
        return f"none of the {report.frames} depth frames can be read, e.g. {report.unreadable[0]}"
    reason = f"no valid depth measurement in any of {report.frames} frames"
    if report.unreadable:
        reason += f" ({len(report.unreadable)} unreadable, e.g. {report.unreadable[0]})"
    if report.far:
        reason += (
            f"; {report.far} measurements lie beyond max_depth={max_depth:g} m: check depth_scale "
            "(depth PNG value per metre) or raise max_depth"
        )
    return reason


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
