"""RGB-D sequences on disk, in the two layouts users have them in.

**TUM layout** (``tum``), ICL-NUIM's own release ("*_frei_png"): a folder with ``depth/`` (uint16
PNGs, metres = value / depth scale, 5000 for ICL-NUIM), usually an ``associations.txt`` (lines
``t depth/N.png t rgb/N.png``, either order) and the ground-truth trajectory ``*.gt.freiburg`` or
``groundtruth.txt`` (lines ``t tx ty tz qx qy qz qw``: camera-to-world), which ICL-NUIM publishes
as a separate download. Frames are matched to poses by timestamp.

**Redwood layout** (``redwood``), used by the Redwood data, Open3D's RGB-D samples and Choi et
al.'s re-release of the ICL-NUIM living rooms: ``depth/`` holding uint16 PNGs in millimetres
named by number (``00000.png``...), and a ``.log`` trajectory (``trajectory.log``,
``livingroom1-traj.txt``...): blocks of five lines, a metadata line of three integers (the third is
the frame number, counted from 1) and the four rows of a camera-to-world matrix. The depth files
count from 0 as Redwood and Open3D name them (``00000.png`` is frame 1), unless the lowest number
is 1, then they count from 1. The re-release's own folders are read too:
``livingroom1-depth-clean/`` holding the PNGs directly, with ``livingroom1-traj.txt`` beside it.
A camera file in Open3D's format (``{"width", "height", "intrinsic_matrix": 9 numbers
column-major}``, e.g. ``camera_intrinsic.json`` or ``camera_primesense.json``) beside the frames
gives the intrinsics.

The layout of a sequence is detected from the content of its trajectory file (:func:`sniff`), so a
``.log`` named ``*-traj.txt`` is read as one. Frames whose depth file or pose is missing (ICL-NUIM
has no pose for its first frame) are skipped and counted (:class:`FrameListing`).
"""

from __future__ import annotations

import contextlib
import json
import os
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from shapebench.api.dataset import ObjectLoadError

AUTO, TUM, REDWOOD = "auto", "tum", "redwood"
LAYOUTS = (AUTO, TUM, REDWOOD)

DEPTH_DIR = "depth"
ASSOCIATION_FILES = ("associations.txt", "associate.txt", "association.txt")
#: Largest timestamp difference between a depth frame and its pose (TUM's associate.py default).
MAX_TIME_DIFFERENCE = 0.02
MAX_SEARCH_DEPTH = 4  # folder levels below the data root searched for sequences
#: What a trajectory file may be called; its content decides its layout.
TRAJECTORY_PATTERNS = (
    "*.gt.freiburg",
    "*.freiburg",
    "groundtruth.txt",
    "*.log",
    "traj.txt",
    "trajectory.txt",
    "*-traj.txt",
    "*_traj.txt",
)
#: A folder of depth PNGs named like Choi et al.'s re-release: ``livingroom1-depth-clean``.
_DEPTH_FOLDER = re.compile(r"^(?P<scene>.+?)-depth(-[a-z]+)?$", re.IGNORECASE)
_NUMBER = re.compile(r"(\d+)(?!.*\d)")  # the last group of digits of a name

OBTAIN = (
    "ICL-NUIM (Handa et al., ICRA 2014) is published on its website "
    "(https://www.doc.ic.ac.uk/~ahanda/VaFRIC/iclnuim.html): download the 'TUM RGB-D "
    "compatible' PNG archives of the living-room and office trajectories (e.g. "
    "living_room_traj0_frei_png.tar.gz, traj0_frei_png.tar.gz) and their ground-truth "
    "trajectories (*.gt.freiburg). Extract each archive into its own folder and put its "
    "trajectory next to depth/ and associations.txt. Sequences in the Redwood layout (Open3D's "
    "RGB-D samples, Choi et al.'s ICL-NUIM re-release: depth/ in millimetres and a .log "
    "trajectory such as trajectory.log or livingroom1-traj.txt) are read too. Then pass the "
    "folder holding the sequences with --data-root (or SHAPEBENCH_ICL_NUIM_ROOT)."
)


