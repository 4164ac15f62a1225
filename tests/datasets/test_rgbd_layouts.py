"""The ``icl-nuim`` dataset on RGB-D data as users have it: the TUM layout (ICL-NUIM's release) and
the Redwood layout (Open3D's samples, Choi et al.'s ICL-NUIM re-release), invalid depth codes,
and what it says when a scene is fused from less than was asked.

The scene is an empty box room whose depth is computed exactly (a ray from inside a box leaves it
through the nearest wall), so every fused point must lie on a wall and none outside the room.
"""

from __future__ import annotations

import json
import sys
import warnings
from pathlib import Path

import imageio.v3 as iio
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

try:
    import shapebench_iclnuim  # noqa: F401
except ModuleNotFoundError:  # the checkout was installed before this plugin existed
    sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "datasets"))

from shapebench_iclnuim.dataset import ICLNUIMDataset, ICLNUIMOptions  # noqa: E402

from shapebench.api.dataset import ObjectLoadError  # noqa: E402
from shapebench.api.errors import ConfigError  # noqa: E402
from shapebench.api.types import ObjectRef  # noqa: E402

W, H = 640, 480
LO = np.array([-2.0, -1.2, -2.5])  # the room's walls, floor and ceiling (metres)
HI = np.array([2.2, 1.4, 3.0])
ICL = (481.20, -480.00, 319.5, 239.5)  # ICL-NUIM's camera (TUM layout, depth x5000)
PRIMESENSE = (525.0, 525.0, 319.5, 239.5)  # Open3D's default (Redwood layout, depth in mm)
POSES = [  # (position, target), inside the room
    ((0.0, 0.0, 0.0), (1.0, -0.5, -2.0)),
    ((0.5, 0.3, 1.0), (-1.5, 0.0, -2.0)),
    ((-1.0, 0.2, -1.0), (2.0, -1.0, 2.0)),
    ((1.2, 0.8, 2.0), (-1.0, -1.0, -1.0)),
    ((-0.5, -0.2, 1.5), (0.0, 1.0, -2.5)),
]
SMALL = {"surface_candidates": 2000, "gt_points": 2000, "frame_stride": 1, "voxel_size": 0.05}


def look_at(position, target) -> np.ndarray:
    """Camera-to-world rotation whose z axis looks at ``target``."""
    z = np.asarray(target, float) - position
    z /= np.linalg.norm(z)
    x = np.cross((0.0, 1.0, 0.0), z)
    x /= np.linalg.norm(x)
    return np.column_stack([x, np.cross(z, x), z])


def box_depth(camera, rotation: np.ndarray, position: np.ndarray) -> np.ndarray:
    """Exact depth (metres along the optical axis) of the room seen through ``camera``."""
    fx, fy, cx, cy = camera
    v, u = np.mgrid[0:H, 0:W]
    rays = np.stack([(u - cx) / fx, (v - cy) / fy, np.ones((H, W))], -1).reshape(-1, 3)
    d = rays @ rotation.T  # camera z component 1: the distance along d is the depth
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.where(d > 0, (HI - position) / d, (LO - position) / d)
    t[d == 0] = np.inf
    return t.min(axis=1).reshape(H, W)


def spoil(raw: np.ndarray, scale: float) -> np.ndarray:
    """Sensor artefacts: pixels with no measurement (0), the invalid code 65535, and a few
    real-looking depths 12 m away (beyond the default max_depth)."""
    raw = raw.copy()
    raw[:20, :] = 0
    raw[100:140, 200:400] = 65535
    raw[300:310, 50:60] = int(12.0 * scale)
    return raw


def poses():
    for position, target in POSES:
        position = np.asarray(position, float)
        yield position, look_at(position, target)


def write_redwood(folder: Path, camera=PRIMESENSE, skip_pose=(), depth_dir=None, log=None):
    """Open3D's sample layout: depth/00000.png... in millimetres and trajectory.log, whose
    metadata lines number frames from 1; frames in ``skip_pose`` (0-based) get no pose."""
    depth_dir = depth_dir or folder / "depth"
    depth_dir.mkdir(parents=True)
    blocks = []
    for k, (position, rotation) in enumerate(poses()):
        raw = np.round(box_depth(camera, rotation, position) * 1000.0).astype("<u2")
        iio.imwrite(depth_dir / f"{k:05d}.png", spoil(raw, 1000.0))
        if k in skip_pose:
            continue
        matrix = np.eye(4)
        matrix[:3, :3], matrix[:3, 3] = rotation, position
        rows = "\n".join(" ".join(f"{v:.10f}" for v in row) for row in matrix)
        blocks.append(f"{k} {k} {k + 1}\n{rows}")
    (log or folder / "trajectory.log").write_text("\n".join(blocks) + "\n")


