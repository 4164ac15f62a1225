"""The ``icl-nuim`` dataset on a sequence this test renders in ICL-NUIM's published layout, and on
the real office sample in ../shared/data (skipped when absent).

The synthetic scene is a box room with two boxes in it, its depth ray-cast with the ICL-NUIM
camera (fx 481.20, fy -480.00, cx 319.5, cy 239.5) from a few poses and written as 16-bit PNGs
(metres x 5000) with ``associations.txt`` and a TUM trajectory ``livingRoom0.gt.freiburg``, like
the ``living_room_traj0_frei_png`` download (no pose for the first frame, as in ICL-NUIM).
"""

from __future__ import annotations

import pickle
import sys
from pathlib import Path

import imageio.v3 as iio
import numpy as np
import pytest
import trimesh
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation

try:
    import shapebench_iclnuim  # noqa: F401
except ModuleNotFoundError:  # the checkout was installed before this plugin existed
    sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "datasets"))

from shapebench_iclnuim import fusion  # noqa: E402
from shapebench_iclnuim.dataset import ICLNUIMDataset, ICLNUIMOptions  # noqa: E402
from shapebench_iclnuim.sequence import discover, read_frames  # noqa: E402

from shapebench.api.dataset import ObjectLoadError  # noqa: E402
from shapebench.api.errors import DataNotFoundError  # noqa: E402
from shapebench.api.types import Category, ObjectRef  # noqa: E402

REAL = Path(__file__).resolve().parents[3] / "shared" / "data" / "rgbd" / "icl-nuim-office-traj0"
K = fusion.Intrinsics(481.20, -480.00, 319.5, 239.5, 5000.0)
W, H = 640, 480
TINY = {"surface_candidates": 3000, "gt_points": 2000, "frame_stride": 1}


def room() -> trimesh.Trimesh:
    """Walls, floor and ceiling facing inwards, two boxes facing outwards: every face normal
    points into free space, where the cameras are."""
    walls = trimesh.creation.box(extents=(4.0, 2.6, 5.0))
    walls.invert()
    table = trimesh.creation.box(extents=(1.2, 0.8, 0.7))
    table.apply_translation((0.8, -0.9, 1.0))
    cabinet = trimesh.creation.box(extents=(0.5, 1.6, 0.9))
    cabinet.apply_translation((-1.6, -0.5, -1.5))
    scene = trimesh.util.concatenate([walls, table, cabinet])
    return scene.apply_translation((1.0, 1.3, -2.0))  # not centred: normalisation must move it


def look_at(position, target) -> np.ndarray:
    """Camera-to-world rotation whose z axis looks at ``target`` (y roughly up)."""
    z = np.asarray(target, float) - position
    z /= np.linalg.norm(z)
    x = np.cross((0.0, 1.0, 0.0), z)
    x /= np.linalg.norm(x)
    return np.column_stack([x, np.cross(z, x), z])


POSES = [  # (position, target), inside the room
    ((1.0, 1.5, 0.0), (1.8, 0.4, -1.0)),
    ((1.0, 1.5, 0.0), (1.0, 1.0, -4.0)),
    ((2.0, 1.6, -1.0), (-0.6, 0.8, -3.5)),
    ((0.2, 1.4, -3.0), (2.5, 0.5, 0.0)),
    ((2.4, 1.8, -2.5), (0.0, 1.0, 0.4)),
]


def render(mesh: trimesh.Trimesh, rotation: np.ndarray, position: np.ndarray) -> np.ndarray:
    """Depth (metres along the optical axis) by ray casting, as the ICL-NUIM camera sees it."""
    v, u = np.mgrid[0:H, 0:W]
    local = np.stack([(u - K.cx) / K.fx, (v - K.cy) / K.fy, np.ones_like(u, float)], -1)
    dirs = local.reshape(-1, 3) @ rotation.T
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    origins = np.broadcast_to(position, dirs.shape)
    hits, ray, _ = mesh.ray.intersects_location(origins, dirs, multiple_hits=False)
    depth = np.zeros(H * W)
    depth[ray] = (hits - position) @ rotation[:, 2]
    return depth.reshape(H, W)


