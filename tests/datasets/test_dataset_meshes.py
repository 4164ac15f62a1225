"""The ``meshes`` dataset on real third-party meshes (../shared/data, referenced, never copied)."""

from __future__ import annotations

import pickle
import sys
from pathlib import Path

import numpy as np
import pytest

try:
    import shapebench_meshes  # noqa: F401
except ModuleNotFoundError:  # the checkout was installed before this plugin existed
    sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "datasets"))

from shapebench_meshes.dataset import MeshFolderDataset, MeshFolderOptions  # noqa: E402

from shapebench.api.dataset import ObjectLoadError  # noqa: E402
from shapebench.api.errors import ConfigError, DataNotFoundError  # noqa: E402
from shapebench.api.types import NOVEL, TRAIN, TRAINED, Category, ObjectRef  # noqa: E402

SHARED = Path(__file__).resolve().parents[3] / "shared" / "data" / "meshes"
REAL = {
    "animals/spot.obj": "common-3d-test-models/data/spot.obj",
    "animals/bunny.off": "libigl-tutorial-data/bunny.off",
    "suzanne.obj": "common-3d-test-models/data/suzanne.obj",
}
TINY = {"surface_candidates": 3000, "gt_points": 2000}

needs_shared = pytest.mark.skipif(
    not SHARED.exists(), reason="../shared/data (real test meshes) is not present"
)


def make_folder(root: Path) -> Path:
    """Real meshes symlinked in (licences forbid copies), plus a broken file and noise."""
    for rel, source in REAL.items():
        (root / rel).parent.mkdir(parents=True, exist_ok=True)
        (root / rel).symlink_to(SHARED / source)
    (root / "animals" / "broken.obj").write_text("v 0 0 0\nv 1 oops 0\nf 1 2 3\n")
    (root / "notes.txt").write_text("not a mesh")
    (root / ".hidden").mkdir()
    (root / ".hidden" / "x.obj").write_text("v 0 0 0\n")
    return root


def dataset(root: Path, cache: Path, **options) -> MeshFolderDataset:
    return MeshFolderDataset(MeshFolderOptions(**(TINY | options)), cache, root)


@needs_shared
def test_folders_are_categories_and_everything_is_novel_by_default(tmp_path):
    ds = dataset(make_folder(tmp_path / "data"), tmp_path / "cache")
    assert ds.categories() == [Category("animals", NOVEL), Category("misc", NOVEL)]
    assert [r.id for r in ds.objects(NOVEL)] == [
        "animals/broken",
        "animals/bunny",
        "animals/spot",
        "suzanne",
    ]
    assert ds.objects(NOVEL)[-1] == ObjectRef("suzanne", "misc")
    assert ds.objects(TRAIN) == [] and ds.objects(TRAINED) == []


@needs_shared
def test_real_meshes_load_normalised_and_the_broken_file_fails_alone(tmp_path):
    ds = dataset(make_folder(tmp_path / "data"), tmp_path / "cache")
    loaded = {}
    for ref in ds.objects(NOVEL):
        if ref.id == "animals/broken":
            with pytest.raises(ObjectLoadError, match="broken.obj"):
                ds.load(ref)
            continue
        data = ds.load(ref)
        loaded[ref.id] = data
        assert 2000 < len(data.surface_points) <= 3000  # the visible part of 3000 candidates
        assert data.gt_points.shape == (2000, 3)
        assert data.surface_points.dtype == np.float32
        assert np.linalg.norm(data.gt_points, axis=1).max() <= 1.0 + 1e-5
        assert np.allclose(np.linalg.norm(data.surface_normals, axis=1), 1.0, atol=1e-4)
    assert sorted(loaded) == ["animals/bunny", "animals/spot", "suzanne"]
    # Cached: a new instance reads the same arrays back, and the failure is remembered.
    again = dataset(tmp_path / "data", tmp_path / "cache")
    ref = ObjectRef("animals/spot", "animals")
    assert np.array_equal(again.load(ref).gt_points, loaded["animals/spot"].gt_points)
    assert (
        again.cache_path(ObjectRef("animals/broken", "animals")).with_suffix(".error.txt").exists()
    )