@dataclass(frozen=True)
class Sequence:
    id: str  # folder relative to the data root, "/"-separated (its own name if it is the root)
    folder: Path  # where the trajectory and the camera file are looked for
    category: str  # "living-room", "office" or "other"
    trajectories: tuple[Path, ...]  # candidate trajectory files (see TRAJECTORY_PATTERNS)
    depth_dir: Path  # the folder holding the depth PNGs
    camera_files: tuple[Path, ...] = ()  # candidate Open3D camera files (*.json)


@dataclass(frozen=True)
class Frame:
    timestamp: float  # TUM: the frame's time; Redwood: its frame number (from 1)
    depth_path: Path
    rotation: np.ndarray  # (3, 3) camera-to-world
    position: np.ndarray  # (3,) camera centre in the world


@dataclass(frozen=True)
class Trajectory:
    path: Path
    layout: str  # TUM or REDWOOD


@dataclass(frozen=True)
class FrameListing:
    """The usable frames of a sequence and what kept the others out."""

    frames: list[Frame]  # frames with a depth file and a pose, in order
    listed: int  # frames the sequence names (depth files, associations, trajectory entries)
    no_file: int  # named frames without a depth file
    no_pose: int  # frames with a depth file but no pose
    trajectory: Path


@dataclass(frozen=True)
class CameraFile:
    """Intrinsics read from an Open3D camera file."""

    path: Path
    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float


# ---------------------------------------------------------------------------- discovery


def discover(root: Path) -> list[Sequence]:
    """Every sequence at or below ``root`` (a folder holding ``depth/``, or a re-release folder
    ``<scene>-depth*`` of PNGs), sorted by id."""
    root = Path(root)
    found = []
    for dirpath, dirnames, filenames in os.walk(root, followlinks=True):
        here = Path(dirpath)
        depth_level = len(here.relative_to(root).parts)
        dirnames[:] = sorted(d for d in dirnames if not d.startswith(".") and d != DEPTH_DIR)
        if depth_level >= MAX_SEARCH_DEPTH:
            dirnames[:] = []
        seq = _sequence_at(root, here, filenames)
        if seq is not None:
            found.append(seq)
    return sorted(found, key=lambda s: s.id)


def _sequence_at(root: Path, here: Path, filenames: list[str]) -> Sequence | None:
    named = _DEPTH_FOLDER.match(here.name)
    if (here / DEPTH_DIR).is_dir():
        depth_dir = here / DEPTH_DIR
    elif named and any(f.lower().endswith(".png") for f in filenames):
        depth_dir = here
    else:
        return None
    files = [here / f for f in sorted(filenames)]
    trajectories = [p for p in files if _is_trajectory(p.name)]
    cameras = [p for p in files if p.suffix.lower() == ".json"]
    if named:  # the re-release keeps livingroom1-traj.txt beside livingroom1-depth-clean/
        scene = named.group("scene")
        trajectories += [p for p in _beside(here, scene) if _is_trajectory(p.name)]
        cameras += [p for p in _beside(here, scene) if p.suffix.lower() == ".json"]
    rel = here.relative_to(root).as_posix()
    seq_id = here.resolve().name if rel == "." else rel
    names = tuple(p.name for p in trajectories)
    return Sequence(
        seq_id,
        here,
        category_of(rel, root, names),
        tuple(trajectories),
        depth_dir,
        tuple(cameras),
    )


def _beside(folder: Path, scene: str) -> list[Path]:
    """Files next to ``folder`` named after its scene (``livingroom1-traj.txt``, not
    ``livingroom10-traj.txt``)."""
    own = re.compile(re.escape(scene) + r"([-_.]|$)", re.IGNORECASE)
    try:
        return sorted(p for p in folder.parent.iterdir() if p.is_file() and own.match(p.name))
    except OSError:
        return []


def _is_trajectory(name: str) -> bool:
    return any(Path(name).match(pattern) for pattern in TRAJECTORY_PATTERNS)