def write_sequence(folder: Path, mesh: trimesh.Trimesh) -> list[np.ndarray]:
    """The ICL-NUIM TUM-format layout; returns the camera centres of the posed frames."""
    (folder / "depth").mkdir(parents=True)
    (folder / "rgb").mkdir()
    assoc, traj, centres = [], [], []
    for i, (pos, target) in enumerate(POSES, start=1):
        pos = np.asarray(pos, float)
        rot = look_at(pos, target)
        depth = render(mesh, rot, pos)
        iio.imwrite(folder / "depth" / f"{i}.png", np.round(depth * K.depth_scale).astype("<u2"))
        grey = (255 * depth / max(depth.max(), 1e-9)).astype(np.uint8)
        iio.imwrite(folder / "rgb" / f"{i}.png", np.stack([grey] * 3, -1))
        assoc.append(f"{i} depth/{i}.png {i} rgb/{i}.png")
        if i == 1:
            continue  # ICL-NUIM has no pose for its first frame
        qx, qy, qz, qw = Rotation.from_matrix(rot).as_quat()
        traj.append(f"{i} {pos[0]} {pos[1]} {pos[2]} {qx} {qy} {qz} {qw}")
        centres.append(pos)
    (folder / "associations.txt").write_text("\n".join(assoc) + "\n")
    (folder / "livingRoom0.gt.freiburg").write_text("\n".join(traj) + "\n")
    return centres


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    root = tmp_path_factory.mktemp("icl")
    mesh = room()
    centres = write_sequence(root / "living_room_traj0_frei_png", mesh)
    return root, mesh, centres


def icl(root, cache, **options) -> ICLNUIMDataset:
    return ICLNUIMDataset(ICLNUIMOptions(**(TINY | options)), cache, root)


def test_sequence_is_one_living_room_scene_of_split_all(scene, tmp_path):
    root, _, _ = scene
    ds = icl(root, tmp_path / "cache")
    ref = ObjectRef("living_room_traj0_frei_png", "living-room")
    assert ds.categories() == [Category("living-room", "all")]
    assert ds.objects("all") == [ref] and ds.objects("trained") == ds.objects("train") == []
    assert ds.eval_splits == ("all",) and ds.default_metric == "chamfer-l2-asym"
    frames, skipped = read_frames(discover(root)[0])
    assert [f.timestamp for f in frames] == [2.0, 3.0, 4.0, 5.0] and skipped == 1
    clone = pickle.loads(pickle.dumps(ds))
    assert clone.objects("all") == [ref] and clone.fingerprint() == ds.fingerprint()


def test_fused_scene_lies_on_the_room_with_normals_towards_the_cameras(scene, tmp_path):
    root, mesh, centres = scene
    ds = icl(root, tmp_path / "cache")
    ref = ds.objects("all")[0]
    data = ds.load(ref)
    assert data.surface_points.shape == (3000, 3) and data.gt_points.shape == (2000, 3)
    assert np.linalg.norm(data.gt_points, axis=1).max() <= 1.0 + 1e-5
    assert np.abs(data.gt_points.mean(axis=0)).max() < 0.05  # centre of mass at the origin

    with np.load(ds.cache_path(ref)) as cached:
        center, scale = cached["center"], float(cached["scale"])
        assert int(cached["frames"]) == 4
    world = data.surface_points.astype(np.float64) * scale + center
    _, distance, face = trimesh.proximity.closest_point(mesh, world)
    assert np.quantile(distance, 0.99) < 1e-3 and distance.max() < 3e-3  # metres, before scaling
    true_normal = mesh.face_normals[face]  # every face of the room faces free space
    agree = np.einsum("ij,ij->i", data.surface_normals, true_normal)
    assert np.mean(agree > 0.9) > 0.9  # PCA blurs edges and corners only
    assert np.mean(agree < -0.5) < 0.005  # oriented towards the cameras, never into the walls
    to_camera = np.stack([np.asarray(c) - world for c in centres], 1)  # (n, cameras, 3)
    facing = np.einsum("nj,ncj->nc", data.surface_normals, to_camera) > 0
    assert facing.any(axis=1).all()

    # Cached: a new instance reads the same arrays back.
    again = icl(root, tmp_path / "cache").load(ref)
    assert np.array_equal(again.surface_points, data.surface_points)


