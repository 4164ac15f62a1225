"""ICL-NUIM sequences on disk, in the TUM RGB-D format the dataset publishes ("*_frei_png").

A sequence is a folder with ``depth/`` (uint16 PNGs, metres = value / depth scale), usually an
``associations.txt`` (lines ``t depth/N.png t rgb/N.png``, either order) and the ground-truth
trajectory ``*.gt.freiburg`` (lines ``t tx ty tz qx qy qz qw``: camera-to-world, TUM format),
which ICL-NUIM publishes as a separate download. Frames are matched to poses by timestamp; frames
whose depth file or pose is missing (ICL-NUIM has no pose for its first frame) are skipped.
"""

from __future__ import annotations

import contextlib
import os
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from shapebench.dataset import ObjectLoadError

DEPTH_DIR = "depth"
ASSOCIATION_FILES = ("associations.txt", "associate.txt", "association.txt")
#: Largest timestamp difference between a depth frame and its pose (TUM's associate.py default).
MAX_TIME_DIFFERENCE = 0.02
MAX_SEARCH_DEPTH = 4  # folder levels below the data root searched for sequences

OBTAIN = (
    "ICL-NUIM (Handa et al., ICRA 2014) is published on its website "
    "(https://www.doc.ic.ac.uk/~ahanda/VaFRIC/iclnuim.html): download the 'TUM RGB-D "
    "compatible' PNG archives of the living-room and office trajectories (e.g. "
    "living_room_traj0_frei_png.tar.gz, traj0_frei_png.tar.gz) and their ground-truth "
    "trajectories (*.gt.freiburg). Extract each archive into its own folder and put its "
    "trajectory next to depth/ and associations.txt; then pass the folder holding the sequences "
    "with --data-root (or SHAPEBENCH_ICL_NUIM_ROOT)."
)


@dataclass(frozen=True)
class Sequence:
    id: str  # folder relative to the data root, "/"-separated (its own name if it is the root)
    folder: Path
    category: str  # "living-room", "office" or "other"
    trajectories: tuple[str, ...]  # candidate trajectory files in the folder


@dataclass(frozen=True)
class Frame:
    timestamp: float
    depth_path: Path
    rotation: np.ndarray  # (3, 3) camera-to-world
    position: np.ndarray  # (3,) camera centre in the world


def discover(root: Path) -> list[Sequence]:
    """Every folder at or below ``root`` that holds a ``depth/`` folder, sorted by id."""
    root = Path(root)
    found = []
    for dirpath, dirnames, filenames in os.walk(root, followlinks=True):
        here = Path(dirpath)
        depth_level = len(here.relative_to(root).parts)
        dirnames[:] = sorted(d for d in dirnames if not d.startswith(".") and d != DEPTH_DIR)
        if depth_level >= MAX_SEARCH_DEPTH:
            dirnames[:] = []
        if not (here / DEPTH_DIR).is_dir():
            continue
        rel = here.relative_to(root).as_posix()
        seq_id = here.resolve().name if rel == "." else rel
        trajectories = tuple(sorted(f for f in filenames if _is_trajectory(f)))
        found.append(Sequence(seq_id, here, category_of(rel, root, trajectories), trajectories))
    return sorted(found, key=lambda s: s.id)


def _is_trajectory(name: str) -> bool:
    return name.endswith(".freiburg") or name == "groundtruth.txt"


def category_of(rel: str, root: Path, trajectories: tuple[str, ...]) -> str:
    """The scene type from the folder names and trajectory name, as ICL-NUIM names them.

    ICL-NUIM calls living-room archives ``living_room_traj<k>_frei_png`` (trajectories
    ``livingRoom<k>.gt.freiburg``) and office archives plain ``traj<k>_frei_png``.
    """
    names = " ".join([Path(root).resolve().name, rel, *trajectories]).lower()
    if "living" in names:
        return "living-room"
    if "office" in names or re.search(r"(^|[^a-z])traj\d", names):
        return "office"
    return "other"