def category_of(rel: str, root: Path, trajectories: tuple[str, ...]) -> str:
    """The scene type from the folder names and trajectory name, as ICL-NUIM names them.

    ICL-NUIM calls living-room archives ``living_room_traj<k>_frei_png`` (trajectories
    ``livingRoom<k>.gt.freiburg``) and office archives plain ``traj<k>_frei_png``; the re-release
    calls them ``livingroom<k>`` and ``office<k>``.
    """
    names = " ".join([Path(root).resolve().name, rel, *trajectories]).lower()
    if "living" in names:
        return "living-room"
    if "office" in names or re.search(r"(^|[^a-z])traj\d", names):
        return "office"
    return "other"


def signature(seq: Sequence) -> tuple[str, int, int]:
    """A cheap identity of a sequence's data: (id, depth files, trajectory bytes)."""
    n_depth = sum(1 for _ in seq.depth_dir.glob("*.png"))
    size = sum(t.stat().st_size for t in seq.trajectories if t.is_file())
    return seq.id, n_depth, size


# ---------------------------------------------------------------------------- layout


def sniff(path: Path) -> str | None:
    """The layout a trajectory file is written in (TUM or REDWOOD), from its first lines, or
    None when it is neither (or unreadable)."""
    try:
        with open(path, encoding="utf-8", errors="replace") as f:
            head = f.read(4096)
    except OSError:
        return None
    rows = [
        line.replace(",", " ").split()
        for line in head.splitlines()
        if line.strip() and not line.lstrip().startswith("#")
    ][:5]
    if rows and len(rows[0]) == 8 and all(_is_number(v) for v in rows[0]):
        return TUM
    if (
        len(rows) == 5
        and len(rows[0]) == 3
        and all(v.lstrip("-").isdigit() for v in rows[0])
        and all(len(r) == 4 and all(_is_number(v) for v in r) for r in rows[1:])
    ):
        return REDWOOD
    return None


def _is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


def find_trajectory(seq: Sequence, layout: str = AUTO) -> Trajectory:
    """The ground-truth trajectory of ``seq`` and its layout (``layout`` AUTO: from its content).

    Raises :class:`ObjectLoadError` with one line naming what was looked for and the fix.
    """
    kinds = {p: sniff(p) for p in seq.trajectories}
    by_layout = {k: [p for p, kind in kinds.items() if kind == k] for k in (TUM, REDWOOD)}
    if layout == AUTO:
        present = [k for k in (TUM, REDWOOD) if by_layout[k]]
        if len(present) > 1:
            raise ObjectLoadError(
                f"both a TUM trajectory ({_names(by_layout[TUM])}) and a .log trajectory "
                f"({_names(by_layout[REDWOOD])}) in {seq.folder}: set the dataset option "
                "layout=tum or layout=redwood"
            )
        if not present:
            raise ObjectLoadError(_no_trajectory(seq, kinds))
        layout = present[0]
    candidates = by_layout[layout]
    if not candidates:
        other = by_layout[REDWOOD if layout == TUM else TUM]
        if other:
            raise ObjectLoadError(
                f"layout={layout} but the trajectory in {seq.folder} is "
                f"{_names(other)} in the {REDWOOD if layout == TUM else TUM} format: set "
                "layout=auto"
            )
        raise ObjectLoadError(_no_trajectory(seq, kinds))
    return Trajectory(_preferred(seq, candidates, layout), layout)


def _names(paths: list[Path]) -> str:
    return ", ".join(p.name for p in paths)


def _no_trajectory(seq: Sequence, kinds: dict[Path, str | None]) -> str:
    unreadable = [p for p, kind in kinds.items() if kind is None]
    found = (
        f"; {_names(unreadable)} is neither a TUM ('t tx ty tz qx qy qz qw') nor a .log trajectory"
        if unreadable
        else ""
    )
    return (
        f"no camera trajectory in {seq.folder} (looked for {', '.join(TRAJECTORY_PATTERNS)})"
        f"{found}; put the sequence's ground-truth trajectory beside {DEPTH_DIR}/ (ICL-NUIM "
        "publishes *.gt.freiburg as a separate download)"
    )