def test_frame_stride_and_voxel_size_change_the_scene(scene, tmp_path):
    root, _, _ = scene
    dense = icl(root, tmp_path / "cache", voxel_size=0.05)
    sparse = icl(root, tmp_path / "cache", voxel_size=0.05, frame_stride=3)
    assert dense.fingerprint() != sparse.fingerprint()
    ref = dense.objects("all")[0]
    sparse.load(ref)
    with np.load(sparse.cache_path(ref)) as cached:
        assert int(cached["frames"]) == 2  # frames 2 and 5 of the four posed ones


def test_missing_data_and_broken_sequences(tmp_path):
    with pytest.raises(DataNotFoundError) as err:
        icl(tmp_path / "nowhere", tmp_path / "cache").objects("all")
    assert "ICL-NUIM" in str(err.value) and "gt.freiburg" in str(err.value)
    (tmp_path / "empty").mkdir()
    with pytest.raises(DataNotFoundError, match="depth/"):
        icl(tmp_path / "empty", tmp_path / "cache").categories()
    assert "ICL-NUIM" in ICLNUIMDataset.obtain_hint and ICLNUIMDataset.needs_data_root

    root = tmp_path / "data"
    (root / "office" / "traj1_frei_png" / "depth").mkdir(parents=True)  # no trajectory
    seq = root / "office" / "traj2_frei_png"
    (seq / "depth").mkdir(parents=True)
    (seq / "depth" / "1.png").write_bytes(b"not a png")
    (seq / "traj2.gt.freiburg").write_text("1 0 0 0 0 0 0 1\n")
    ds = icl(root, tmp_path / "cache")
    assert [(r.id, r.category) for r in ds.objects("all")] == [
        ("office/traj1_frei_png", "office"),
        ("office/traj2_frei_png", "office"),
    ]
    no_traj, bad_png = ds.objects("all")
    with pytest.raises(ObjectLoadError, match="trajectory"):
        ds.load(no_traj)
    with pytest.raises(ObjectLoadError, match="depth image"):
        ds.load(bad_png)
    assert ds.cache_path(bad_png).with_suffix(".error.txt").exists()


needs_real = pytest.mark.skipif(
    not REAL.exists(), reason="../shared/data/rgbd/icl-nuim-office-traj0 is not present"
)


@needs_real
def test_real_office_sample_loads(tmp_path):
    ds = icl(REAL.parent, tmp_path / "cache", frame_stride=4)
    refs = [r for r in ds.objects("all") if r.id == REAL.name]
    assert refs and refs[0].category == "office"
    data = ds.load(refs[0])
    assert data.surface_points.shape == (3000, 3) and data.gt_points.shape == (2000, 3)
    assert np.allclose(np.linalg.norm(data.surface_normals, axis=1), 1.0, atol=1e-4)