def read_frames(seq: Sequence) -> tuple[list[Frame], int]:
    """The frames of ``seq`` that have a depth file and a pose, in time order, and how many
    listed frames were skipped for lacking one of them."""
    trajectory = _trajectory_file(seq)
    poses = read_trajectory(trajectory)
    listed = _depth_frames(seq.folder)
    if not listed:
        raise ObjectLoadError(f"sequence {seq.folder} has no depth frames in {DEPTH_DIR}/")
    times = poses[:, 0]
    frames = []
    for t, rel in listed:
        path = seq.folder / rel
        j = _nearest(times, t)
        if abs(times[j] - t) > MAX_TIME_DIFFERENCE or not path.is_file():
            continue
        frames.append(Frame(t, path, quaternion_matrix(poses[j, 4:8]), poses[j, 1:4].copy()))
    if not frames:
        raise ObjectLoadError(
            f"no depth frame of {seq.folder} has both its file and a pose in {trajectory.name} "
            f"({len(listed)} frames listed, {len(times)} poses)"
        )
    return frames, len(listed) - len(frames)


def _nearest(times: np.ndarray, t: float) -> int:
    """Index of the timestamp closest to ``t`` in the sorted ``times``."""
    i = int(np.searchsorted(times, t))
    candidates = [k for k in (i - 1, i) if 0 <= k < len(times)]
    return min(candidates, key=lambda k: abs(times[k] - t))


def _trajectory_file(seq: Sequence) -> Path:
    if len(seq.trajectories) == 1:
        return seq.folder / seq.trajectories[0]
    if not seq.trajectories:
        raise ObjectLoadError(
            f"sequence {seq.folder} has no ground-truth trajectory (*.gt.freiburg); ICL-NUIM "
            "publishes it as a separate download: put it next to depth/"
        )
    gt = [t for t in seq.trajectories if t.endswith(".gt.freiburg")]
    if len(gt) == 1:
        return seq.folder / gt[0]
    raise ObjectLoadError(
        f"sequence {seq.folder} has several trajectories ({', '.join(seq.trajectories)}); "
        "keep only the ground truth of this sequence"
    )


def read_trajectory(path: Path) -> np.ndarray:
    """``(n, 8)`` rows ``t tx ty tz qx qy qz qw`` sorted by time."""
    rows = []
    for number, line in enumerate(path.read_text().splitlines(), 1):
        line = line.strip()
        if not line or line.startswith("#"):
            continue
        parts = line.replace(",", " ").split()
        try:
            values = [float(p) for p in parts]
        except ValueError:
            values = []
        if len(values) != 8:
            raise ObjectLoadError(
                f"{path}:{number}: expected 't tx ty tz qx qy qz qw', got {line[:60]!r}"
            )
        rows.append(values)
    if not rows:
        raise ObjectLoadError(f"trajectory {path} has no poses")
    poses = np.asarray(rows, dtype=np.float64)
    return poses[np.argsort(poses[:, 0], kind="stable")]


def quaternion_matrix(q: np.ndarray) -> np.ndarray:
    """Rotation matrix of the TUM quaternion ``(qx, qy, qz, qw)`` (normalised first)."""
    x, y, z, w = np.asarray(q, dtype=np.float64) / np.linalg.norm(q)
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )


def _depth_frames(folder: Path) -> list[tuple[float, str]]:
    """(timestamp, depth path relative to the sequence) from the associations file, or from the
    depth file names (TUM names frames by timestamp) when there is none."""
    for name in ASSOCIATION_FILES:
        path = folder / name
        if path.is_file():
            return _read_associations(path)
    out = []
    for p in sorted((folder / DEPTH_DIR).glob("*.png")):
        try:
            out.append((float(p.stem), f"{DEPTH_DIR}/{p.name}"))
        except ValueError:
            continue
    return sorted(out)


def _read_associations(path: Path) -> list[tuple[float, str]]:
    out = []
    for line in path.read_text().splitlines():
        parts = line.split("#", 1)[0].split()
        for t, rel in zip(parts[0::2], parts[1::2], strict=False):
            if rel.replace("\\", "/").split("/")[0] == DEPTH_DIR:
                with contextlib.suppress(ValueError):
                    out.append((float(t), rel))
                break
    return sorted(out)


def signature(seq: Sequence) -> tuple[str, int, int]:
    """A cheap identity of a sequence's data: (id, depth files, trajectory bytes)."""
    n_depth = sum(1 for _ in (seq.folder / DEPTH_DIR).glob("*.png"))
    size = sum((seq.folder / t).stat().st_size for t in seq.trajectories)
    return seq.id, n_depth, size