def _preferred(seq: Sequence, candidates: list[Path], layout: str) -> Path:
    """The one trajectory among several candidates: ICL-NUIM's ``*.gt.freiburg`` for TUM, the one
    named ``*traj*`` for Redwood (Open3D's samples hold ``trajectory.log`` and ``odometry.log``)."""
    if len(candidates) == 1:
        return candidates[0]
    if layout == TUM:
        best = [p for p in candidates if p.name.endswith(".gt.freiburg")]
    else:
        best = [p for p in candidates if "traj" in p.name.lower()]
    if len(best) == 1:
        return best[0]
    raise ObjectLoadError(
        f"{seq.folder} has several trajectories ({_names(candidates)}); keep only the "
        "ground truth of this sequence"
    )


# ---------------------------------------------------------------------------- frames


def read_frames(seq: Sequence) -> tuple[list[Frame], int]:
    """The usable frames of ``seq`` (layout detected) and how many named frames were skipped."""
    listing = list_frames(seq, find_trajectory(seq))
    return listing.frames, listing.no_file + listing.no_pose


def list_frames(seq: Sequence, trajectory: Trajectory) -> FrameListing:
    """The frames of ``seq`` that have a depth file and a pose in ``trajectory``, in order."""
    if trajectory.layout == REDWOOD:
        listing = _redwood_frames(seq, trajectory.path)
    else:
        listing = _tum_frames(seq, trajectory.path)
    if not listing.frames:
        raise ObjectLoadError(
            f"no depth frame of {seq.folder} has both its file and a pose in "
            f"{trajectory.path.name} ({listing.listed} frames named, {listing.no_file} without "
            f"a depth file, {listing.no_pose} without a pose)"
        )
    return listing


def _tum_frames(seq: Sequence, trajectory: Path) -> FrameListing:
    poses = read_trajectory(trajectory)
    listed = _depth_frames(seq)
    if not listed:
        raise ObjectLoadError(f"sequence {seq.folder} has no depth frames in {DEPTH_DIR}/")
    times = poses[:, 0]
    frames, no_file, no_pose = [], 0, 0
    for t, path in listed:
        j = _nearest(times, t)
        if not path.is_file():
            no_file += 1
        elif abs(times[j] - t) > MAX_TIME_DIFFERENCE:
            no_pose += 1
        else:
            frames.append(Frame(t, path, quaternion_matrix(poses[j, 4:8]), poses[j, 1:4].copy()))
    return FrameListing(frames, len(listed), no_file, no_pose, trajectory)


def _redwood_frames(seq: Sequence, trajectory: Path) -> FrameListing:
    numbers, matrices = read_log(trajectory)
    files = numbered_depth_files(seq.depth_dir)
    if not files:
        raise ObjectLoadError(
            f"sequence {seq.folder} has no numbered depth PNGs in {seq.depth_dir}"
        )
    # Redwood and Open3D name files from 0 (00000.png is frame 1); some copies count from 1.
    offset = 0 if min(files) == 1 else 1
    by_frame = {k + offset: path for k, path in files.items()}
    poses = dict(zip(numbers.tolist(), matrices, strict=True))
    frames = [
        Frame(float(n), by_frame[n], poses[n][:3, :3].copy(), poses[n][:3, 3].copy())
        for n in sorted(by_frame)
        if n in poses
    ]
    named = len(set(by_frame) | set(poses))
    no_file = len(set(poses) - set(by_frame))
    no_pose = len(set(by_frame) - set(poses))
    return FrameListing(frames, named, no_file, no_pose, trajectory)


def numbered_depth_files(folder: Path) -> dict[int, Path]:
    """The PNGs of ``folder`` by the number in their name (files without one are ignored)."""
    out: dict[int, Path] = {}
    for p in sorted(folder.glob("*.png")):
        match = _NUMBER.search(p.stem)
        if match is None:
            continue
        k = int(match.group(1))
        if k in out:
            raise ObjectLoadError(f"{out[k].name} and {p.name} in {folder} are both frame {k}")
        out[k] = p
    return out


def _nearest(times: np.ndarray, t: float) -> int:
    """Index of the timestamp closest to ``t`` in the sorted ``times``."""
    i = int(np.searchsorted(times, t))
    candidates = [k for k in (i - 1, i) if 0 <= k < len(times)]
    return min(candidates, key=lambda k: abs(times[k] - t))


