"""The ``icl-nuim`` dataset: RGB-D scenes fused from depth frames (the paper's Table 3).

Each sequence (a folder with ``depth/`` and its ground-truth trajectory, see
:mod:`shapebench_iclnuim.sequence`) is one test scene of the ``all`` split, in the category
``living-room``, ``office`` or ``other``. The scene is every ``frame_stride``-th usable depth frame
back-projected into the world frame, thinned to one point per voxel, normalised like ShapeNet
(centre of mass of the points at the origin, largest distance 1) and given PCA normals oriented
towards the camera that saw each point (:mod:`shapebench_iclnuim.fusion`). There is no mesh: the
ground truth is the fused cloud itself (``gt_points`` of it) and the visible surface points are the
same cloud with normals (``surface_candidates`` of it). It covers only what the cameras saw, hence
the paper's asymmetric Chamfer distance (``chamfer-l2-asym``: ground truth to completion only).

Layouts and cameras
-------------------
Two on-disk layouts are read (option ``layout``, default ``auto``: detected per sequence from the
content of its trajectory file):

* ``tum``: ICL-NUIM's own release (``associations.txt``, ``*.gt.freiburg`` or
  ``groundtruth.txt``); default camera ICL-NUIM's: fx 481.20, fy -480.00 (its sign convention),
  cx 319.5, cy 239.5, depth PNG value 5000 per metre, 640x480.
* ``redwood``: Redwood, Open3D's RGB-D samples and Choi et al.'s ICL-NUIM re-release (a ``.log``
  trajectory such as ``trajectory.log`` or ``livingroom1-traj.txt``, depth in millimetres);
  default camera Open3D's PrimeSense default: fx = fy = 525, cx 319.5, cy 239.5, depth PNG value
  1000 per metre, 640x480.

The options ``fx``, ``fy``, ``cx``, ``cy`` and ``depth_scale`` default to 0, meaning "not set":
each scene then takes them from an Open3D camera file beside its frames (``camera_intrinsic.json``
or any ``*.json`` with an ``intrinsic_matrix``; no depth scale there) and otherwise from its
layout's default above. A non-zero option wins over both. The values each scene resolves to are
part of the dataset's identity (``identity()["cameras"]``), so the cache and cell keys change
whenever they do.

Depth pixels holding 0 or 65535 (no measurement) are dropped, and so are depths beyond
``max_depth`` (default 10 m: ICL-NUIM and Redwood scenes are rooms; 0 keeps every depth).

What is reported
----------------
A scene that cannot be fused raises :class:`~shapebench.api.dataset.ObjectLoadError` with one line
``scene <id>: <reason>; <fix>``. A scene that is fused but short of what was asked gets a
:class:`RGBDWarning` each time it is loaded (also from the cache): fewer frames fused than
``frame_stride`` asks of the frames the sequence names (frames without a depth file or a pose,
unreadable or empty frames; a single frame without a pose, as ICL-NUIM's first frame, is not
reported), a ``frame_stride`` that keeps one frame of several, a fused cloud smaller than
``gt_points`` (the ground truth then has the fused cloud's size), or most depth measurements
beyond ``max_depth`` (a wrong ``depth_scale``). The counts are in the cached arrays and in
``ObjectData.extra`` (see :data:`STAT_KEYS`).

Arrays are cached like :class:`shapebench.api.dataset.MeshDataset` caches them: one atomically
written ``.npz`` per scene under ``<cache_dir>/icl-nuim/<fingerprint>/objects/``, and a failed
scene's reason next to it, so a preparation resumes and a broken scene is not retried.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, ClassVar

import numpy as np

from shapebench.api.dataset import Dataset, ObjectLoadError, save_npz_atomic
from shapebench.api.errors import ConfigError, DataNotFoundError
from shapebench.api.types import Category, ObjectData, ObjectRef, Supervision
from shapebench.hashing import stable_hash, stable_seed
from shapebench_iclnuim import fusion
from shapebench_iclnuim.sequence import (
    AUTO,
    LAYOUTS,
    OBTAIN,
    REDWOOD,
    TUM,
    FrameListing,
    Sequence,
    Trajectory,
    discover,
    find_trajectory,
    list_frames,
    read_camera_file,
    signature,
)

ALL = "all"

#: Each layout's camera when neither an option nor a camera file beside the frames sets it.
LAYOUT_CAMERAS = {
    TUM: fusion.Intrinsics(481.20, -480.00, 319.50, 239.50, 5000.0, 640, 480),  # ICL-NUIM
    REDWOOD: fusion.Intrinsics(525.0, 525.0, 319.5, 239.5, 1000.0, 640, 480),  # PrimeSense
}
_CAMERA_OPTIONS = ("fx", "fy", "cx", "cy", "depth_scale")

#: Scalars each scene's cached arrays (and ``ObjectData.extra``) hold about its fusion.
STAT_KEYS = (
    "frames_listed",  # frames the sequence names (depth files, associations, trajectory)
    "frames_asked",  # ceil(frames_listed / frame_stride)
    "frames_posed",  # named frames with both a depth file and a pose
    "frames_selected",  # every frame_stride-th posed frame: the frames read
    "frames_fused",  # frames that contributed points
    "fused_points",  # points of the fused, voxel-thinned cloud (before subsampling)
    "gt_point_count",  # points of the ground truth actually stored: min(gt_points, fused_points)
)


class RGBDWarning(UserWarning):
    """A scene was fused from less than was asked (frames or points); it is still evaluated."""


@dataclass(frozen=True)
class ICLNUIMOptions:
    layout: str = field(
        default=AUTO,
        metadata={
            "help": "sequence layout: auto (detected from the trajectory file), tum "
            "(associations.txt + *.gt.freiburg, ICL-NUIM's release) or redwood (.log "
            "trajectory, depth in mm: Redwood, Open3D samples, ICL-NUIM re-release)"
        },
    )
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
        default=10.0,
        metadata={"help": "ignore depths beyond this many metres (rooms: 10; 0 keeps all)"},
    )
    surface_candidates: int = field(
        default=20_000, metadata={"help": "visible points (with normals) kept per scene"}
    )
    gt_points: int = field(default=30_000, metadata={"help": "ground-truth points per scene"})
    seed: int = field(default=0, metadata={"help": "seed of the subsampling"})
    fx: float = field(
        default=0.0,
        metadata={
            "help": "focal length x (pixels); 0: camera file, else layout default "
            "(tum 481.20, redwood 525)"
        },
    )
    fy: float = field(
        default=0.0,
        metadata={
            "help": "focal length y (pixels); 0: camera file, else layout default "
            "(tum -480.00, ICL-NUIM's sign; redwood 525)"
        },
    )
    cx: float = field(
        default=0.0,
        metadata={"help": "principal point x (pixels); 0: camera file, else 319.5"},
    )
    cy: float = field(
        default=0.0,
        metadata={"help": "principal point y (pixels); 0: camera file, else 239.5"},
    )
    depth_scale: float = field(
        default=0.0,
        metadata={"help": "depth PNG value per metre; 0: layout default (tum 5000, redwood 1000)"},
    )


@dataclass(frozen=True)
class SceneCamera:
    """How one scene's frames are read: its layout, trajectory and resolved intrinsics."""

    layout: str
    trajectory: Path
    intrinsics: fusion.Intrinsics
    source: str  # where the intrinsics come from: a camera file's name or "<layout> default"

    def describe(self) -> str:
        """What the scene's arrays depend on, as ``key=value`` words (one run parameter per
        scene; no absolute paths, so the data may move)."""
        k = self.intrinsics
        return (
            f"layout={self.layout} trajectory={self.trajectory.name} fx={k.fx:g} fy={k.fy:g} "
            f"cx={k.cx:g} cy={k.cy:g} depth_scale={k.depth_scale:g} size={k.width}x{k.height}"
        )