def write_tum(folder: Path, frames=5, files=None, posed=None):
    """ICL-NUIM's layout: associations.txt, depth x5000 named by timestamp, *.gt.freiburg."""
    files = set(range(1, frames + 1)) if files is None else set(files)
    posed = set(range(2, frames + 1)) if posed is None else set(posed)  # no pose for frame 1
    (folder / "depth").mkdir(parents=True)
    assoc, traj = [], []
    for i, (position, rotation) in enumerate(poses(), start=1):
        if i > frames:
            break
        assoc.append(f"{i} depth/{i}.png {i} rgb/{i}.png")
        if i in files:
            raw = np.round(box_depth(ICL, rotation, position) * 5000.0).astype("<u2")
            iio.imwrite(folder / "depth" / f"{i}.png", spoil(raw, 5000.0))
        if i in posed:
            qx, qy, qz, qw = Rotation.from_matrix(rotation).as_quat()
            traj.append(f"{i} {position[0]} {position[1]} {position[2]} {qx} {qy} {qz} {qw}")
    (folder / "associations.txt").write_text("\n".join(assoc) + "\n")
    (folder / "livingRoom0.gt.freiburg").write_text("\n".join(traj) + "\n")


def dataset(root, cache, **options) -> ICLNUIMDataset:
    return ICLNUIMDataset(ICLNUIMOptions(**(SMALL | options)), cache, root)


def world_points(ds: ICLNUIMDataset, ref: ObjectRef):
    """The scene's surface and ground-truth points back in metres, and the scene."""
    data = ds.load(ref)
    with np.load(ds.cache_path(ref)) as cached:
        center, scale = cached["center"], float(cached["scale"])
    pts = np.concatenate([data.surface_points, data.gt_points]).astype(np.float64)
    return pts * scale + center, data


def wall_distance(points: np.ndarray) -> np.ndarray:
    """Distance of each point to the nearest wall of the room, and how far outside it is."""
    inside = np.minimum(points - LO, HI - points).min(axis=1)
    return np.abs(inside)


def assert_on_walls(points: np.ndarray) -> None:
    assert (points >= LO - 0.01).all() and (points <= HI + 0.01).all(), "points outside the room"
    assert wall_distance(points).max() < 0.005  # millimetre depth: every point on a wall


def camera(ds: ICLNUIMDataset, ref: ObjectRef) -> dict[str, str]:
    """The scene's resolved camera, as the dataset's identity records it."""
    return dict(word.split("=") for word in ds.cameras()[ref.id].split())