@needs_shared
def test_the_ground_truth_alone_is_the_loaded_objects_bit_for_bit_and_caches_nothing(tmp_path):
    folder = make_folder(tmp_path / "data")
    alone = dataset(folder, tmp_path / "cache-alone")
    whole = dataset(folder, tmp_path / "cache-whole")
    for ref in alone.objects(NOVEL):
        if ref.id == "animals/broken":
            with pytest.raises(ObjectLoadError, match="broken.obj"):
                alone.ground_truth_points(ref)
            continue
        gt = alone.ground_truth_points(ref)  # from the mesh: no visible points were cast
        assert not alone.cache_path(ref).exists()
        loaded = whole.load(ref).gt_points
        assert gt.dtype == loaded.dtype and np.array_equal(gt, loaded)
        # Once the object is cached, the cached array is what it returns.
        assert np.array_equal(whole.ground_truth_points(ref), loaded)
    # A failure the whole preparation recorded is reported without reading the mesh again.
    broken = ObjectRef("animals/broken", "animals")
    with pytest.raises(ObjectLoadError):
        whole.load(broken)
    (folder / "animals" / "broken.obj").unlink()
    with pytest.raises(ObjectLoadError, match="broken.obj"):
        whole.ground_truth_points(broken)


@needs_shared
def test_train_fraction_splits_each_category_deterministically(tmp_path):
    root = make_folder(tmp_path / "data")
    ds = dataset(root, tmp_path / "cache", train_fraction=0.5)
    assert {c.split for c in ds.categories()} == {TRAINED}
    train, test = ds.objects(TRAIN), ds.objects(TRAINED)
    assert ds.objects(NOVEL) == []
    assert not {r.id for r in train} & {r.id for r in test}
    assert len(train) + len(test) == 4
    # every category keeps at least one test object; suzanne alone in misc stays a test object
    assert {r.category for r in test} == {"animals", "misc"}
    other = dataset(root, tmp_path / "cache2", train_fraction=0.5)
    assert other.objects(TRAIN) == train and other.objects(TRAINED) == test
    # the fraction decides which objects are test objects: it is part of the fingerprint
    assert other.fingerprint() != dataset(root, tmp_path / "c", train_fraction=0.25).fingerprint()


def test_max_train_per_category_caps_training_objects_in_nested_sets(tmp_path):
    import trimesh

    root = tmp_path / "data"
    for i in range(10):
        (root / "boxes").mkdir(parents=True, exist_ok=True)
        trimesh.creation.box((0.2 + 0.05 * i, 0.3, 0.4)).export(root / "boxes" / f"b{i}.obj")
    every = dataset(root, tmp_path / "cache", train_fraction=0.8)
    assert len(every.objects(TRAIN)) == 8
    two = dataset(root, tmp_path / "cache", train_fraction=0.8, max_train_per_category=2)
    five = dataset(root, tmp_path / "cache", train_fraction=0.8, max_train_per_category=5)
    small, large = {r.id for r in two.objects(TRAIN)}, {r.id for r in five.objects(TRAIN)}
    assert len(small) == 2 and len(large) == 5 and small < large  # nested
    assert large < {r.id for r in every.objects(TRAIN)}
    # The test objects, and the evaluation data, do not move: a training-only option.
    assert two.objects(TRAINED) == every.objects(TRAINED)
    assert two.data_fingerprint() == every.data_fingerprint()
    assert two.training_fingerprint() != every.training_fingerprint()


@needs_shared
def test_fingerprint_follows_the_files_and_the_dataset_pickles(tmp_path):
    root = make_folder(tmp_path / "data")
    ds = dataset(root, tmp_path / "cache")
    ds.objects(NOVEL)
    clone = pickle.loads(pickle.dumps(ds))
    assert clone.fingerprint() == ds.fingerprint() and clone.objects(NOVEL) == ds.objects(NOVEL)
    (root / "animals" / "broken.obj").unlink()
    assert dataset(root, tmp_path / "cache").fingerprint() != ds.fingerprint()