def resolve_camera(seq: Sequence, options: ICLNUIMOptions) -> SceneCamera:
    """The scene's layout and intrinsics: non-zero options, else its camera file, else the
    layout's default (:data:`LAYOUT_CAMERAS`). Raises :class:`ObjectLoadError`."""
    trajectory = find_trajectory(seq, options.layout)
    k = LAYOUT_CAMERAS[trajectory.layout]
    source = f"{trajectory.layout} default"
    camera_file = read_camera_file(seq)
    if camera_file is not None:
        c = camera_file
        k = replace(k, fx=c.fx, fy=c.fy, cx=c.cx, cy=c.cy, width=c.width, height=c.height)
        source = c.path.name
    given = {name: getattr(options, name) for name in _CAMERA_OPTIONS if getattr(options, name)}
    k = replace(k, **given)
    if "cx" in given or "cy" in given:  # a principal point given by hand: any image size goes
        k = replace(k, width=0, height=0)
    return SceneCamera(trajectory.layout, trajectory.path, k, source)


class ICLNUIMDataset(Dataset):
    name = "icl-nuim"
    display_name = "ICL-NUIM"
    description = (
        "ICL-NUIM (and other RGB-D) scenes fused from depth frames, TUM or Redwood layout "
        "(local copy)"
    )
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
        if o.layout not in LAYOUTS:
            raise ConfigError(
                f"icl-nuim layout must be one of {', '.join(LAYOUTS)}, got {o.layout!r}"
            )
        if o.depth_scale < 0 or o.max_depth < 0:
            raise ConfigError(
                "icl-nuim needs depth_scale >= 0 (0: the layout's default) and max_depth >= 0 "
                f"(0: keep all), got {o.depth_scale}, {o.max_depth}"
            )
        self._sequences: dict[str, Sequence] | None = None
        self._version: str | None = None
        self._cameras: dict[str, str | None] | None = None

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
                    f"no RGB-D sequence under {root}: expected folders holding depth/ (16-bit "
                    "PNGs) and a ground-truth trajectory (*.gt.freiburg with associations.txt, "
                    "or a .log such as trajectory.log)",
                    OBTAIN,
                )
            self._sequences = {s.id: s for s in found}
        return self._sequences

    @property
    def version(self) -> str:
        # The frames and trajectory of each sequence identify its data, so a sample and the full
        # sequence under the same folder name never share cached arrays. icl2: invalid depth
        # codes are dropped and each scene's camera is resolved from its layout.
        if self._version is None:
            listing = [signature(s) for s in self.sequences.values()]
            self._version = f"icl2-{stable_hash(listing)}"
        return self._version

    def identity(self, training: bool, selection: bool = True) -> dict[str, Any]:
        # The options may say "layout default" (0, auto); what each scene resolves to is what
        # its arrays depend on.
        return {**super().identity(training, selection), "cameras": self.cameras()}

    def cameras(self) -> dict[str, str | None]:
        """Each scene's resolved layout and intrinsics (:meth:`SceneCamera.describe`; None where
        they cannot be resolved: the scene then fails to load, with the reason)."""
        if self._cameras is None:
            cameras: dict[str, str | None] = {}
            for seq in self.sequences.values():
                try:
                    cameras[seq.id] = resolve_camera(seq, self.options).describe()
                except ObjectLoadError:
                    cameras[seq.id] = None
            self._cameras = cameras
        return self._cameras

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
        """The scene's arrays (``need`` is ignored: scenes only have surface points).

        ``extra`` holds the scene's :data:`STAT_KEYS` and ``notes``; each note is also issued as
        an :class:`RGBDWarning`, from the cache as well, so a short scene never goes unsaid.
        """
        path = self.cache_path(ref)
        failed = path.with_suffix(".error.txt")
        if failed.exists():  # this exact data version already failed: do not fuse it again
            raise ObjectLoadError(failed.read_text())
        arrays = _read_npz(path)
        if arrays is None:
            try:
                arrays = self.build(ref)
            except Exception as exc:
                reason = _failure(ref, exc)
                failed.parent.mkdir(parents=True, exist_ok=True)
                failed.write_text(reason)
                raise ObjectLoadError(reason) from exc
            save_npz_atomic(path, arrays)
        for note in arrays.get("notes", ()):
            warnings.warn(str(note), RGBDWarning, stacklevel=2)
        extra = {k: v for k, v in arrays.items() if k not in _BASE_ARRAYS}
        return ObjectData(
            ref, arrays["surface_points"], arrays["surface_normals"], arrays["gt_points"], extra
        )

    def build(self, ref: ObjectRef) -> dict[str, np.ndarray]:
        """Fuse, normalise and subsample one scene (no caching)."""
        o = self.options
        seq = self.sequences.get(ref.id)
        if seq is None:
            raise ObjectLoadError(f"no RGB-D sequence {ref.id!r} under {self.data_root}")
        camera = resolve_camera(seq, o)
        listing = list_frames(seq, Trajectory(camera.trajectory, camera.layout))
        selected = listing.frames[:: o.frame_stride]
        cloud = fusion.fuse(selected, camera.intrinsics, o.voxel_size, o.max_depth)
        normals = fusion.estimate_normals(cloud.points, o.normal_neighbors)
        normals = fusion.orient_towards(normals, cloud.points, cloud.cameras[cloud.camera])
        center = cloud.points.mean(axis=0)
        scale = float(np.linalg.norm(cloud.points - center, axis=1).max())
        if not np.isfinite(scale) or scale <= 0:
            raise ObjectLoadError("degenerate: all points at one place")
        unit = (cloud.points - center) / scale
        rng = np.random.default_rng(stable_seed("preprocess", self.data_fingerprint(), ref.id))
        surface = _subset(len(unit), o.surface_candidates, rng)
        gt = _subset(len(unit), o.gt_points, rng)
        stats = _stats(listing, cloud, o)
        k = camera.intrinsics
        return {
            "surface_points": unit[surface].astype(np.float32),
            "surface_normals": normals[surface].astype(np.float32),
            "gt_points": unit[gt].astype(np.float32),
            "center": center.astype(np.float64),
            "scale": np.array(scale, dtype=np.float64),
            "frames": np.array(cloud.report.fused),  # kept for older readers: frames fused
            **{name: np.array(value) for name, value in stats.items()},
            "layout": np.array(camera.layout),
            "intrinsics": np.array([k.fx, k.fy, k.cx, k.cy, k.depth_scale], dtype=np.float64),
            "notes": np.array(scene_notes(ref.id, listing, cloud.report, stats, camera, o), str),
        }