def load_quietly(ds, ref):
    """Load with warnings recorded; returns the data and the warning messages."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        data = ds.load(ref)
    return data, [str(w.message) for w in caught]


# ---------------------------------------------------------------------------- Redwood layout


def test_redwood_layout_is_detected_and_fused_onto_the_walls(tmp_path):
    """Open3D's sample layout, with the PrimeSense camera and depth in millimetres by default;
    the .log numbers frames from 1, and the frame without a pose (00002.png) is left out."""
    root = tmp_path / "data"
    write_redwood(root / "SampleRedwoodRGBDImages", skip_pose=(2,))
    ds = dataset(root, tmp_path / "cache")
    ref = ObjectRef("SampleRedwoodRGBDImages", "other")
    assert ds.objects("all") == [ref]
    points, data = world_points(ds, ref)
    assert_on_walls(points)  # 0, 65535 and depths beyond 10 m are dropped
    assert str(data.extra["layout"]) == "redwood"
    assert data.extra["intrinsics"].tolist() == [525.0, 525.0, 319.5, 239.5, 1000.0]
    assert int(data.extra["frames_fused"]) == 4 and int(data.extra["frames_listed"]) == 5
    assert camera(ds, ref)["layout"] == "redwood"


def test_redwood_camera_file_and_options_set_the_intrinsics(tmp_path):
    """Open3D's camera file beside the frames wins over the layout default; a non-zero option
    wins over both; what each scene resolves to is in the fingerprint."""
    lens = (480.0, 480.0, 320.0, 240.0)
    with_file, without = tmp_path / "a", tmp_path / "b"
    for root in (with_file, without):
        write_redwood(root / "seq", camera=lens)
        (root / "seq" / "odometry.log").write_text((root / "seq" / "trajectory.log").read_text())
    intrinsic = [480.0, 0, 0, 0, 480.0, 0, 320.0, 240.0, 1]  # column-major, as Open3D writes it
    spec = {"width": W, "height": H, "intrinsic_matrix": intrinsic}
    (with_file / "seq" / "camera_primesense.json").write_text(json.dumps(spec))

    ds = dataset(with_file, tmp_path / "cache")
    ref = ds.objects("all")[0]
    points, data = world_points(ds, ref)
    assert_on_walls(points)
    assert data.extra["intrinsics"].tolist() == [480.0, 480.0, 320.0, 240.0, 1000.0]
    assert camera(ds, ref)["trajectory"] == "trajectory.log"  # not odometry.log

    plain = dataset(without, tmp_path / "cache")
    assert camera(plain, ref)["fx"] == "525"
    assert plain.data_fingerprint() != ds.data_fingerprint()
    given = dataset(with_file, tmp_path / "cache", fx=500.0, depth_scale=1000.0)
    assert camera(given, ref)["fx"] == "500"
    assert camera(given, ref) | {"fx": "480"} == camera(ds, ref)


def test_icl_nuim_re_release_folders_are_read(tmp_path):
    """Choi et al.'s re-release: livingroom1-depth-clean/ of PNGs, livingroom1-traj.txt beside."""
    root = tmp_path / "data"
    root.mkdir()
    write_redwood(
        root, depth_dir=root / "livingroom1-depth-clean", log=root / "livingroom1-traj.txt"
    )
    ds = dataset(root, tmp_path / "cache")
    ref = ObjectRef("livingroom1-depth-clean", "living-room")
    assert ds.objects("all") == [ref]
    points, data = world_points(ds, ref)
    assert_on_walls(points)
    assert str(data.extra["layout"]) == "redwood" and int(data.extra["frames_fused"]) == 5

    unzipped = tmp_path / "unzipped"  # unzip livingroom1-depth-clean.zip -d depth
    write_redwood(
        unzipped / "living_room_1", log=unzipped / "living_room_1" / "livingroom1-traj.txt"
    )
    ds = dataset(unzipped, tmp_path / "cache")
    ref = ObjectRef("living_room_1", "living-room")
    assert ds.objects("all") == [ref]
    assert camera(ds, ref)["layout"] == "redwood"


def test_layout_option_picks_or_refuses_a_layout(tmp_path):
    root = tmp_path / "data"
    write_redwood(root / "seq")
    ref = ObjectRef("seq", "other")
    with pytest.raises(ObjectLoadError, match=r"^scene seq: layout=tum .* set layout=auto"):
        dataset(root, tmp_path / "c1", layout="tum").load(ref)
    assert str(dataset(root, tmp_path / "c2", layout="redwood").load(ref).extra["layout"]) == (
        "redwood"
    )
    with pytest.raises(ConfigError, match="layout"):
        dataset(root, tmp_path / "c3", layout="kinect")
    write_tum(root / "both")
    (root / "both" / "trajectory.log").write_text((root / "seq" / "trajectory.log").read_text())
    with pytest.raises(
        ObjectLoadError, match="set the dataset option layout=tum or layout=redwood"
    ):
        dataset(root, tmp_path / "c4").load(ObjectRef("both", "living-room"))


# ---------------------------------------------------------------------------- invalid depth


def test_tum_invalid_codes_and_far_depths_are_dropped(tmp_path):
    """65535 / 5000 would be a wall 13 m away and 12 m readings lie beyond max_depth (10 m):
    neither may reach the scene, whose normalisation radius is then the room's."""
    root = tmp_path / "data"
    write_tum(root / "living_room_traj0_frei_png")
    ds = dataset(root, tmp_path / "cache")
    points, data = world_points(ds, ds.objects("all")[0])
    assert_on_walls(points)
    assert float(data.extra["scale"]) < np.linalg.norm(HI - LO)
    assert str(data.extra["layout"]) == "tum"
    assert data.extra["intrinsics"].tolist() == [481.20, -480.0, 319.5, 239.5, 5000.0]


def test_max_depth_zero_keeps_far_depths_but_never_invalid_codes(tmp_path):
    root = tmp_path / "data"
    write_tum(root / "living_room_traj0_frei_png")
    ds = dataset(root, tmp_path / "cache", max_depth=0.0)
    points, _ = world_points(ds, ds.objects("all")[0])
    outside = points[wall_distance(points) > 0.01]
    assert len(outside)  # the 12 m readings are kept...
    depth = np.stack([(outside - pos) @ rot[:, 2] for pos, rot in poses()], axis=1)
    assert (np.abs(depth - 12.0).min(axis=1) < 0.01).all()  # ...and 65535 (13.1 m) is not


