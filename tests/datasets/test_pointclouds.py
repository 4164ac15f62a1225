"""Point-cloud layouts (issue 29 §3): the PCD reader and writer, and ShapeNet-55/34 in PoinTr's
layout, on tiny fixtures the tests write (clouds sampled from meshes)."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh
from shapebench_pointclouds.shapenet55 import ShapeNet55Dataset, ShapeNet55Options

from shapebench.api.dataset import ObjectLoadError
from shapebench.api.errors import ConfigError
from shapebench.api.types import NOVEL, TRAIN, TRAINED, VALIDATION, Supervision
from shapebench.exchange.pcd import read_pcd, write_pcd

# -- PCD ------------------------------------------------------------------------------------------


@pytest.mark.parametrize("binary", [True, False])
def test_pcd_round_trip(tmp_path, binary: bool) -> None:
    points = np.random.default_rng(0).normal(size=(500, 3)).astype(np.float32)
    path = tmp_path / "cloud.pcd"
    write_pcd(path, points, binary=binary)
    assert path.read_bytes().startswith(b"# .PCD v0.7")
    got = read_pcd(path)
    if binary:
        np.testing.assert_array_equal(got, points)
    else:
        np.testing.assert_allclose(got, points, rtol=1e-7)


def test_pcd_ascii_by_hand_with_more_fields_and_an_invalid_point(tmp_path) -> None:
    path = tmp_path / "hand.pcd"
    path.write_text(
        "# .PCD v0.7\nVERSION 0.7\nFIELDS x y z rgb\nSIZE 4 4 4 4\nTYPE F F F U\nCOUNT 1 1 1 1\n"
        "WIDTH 3\nHEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS 3\nDATA ascii\n"
        "1 2 3 4278190080\nnan nan nan 0\n-1.5 0 2.25 16711680\n"
    )
    np.testing.assert_array_equal(read_pcd(path), [[1, 2, 3], [-1.5, 0, 2.25]])


def test_pcd_binary_by_hand_with_an_intensity_field(tmp_path) -> None:
    # Records of x, y, z (float32) and intensity (uint16), packed little-endian.
    dtype = np.dtype([("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("i", "<u2")])
    records = np.array([(1, 2, 3, 7), (4, 5, 6, 9)], dtype=dtype)
    header = (
        "VERSION 0.7\nFIELDS x y z intensity\nSIZE 4 4 4 2\nTYPE F F F U\nCOUNT 1 1 1 1\n"
        "WIDTH 2\nHEIGHT 1\nPOINTS 2\nDATA binary\n"
    )
    path = tmp_path / "intensity.pcd"
    path.write_bytes(header.encode() + records.tobytes())
    np.testing.assert_array_equal(read_pcd(path), [[1, 2, 3], [4, 5, 6]])


def test_pcd_problems_are_one_line_naming_the_file(tmp_path) -> None:
    compressed = tmp_path / "c.pcd"
    compressed.write_text(
        "FIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nPOINTS 1\nDATA binary_compressed\n"
    )
    with pytest.raises(ObjectLoadError, match="c.pcd is binary_compressed PCD.*compressed=False"):
        read_pcd(compressed)
    truncated = tmp_path / "t.pcd"
    write_pcd(truncated, np.ones((10, 3)))
    truncated.write_bytes(truncated.read_bytes()[:-7])
    with pytest.raises(ObjectLoadError, match="t.pcd is truncated"):
        read_pcd(truncated)
    noxyz = tmp_path / "n.pcd"
    noxyz.write_text("FIELDS a b\nSIZE 4 4\nTYPE F F\nPOINTS 0\nDATA ascii\n")
    with pytest.raises(ObjectLoadError, match="has no x, y, z fields"):
        read_pcd(noxyz)


# -- ShapeNet-55/34 -------------------------------------------------------------------------------

#: synset -> (the paper's category name, a primitive to sample)
CATEGORIES = {
    "02691156": ("Plane", trimesh.creation.box),
    "03001627": ("Chair", trimesh.creation.icosphere),
    "04379243": ("Table", trimesh.creation.cylinder),
}


def _cloud(shape, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    mesh = shape() if shape is not trimesh.creation.cylinder else shape(radius=1, height=2)
    points, _ = trimesh.sample.sample_surface(mesh, 8192, seed=seed)
    return (points * rng.uniform(0.5, 3) + rng.normal(size=3)).astype(np.float32)


@pytest.fixture
def pointr_root(tmp_path):
    """PoinTr's layout: 4 training and 2 test models per category (ShapeNet-55), and for
    ShapeNet-34 two seen categories and one unseen."""
    root = tmp_path / "ShapeNet55-34"
    (root / "shapenet_pc").mkdir(parents=True)
    lists: dict[str, list[str]] = {}
    for k, (synset, (_, shape)) in enumerate(CATEGORIES.items()):
        for i in range(6):
            name = f"{synset}-model{i:02d}.npy"
            np.save(root / "shapenet_pc" / name, _cloud(shape, 10 * k + i))
            lists.setdefault("55-" + ("train" if i < 4 else "test"), []).append(name)
            if synset != "04379243":
                lists.setdefault("34-" + ("train" if i < 4 else "test"), []).append(name)
            elif i >= 4:
                lists.setdefault("unseen", []).append(name)
    for rel, key in (
        ("ShapeNet-55/train.txt", "55-train"),
        ("ShapeNet-55/test.txt", "55-test"),
        ("ShapeNet-34/train.txt", "34-train"),
        ("ShapeNet-34/test.txt", "34-test"),
        ("ShapeNet-Unseen21/test.txt", "unseen"),
    ):
        (root / rel).parent.mkdir(exist_ok=True)
        (root / rel).write_text("\n".join(lists[key]) + "\n")
    return root


def _dataset(root, tmp_path, **options) -> ShapeNet55Dataset:
    return ShapeNet55Dataset(ShapeNet55Options(**options), tmp_path / "cache", root)


def test_shapenet55_splits_names_and_a_validation_split_carved_from_training(
    pointr_root, tmp_path
) -> None:
    ds = _dataset(pointr_root, tmp_path)
    assert [(c.name, c.split) for c in ds.categories()] == [
        ("Chair", TRAINED),
        ("Plane", TRAINED),
        ("Table", TRAINED),
    ]
    ids = {s: [r.id for r in ds.objects(s)] for s in (TRAIN, TRAINED, NOVEL, VALIDATION)}
    assert len(ids[TRAINED]) == 6 and ids[NOVEL] == []
    assert len(ids[VALIDATION]) == 6 and len(ids[TRAIN]) == 6  # 2 of 4 per category kept apart
    assert not set(ids[VALIDATION]) & set(ids[TRAIN])
    assert "Plane/02691156-model04" in ids[TRAINED]

    ds34 = _dataset(pointr_root, tmp_path, benchmark=34, validation_per_category=1)
    assert {(c.name, c.split) for c in ds34.categories()} == {
        ("Chair", TRAINED),
        ("Plane", TRAINED),
        ("Table", NOVEL),
    }
    assert [r.id for r in ds34.objects(NOVEL)] == [
        "Table/04379243-model04",
        "Table/04379243-model05",
    ]
    assert len(ds34.objects(TRAIN)) == 6  # 3 of 4 per seen category
    with pytest.raises(ConfigError, match="benchmark must be 55 or 34"):
        _dataset(pointr_root, tmp_path, benchmark=21)


def test_shapenet55_clouds_are_normalised_as_pointr_does(pointr_root, tmp_path) -> None:
    ds = _dataset(pointr_root, tmp_path)
    data = ds.load(ds.objects(TRAINED)[0], frozenset({Supervision.COMPLETE_POINTS}))
    assert data.gt_points.shape == (8192, 3)
    np.testing.assert_allclose(data.gt_points.mean(axis=0), 0, atol=1e-6)
    assert np.linalg.norm(data.gt_points, axis=1).max() == pytest.approx(1.0, abs=1e-6)
    np.testing.assert_array_equal(data.extra["complete_points"], data.gt_points)
    (pointr_root / "shapenet_pc" / "02691156-model05.npy").write_bytes(b"not numpy")
    with pytest.raises(ObjectLoadError, match="cannot read point cloud .*02691156-model05.npy"):
        ds.load(next(r for r in ds.objects(TRAINED) if r.id == "Plane/02691156-model05"))


@pytest.mark.slow  # runs the CLI
def test_shapenet55_under_the_crop_protocol_from_the_command_line(shapebench, pointr_root):
    base = ("run", "-m", "gauss", "-d", "shapenet55", "--data-root", str(pointr_root), "-q")
    res = shapebench(*base, "--protocol", "crop", "--crop-fraction", "0.5", "--contexts", "2048")
    assert res.returncode == 0, res.stdout + res.stderr
    assert "shapenet55/trained: 6 objects in 3 categories (ShapeNet-55)" in res.stdout
    assert "gauss[crop=0.5] on shapenet55/trained" in res.stdout
    res = shapebench(*base, "--contexts", "50", "--context-normals")
    assert res.returncode == 2 and "has points without normals" in res.stderr
    res = shapebench("run", "-m", "gauss", "-d", "shapenet55", "--contexts", "50")
    assert res.returncode == 2 and "PoinTr's ShapeNet-55/34 layout" in res.stderr


# -- PCN ------------------------------------------------------------------------------------------


@pytest.fixture
def pcn_root(tmp_path):
    """PCN's layout: two categories, 2 train (8 scans each), 1 val and 2 test models (scan 00),
    complete clouds of 2,048 points (16,384 in PCN), scans cut from them as back-projections
    would (the part facing one viewpoint), written as binary PCD and one as ASCII."""
    from shapebench.api.contexts import CROP_VIEWPOINTS, crop_keep

    root = tmp_path / "PCN"
    catalog = []
    for k, (synset, name, shape) in enumerate(
        [
            ("02691156", "airplane", trimesh.creation.box),
            ("03001627", "chair", trimesh.creation.icosphere),
        ]
    ):
        entry = {"taxonomy_id": synset, "taxonomy_name": name, "train": [], "val": [], "test": []}
        for i, folder in enumerate(["train", "train", "val", "test", "test"]):
            model = f"m{k}{i}"
            entry[folder].append(model)
            points, _ = trimesh.sample.sample_surface(shape(), 2048, seed=10 * k + i)
            points = points - points.mean(axis=0)
            points = points / np.linalg.norm(points, axis=1).max() * 0.9
            complete = root / folder / "complete" / synset / f"{model}.pcd"
            complete.parent.mkdir(parents=True, exist_ok=True)
            write_pcd(complete, points)
            for view in range(8 if folder == "train" else 1):
                keep = crop_keep(points, -CROP_VIEWPOINTS[view], 0.6)
                scan = root / folder / "partial" / synset / model / f"{view:02d}.pcd"
                scan.parent.mkdir(parents=True, exist_ok=True)
                write_pcd(scan, points[keep], binary=(i, view) != (3, 0))
        catalog.append(entry)
    (root / "PCN.json").write_text(__import__("json").dumps(catalog))
    return root


def test_pcn_splits_scans_and_ground_truth(pcn_root, tmp_path) -> None:
    from shapebench_pointclouds.pcn import PCNDataset, PCNOptions

    ds = PCNDataset(PCNOptions(), tmp_path / "cache", pcn_root)
    assert [(c.name, c.split) for c in ds.categories()] == [
        ("airplane", TRAINED),
        ("chair", TRAINED),
    ]
    assert [r.id for r in ds.objects(TRAINED)] == [
        "airplane/m03",
        "airplane/m04",
        "chair/m13",
        "chair/m14",
    ]
    assert [r.id for r in ds.objects(VALIDATION)] == ["airplane/m02", "chair/m12"]
    assert len(ds.objects(TRAIN)) == 4
    data = ds.load(ds.objects(TRAINED)[0])  # the ASCII scan
    assert data.gt_points.shape == (2048, 3) and len(data.surface_points) == 2048 - int(0.6 * 2048)
    assert ds.scan_path(ds.objects(TRAINED)[0]).name == "00.pcd"
    # A training model's scan is picked by the seed among its 8, and fixed by view=.
    views = {ds.scan_path(r).name for r in ds.objects(TRAIN)}
    assert views <= {f"{v:02d}.pcd" for v in range(8)}
    fixed = PCNDataset(PCNOptions(view=5), tmp_path / "cache", pcn_root)
    assert {fixed.scan_path(r).name for r in fixed.objects(TRAIN)} == {"05.pcd"}


@pytest.mark.slow  # runs the CLI
def test_pcn_from_the_command_line(shapebench, pcn_root) -> None:
    base = ("run", "-m", "gauss", "-d", "pcn", "--data-root", str(pcn_root), "-q")
    res = shapebench(*base, "--contexts", "256")
    assert res.returncode == 0, res.stdout + res.stderr
    assert "pcn/trained: 4 objects in 2 categories" in res.stdout
    res = shapebench(*base, "--contexts", "2048")
    assert res.returncode == 2 and "larger than the 820 visible surface points" in res.stderr
    res = shapebench(*base, "--split", "validation", "--contexts", "256")
    assert res.returncode == 0 and "pcn/validation: 2 objects" in res.stdout


# -- partial scans without ground truth -----------------------------------------------------------


@pytest.mark.slow  # runs the CLI
def test_partial_scans_are_completed_pictured_and_scored_by_fidelity_only(shapebench, tmp_path):
    root = tmp_path / "scans"
    (root / "cars").mkdir(parents=True)
    box = trimesh.sample.sample_surface(trimesh.creation.box(), 3000, seed=1)[0] * 2 + 5
    write_pcd(root / "cars" / "a.pcd", box)
    np.save(root / "cars" / "b.npy", box)
    np.savetxt(root / "c.xyz", np.c_[box, np.ones(len(box))])  # a fourth column, ignored
    trimesh.PointCloud(box).export(root / "cars" / "d.ply")
    (root / "cars" / "broken.pcd").write_text("garbage")
    base = ("run", "-m", "gauss", "-d", "partials", "--data-root", str(root), "--contexts", "50")
    res = shapebench(*base, "-q")
    assert res.returncode == 0, res.stdout + res.stderr
    assert "gauss on partials/novel: fidelity x1000" in res.stdout
    assert "scans/cars/broken.pcd is not a PCD file" in res.stdout
    runs = shapebench.cell_runs("partials-novel")
    assert len(runs) == 1 and runs[0].data.metrics["failures"] == 1.0
    assert {k for k in runs[0].data.tags if k.startswith("card.")} == {"card.fidelity"}
    artifacts = {a.path for a in shapebench.client().list_artifacts(runs[0].info.run_id)}
    assert "pictures" in artifacts  # completions pictured, without a ground-truth panel
    res = shapebench(*base, "--metric", "chamfer-l2")
    assert res.returncode == 2
    assert "metric chamfer-l2 does not apply to dataset 'partials': it has no ground" in res.stderr
    res = shapebench(*base, "--protocol", "crop", "--crop-fraction", "0.5")
    assert res.returncode == 2 and "has none" in res.stderr