def _stats(listing: FrameListing, cloud: fusion.FusedCloud, o: ICLNUIMOptions) -> dict[str, int]:
    """The :data:`STAT_KEYS` of one fused scene."""
    n = len(cloud.points)
    return {
        "frames_listed": listing.listed,
        "frames_asked": math.ceil(listing.listed / o.frame_stride),
        "frames_posed": len(listing.frames),
        "frames_selected": cloud.report.frames,
        "frames_fused": cloud.report.fused,
        "fused_points": n,
        "gt_point_count": min(n, o.gt_points),
    }


def scene_notes(
    scene: str,
    listing: FrameListing,
    report: fusion.FusionReport,
    stats: dict[str, int],
    camera: SceneCamera,
    o: ICLNUIMOptions,
) -> list[str]:
    """One line (no line breaks) per way the fused scene falls short of what the options ask."""
    notes = []
    frames = _frames_note(listing, report, stats, o)
    if frames:
        notes.append(f"scene {scene}: {frames}")
    if stats["frames_selected"] == 1 and stats["frames_posed"] > 1:
        notes.append(
            f"scene {scene}: frame_stride={o.frame_stride} fuses 1 of its "
            f"{stats['frames_posed']} frames with a pose; lower frame_stride to see more of it"
        )
    n = stats["fused_points"]
    if n < o.gt_points:
        visible = (
            f" and {n} visible points instead of surface_candidates={o.surface_candidates}"
            if n < o.surface_candidates
            else ""
        )
        notes.append(
            f"scene {scene}: the fused cloud holds {n} points, fewer than gt_points={o.gt_points}:"
            f" its ground truth has {n} points{visible} (a smaller voxel_size or frame_stride "
            "fuses more)"
        )
    if report.far * 2 > report.measured:
        notes.append(
            f"scene {scene}: {report.far} of {report.measured} depth measurements lie beyond "
            f"max_depth={o.max_depth:g} m and were dropped: check depth_scale (now "
            f"{camera.intrinsics.depth_scale:g} per metre, layout {camera.layout})"
        )
    return [" ".join(note.split()) for note in notes]