# ---------------------------------------------------------------------------- warnings


def test_warns_when_fewer_frames_are_fused_than_asked(tmp_path):
    """7 frames named; 3 have no depth file, frame 1 has no pose: 3 fused of 7 asked."""
    root = tmp_path / "data"
    write_tum(root / "living_room_traj0_frei_png", frames=5, files=range(1, 5), posed=range(2, 6))
    assoc = root / "living_room_traj0_frei_png" / "associations.txt"
    assoc.write_text(assoc.read_text() + "6 depth/6.png 6 rgb/6.png\n7 depth/7.png 7 rgb/7.png\n")
    ds = dataset(root, tmp_path / "cache")
    ref = ds.objects("all")[0]
    with pytest.warns(UserWarning, match=r"scene living_room_traj0_frei_png: fused 3 of the 7"):
        data = ds.load(ref)
    assert int(data.extra["frames_fused"]) == 3 and int(data.extra["frames_asked"]) == 7
    with pytest.warns(UserWarning, match="3 named frames without a depth file"):
        dataset(root, tmp_path / "cache").load(ref)  # again from the cache


def test_a_single_missing_first_pose_is_not_worth_a_warning(tmp_path):
    root = tmp_path / "data"
    write_tum(root / "living_room_traj0_frei_png")  # ICL-NUIM: no pose for frame 1
    ds = dataset(root, tmp_path / "cache")
    _, messages = load_quietly(ds, ds.objects("all")[0])
    assert messages == []


def test_warns_when_frame_stride_keeps_one_frame(tmp_path):
    root = tmp_path / "data"
    write_tum(root / "living_room_traj0_frei_png")
    ds = dataset(root, tmp_path / "cache", frame_stride=10)
    with pytest.warns(UserWarning, match=r"frame_stride=10 fuses 1 of its 4 frames with a pose"):
        ds.load(ds.objects("all")[0])


def test_warns_when_the_fused_cloud_is_smaller_than_gt_points(tmp_path):
    """The ground truth then has the fused cloud's size, and the scene says how many."""
    root = tmp_path / "data"
    write_tum(root / "living_room_traj0_frei_png")
    ds = dataset(root, tmp_path / "cache", voxel_size=0.25)
    with pytest.warns(UserWarning, match=r"holds \d+ points, fewer than gt_points=2000") as rec:
        data = ds.load(ds.objects("all")[0])
    n = len(data.gt_points)
    assert n < 2000 and int(data.extra["fused_points"]) == n == int(data.extra["gt_point_count"])
    assert any(f"its ground truth has {n} points" in str(w.message) for w in rec)


def test_unreadable_frames_are_skipped_and_counted(tmp_path):
    """One corrupt frame costs that frame, not the scene."""
    root = tmp_path / "data"
    write_tum(root / "living_room_traj0_frei_png")
    (root / "living_room_traj0_frei_png" / "depth" / "3.png").write_bytes(b"not a png")
    ds = dataset(root, tmp_path / "cache")
    with pytest.warns(UserWarning, match=r"fused 3 of the 5 frames asked.*1 unusable frame"):
        points, data = world_points(ds, ds.objects("all")[0])
    assert_on_walls(points)
    assert int(data.extra["frames_selected"]) == 4 and int(data.extra["frames_fused"]) == 3


# ---------------------------------------------------------------------------- failures


def test_failures_name_the_scene_and_the_fix_on_one_line(tmp_path):
    root = tmp_path / "data"
    (root / "office" / "traj1" / "depth").mkdir(parents=True)
    write_redwood(root / "office" / "scaled")
    ds = dataset(root, tmp_path / "cache")
    no_trajectory = ObjectRef("office/traj1", "office")
    with pytest.raises(ObjectLoadError) as err:
        ds.load(no_trajectory)
    message = str(err.value)
    assert message.startswith("scene office/traj1: no camera trajectory") and "\n" not in message
    assert "*.gt.freiburg" in message and "*.log" in message and "beside depth/" in message
    with pytest.raises(ObjectLoadError) as again:  # cached: the same line
        dataset(root, tmp_path / "cache").load(no_trajectory)
    assert str(again.value) == message

    wrong_scale = dataset(root, tmp_path / "cache2", depth_scale=10.0)  # depths x100
    with pytest.raises(ObjectLoadError, match=r"^scene office/scaled: .*check depth_scale"):
        wrong_scale.load(ObjectRef("office/scaled", "office"))