def read_trajectory(path: Path) -> np.ndarray:
    """``(n, 8)`` rows ``t tx ty tz qx qy qz qw`` of a TUM trajectory, sorted by time."""
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


def read_log(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """Frame numbers (from 1) and ``(n, 4, 4)`` camera-to-world matrices of a ``.log`` trajectory.

    The third metadata integer numbers the frame from 1 (Redwood's convention); a file that
    numbers a frame 0 counts from 0, and is shifted to count from 1.
    """
    lines = [
        (number, line.split())
        for number, line in enumerate(path.read_text().splitlines(), 1)
        if line.strip() and not line.lstrip().startswith("#")
    ]
    if not lines or len(lines) % 5:
        raise ObjectLoadError(
            f"{path}: {len(lines)} lines, expected blocks of 5 (a line 'id id frame' and the 4 "
            "rows of a camera-to-world matrix)"
        )
    frames, matrices = [], []
    for start in range(0, len(lines), 5):
        number, meta = lines[start]
        if len(meta) != 3 or not all(v.lstrip("-").isdigit() for v in meta):
            raise ObjectLoadError(f"{path}:{number}: expected 3 integers 'id id frame'")
        rows = lines[start + 1 : start + 5]
        try:
            matrix = np.array([[float(v) for v in r] for _, r in rows], dtype=np.float64)
        except ValueError:
            matrix = np.empty(0)
        if matrix.shape != (4, 4) or not np.isfinite(matrix).all():
            raise ObjectLoadError(f"{path}:{rows[0][0]}: expected 4 rows of 4 numbers")
        frames.append(int(meta[2]))
        matrices.append(matrix)
    numbers = np.asarray(frames)
    if len(set(frames)) != len(frames):
        raise ObjectLoadError(
            f"{path} numbers a frame twice in its metadata lines: not a camera trajectory"
        )
    if numbers.min() == 0:
        numbers = numbers + 1
    return numbers, np.stack(matrices)


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


def _depth_frames(seq: Sequence) -> list[tuple[float, Path]]:
    """(timestamp, depth path) from the associations file, or from the depth file names (TUM
    names frames by timestamp) when there is none."""
    for name in ASSOCIATION_FILES:
        path = seq.folder / name
        if path.is_file():
            return [(t, seq.folder / rel) for t, rel in _read_associations(path)]
    out = []
    for p in sorted(seq.depth_dir.glob("*.png")):
        with contextlib.suppress(ValueError):
            out.append((float(p.stem), p))
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


# ---------------------------------------------------------------------------- camera file


def read_camera_file(seq: Sequence) -> CameraFile | None:
    """The intrinsics of the Open3D camera file beside ``seq`` (``*.json`` holding
    ``intrinsic_matrix``), or None when there is none; ``camera_intrinsic.json`` wins a tie."""
    found = [c for c in (_camera_file(p) for p in seq.camera_files) if c is not None]
    if len(found) > 1:
        preferred = [c for c in found if c.path.name == "camera_intrinsic.json"]
        if len(preferred) != 1:
            raise ObjectLoadError(
                f"several camera files in {seq.folder} ({_names([c.path for c in found])}); "
                "keep one, or set the intrinsics with the options fx, fy, cx, cy"
            )
        found = preferred
    return found[0] if found else None


def _camera_file(path: Path) -> CameraFile | None:
    """``path`` read as an Open3D camera file; None if it is some other JSON file."""
    try:
        data = json.loads(path.read_text())
    except (OSError, ValueError):
        return None
    if not isinstance(data, dict) or "intrinsic_matrix" not in data:
        return None
    try:
        m = [float(v) for v in data["intrinsic_matrix"]]  # column-major 3x3
        width, height = int(data.get("width", 0)), int(data.get("height", 0))
    except (TypeError, ValueError):
        m, width, height = [], 0, 0
    if len(m) != 9 or m[0] == 0 or m[4] == 0:
        raise ObjectLoadError(
            f"camera file {path}: 'intrinsic_matrix' must hold 9 numbers (column-major 3x3) with "
            "non-zero focal lengths"
        )
    return CameraFile(path, width, height, m[0], m[4], m[6], m[7])