@needs_real
def test_real_office_frames_agree_with_the_camera_model():
    """fy = -480 (ICL-NUIM's sign) makes overlapping frames coincide; +480 would not."""
    frames, _ = read_frames(next(s for s in discover(REAL.parent) if s.id == REAL.name))
    by_time = {f.timestamp: f for f in frames}

    def cloud(t, k, step):
        f = by_time[t]
        depth = fusion.read_depth(f.depth_path, k.depth_scale)[::step, ::step]
        sub = fusion.Intrinsics(k.fx / step, k.fy / step, k.cx / step, k.cy / step, 5000.0)
        return fusion.backproject(depth, sub) @ f.rotation.T + f.position

    def overlap(k):
        tree = cKDTree(cloud(2.0, k, 1))
        distance, _ = tree.query(cloud(10.0, k, 8))
        return np.mean(distance < 0.01)

    flipped = fusion.Intrinsics(K.fx, -K.fy, K.cx, K.cy, K.depth_scale)
    assert overlap(K) > 0.85 > 0.6 > overlap(flipped)


def copy_real(folder: Path, frames, spoil: bool) -> None:
    """Real ICL-NUIM frames in their own TUM-layout folder, optionally with sensor artefacts."""
    (folder / "depth").mkdir(parents=True)
    for i in frames:
        raw = iio.imread(REAL / "depth" / f"{i}.png")
        if spoil:
            raw[200:260, 100:300] = 65535  # invalid code: 13.1 m at depth scale 5000
            raw[:40, :] = 0
        iio.imwrite(folder / "depth" / f"{i}.png", raw)
    lines = [f"{i} depth/{i}.png {i} rgb/{i}.png" for i in frames]
    (folder / "associations.txt").write_text("\n".join(lines) + "\n")
    (folder / "traj0.gt.freiburg").write_text((REAL / "traj0.gt.freiburg").read_text())


@needs_real
def test_real_frames_with_invalid_depth_codes_keep_the_scene(tmp_path):
    """65535 pixels in real ICL-NUIM frames must not become points 13 m away: every point of the
    spoiled scene lies on the clean one, and the normalisation radius stays the room's."""
    frames = range(2, 11)
    for name, spoil in (("clean", False), ("spoiled", True)):
        copy_real(tmp_path / name / "traj0_frei_png", frames, spoil)

    def world(name):
        ds = icl(tmp_path / name, tmp_path / f"cache-{name}", frame_stride=4, voxel_size=0.05)
        ref = ds.objects("all")[0]
        data = ds.load(ref)
        with np.load(ds.cache_path(ref)) as cached:
            scale = float(cached["scale"])
            return data.gt_points.astype(np.float64) * scale + cached["center"], scale

    clean, clean_scale = world("clean")
    spoiled, spoiled_scale = world("spoiled")
    distance, _ = cKDTree(clean).query(spoiled)
    assert distance.max() < 0.5  # metres (2000-point samples of each): none off the clean scene
    assert spoiled_scale < 1.2 * clean_scale


@pytest.mark.skipif(not REAL.exists(), reason="the real ICL-NUIM sample is not here")
@pytest.mark.slow
def test_run_says_why_a_scene_failed_and_that_the_card_promises_too_many_points(
    shapebench, tmp_path
):
    """On the console, not only in per_object.csv: a scene without trajectory, and a fused
    cloud holding fewer points than the card's gt_points (the real count goes on the run)."""
    root = tmp_path / "icl"
    (root / "office").mkdir(parents=True)
    (root / "office" / "traj0").symlink_to(REAL)
    broken = root / "office" / "broken" / "depth"
    broken.mkdir(parents=True)
    (broken / "1.png").write_bytes((REAL / "depth" / "1.png").read_bytes())
    res = shapebench(
        "run",
        "-m",
        "gauss",
        "-d",
        "icl-nuim",
        "--data-root",
        str(root),
        "-D",
        "surface_candidates=3000",
        "-D",
        "gt_points=500000",
        "--contexts",
        "50",
        "-q",
    )
    assert res.returncode == 0, res.stderr[-3000:]
    out = res.stdout + res.stderr
    assert "scene office/broken: no camera trajectory" in out
    assert "fewer ground-truth points than the 500000 the metric card states" in out
    (run,) = shapebench.cell_runs("icl-nuim-all")
    actual = int(run.data.tags["eval_points.actual"])
    assert 0 < actual < 500000