def _frames_note(
    listing: FrameListing, report: fusion.FusionReport, stats: dict[str, int], o: ICLNUIMOptions
) -> str | None:
    """Why fewer frames were fused than ``frame_stride`` asks of the frames named, or None.

    A single frame without a pose and nothing else is not worth a warning: ICL-NUIM has no pose
    for its first frame.
    """
    asked, fused = stats["frames_asked"], report.fused
    if fused >= asked:
        return None
    only_first_pose = listing.no_pose <= 1 and not (
        listing.no_file or report.unreadable or report.empty
    )
    if only_first_pose and asked - fused <= 1:
        return None
    why = []
    if listing.no_file:
        why.append(f"{_count(listing.no_file, 'named frame')} without a depth file")
    if listing.no_pose:
        why.append(
            f"{_count(listing.no_pose, 'frame')} without a pose in {listing.trajectory.name}"
        )
    if report.unreadable:
        why.append(f"{_count(len(report.unreadable), 'unusable frame')} ({report.unreadable[0]})")
    if report.empty:
        why.append(f"{_count(report.empty, 'frame')} without a valid depth within max_depth")
    return (
        f"fused {fused} of the {asked} frames asked (frame_stride={o.frame_stride} over "
        f"{listing.listed} frames named): {'; '.join(why)}"
    )


def _count(n: int, noun: str) -> str:
    return f"{n} {noun}" + ("" if n == 1 else "s")


def _failure(ref: ObjectRef, exc: Exception) -> str:
    """The one-line reason a scene failed, naming it."""
    text = str(exc) if isinstance(exc, ObjectLoadError) else f"{type(exc).__name__}: {exc}"
    return f"scene {ref.id}: " + " ".join(text.split())


_BASE_ARRAYS = ("surface_points", "surface_normals", "gt_points")


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