def test_missing_or_empty_folder_says_what_to_pass(tmp_path):
    with pytest.raises(DataNotFoundError) as err:
        dataset(tmp_path / "nowhere", tmp_path / "cache").objects(NOVEL)
    assert "--data-root" in str(err.value)
    (tmp_path / "empty").mkdir()
    with pytest.raises(DataNotFoundError, match="no mesh files"):
        dataset(tmp_path / "empty", tmp_path / "cache").categories()
    with pytest.raises(DataNotFoundError):
        dataset(None, tmp_path / "cache").categories()
    assert MeshFolderDataset.needs_data_root and "--data-root" in MeshFolderDataset.obtain_hint


def test_train_fraction_must_leave_test_objects(tmp_path):
    with pytest.raises(ConfigError, match="train_fraction"):
        dataset(tmp_path, tmp_path / "cache", train_fraction=1.0)


def test_same_stem_different_suffix_keeps_ids_unique(tmp_path):
    import trimesh

    trimesh.creation.box().export(tmp_path / "a.obj")
    trimesh.creation.icosphere(subdivisions=1).export(tmp_path / "a.stl")
    ds = dataset(tmp_path, tmp_path / "cache")
    assert [r.id for r in ds.objects(NOVEL)] == ["a.obj", "a.stl"]
    assert len(ds.mesh(ObjectRef("a.stl", "misc")).faces) == 80


@pytest.mark.slow  # runs the CLI
def test_empty_garbage_and_nan_meshes_are_named_and_the_good_ones_scored(shapebench, tmp_path):
    """issue 31: a folder with an empty, a garbage and a NaN mesh beside good ones names all
    three files in the run's output, scores the good ones, and prints no traceback. The NaN
    file matters most: trimesh's processing drops non-finite vertices silently, which scored a
    box with a corner cut off as if it were the file."""
    import trimesh

    folder = tmp_path / "root" / "things"
    folder.mkdir(parents=True)
    trimesh.creation.icosphere(subdivisions=2).export(folder / "ball.obj")
    trimesh.creation.box().export(folder / "cube.obj")
    (folder / "empty.obj").write_text("")
    (folder / "garbage.ply").write_bytes(np.random.default_rng(0).bytes(4096))
    box = trimesh.creation.box()
    vertices = box.vertices.copy()
    vertices[0, 0] = np.nan
    (folder / "nan.obj").write_text(
        "".join(f"v {x} {y} {z}\n" for x, y, z in vertices)
        + "".join(f"f {a + 1} {b + 1} {c + 1}\n" for a, b, c in box.faces)
    )
    # A single flat triangle is a surface like any other (a sheet): it is scored. Triangles whose
    # corners lie on one line have no area at all: a failure naming the file.
    (folder / "flat.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    (folder / "line.obj").write_text("v 0 0 0\nv 1 0 0\nv 2 0 0\nv 3 0 0\nf 1 2 3\nf 2 3 4\n")
    # Files that are not meshes (ShapeNet keeps materials and notes beside its models) are not
    # objects: one line says how many were left out.
    (folder / "model.mtl").write_text("newmtl a\n")
    (folder / "README.txt").write_text("not a mesh\n")
    res = shapebench(
        "run",
        "-m",
        "gauss",
        "-d",
        "meshes",
        "--data-root",
        str(tmp_path / "root"),
        "--contexts",
        "50",
        "-q",
        *[f"-D{k}={v}" for k, v in TINY.items()],
    )
    out = res.stdout + res.stderr
    assert res.returncode == 0, out
    assert "Traceback" not in out
    assert "empty.obj has no triangles" in out
    assert "garbage.ply" in out and "cannot read mesh file" in out
    assert "nan.obj has NaN or infinite vertex coordinates" in out
    assert "line.obj has zero surface area (every triangle is degenerate)" in out
    assert "2 files are not meshes and were left out (1 .mtl, 1 .txt; e.g. things/README.txt" in out
    runs = shapebench.cell_runs("meshes-novel")
    assert len(runs) == 1 and runs[0].data.metrics["failures"] == 4.0
    assert runs[0].data.metrics["n_objects"] == 7.0  # ball, cube and flat scored
