"""The ``shapenet`` dataset on small ShapeNetCore v1 and v2 trees written in the real layout.

The meshes are procedural and written the way ShapeNet's are messy: multi-material OBJ files
(with a missing material library and an empty material group), flipped faces, an open
(non-watertight) mesh with a duplicated sheet, a model folder without its mesh, and one
unreadable file.
"""

from __future__ import annotations

import json
import pickle
import sys
from pathlib import Path

import numpy as np
import pytest
import trimesh

try:
    import shapebench_shapenet  # noqa: F401
except ModuleNotFoundError:  # the checkout was installed before this plugin existed
    sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "datasets"))

from shapebench_shapenet.dataset import ShapeNetDataset, ShapeNetOptions  # noqa: E402

from shapebench.api.dataset import ObjectLoadError  # noqa: E402
from shapebench.api.errors import ConfigError, DataNotFoundError  # noqa: E402
from shapebench.api.types import (  # noqa: E402
    NOVEL,
    TRAIN,
    TRAINED,
    VALIDATION,
    Category,
    ObjectRef,
    Supervision,
)

CHAIR, PLANE = "03001627", "02691156"  # trained categories of the paper
BUS, BENCH = "02924116", "02828884"  # novel categories of the paper
V1, V2 = "model.obj", "models/model_normalized.obj"
TINY = {"surface_candidates": 3000, "gt_points": 2000, "sdf_samples": 2000}


def write_multimaterial_obj(path: Path, mesh: trimesh.Trimesh) -> None:
    """``mesh`` as ShapeNet writes it: faces spread over material groups, a missing .mtl with a
    texture, an empty group and a polyline that is not a surface."""
    lines = ["mtllib model.mtl"]
    lines += [f"v {x:.6f} {y:.6f} {z:.6f}" for x, y, z in mesh.vertices]
    lines += ["vt 0.0 0.0", "vt 1.0 0.0", "vn 0.0 0.0 1.0"]
    lines += ["g empty", "usemtl unused"]
    for i, group in enumerate(np.array_split(np.asarray(mesh.faces), 3)):
        lines += [f"g part{i}", f"usemtl material_{i}"]
        lines += [f"f {a + 1}/1/1 {b + 1}/2/1 {c + 1}/1/1" for a, b, c in group]
    lines += ["l 1 2"]
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("\n".join(lines) + "\n")


def flipped_box(extents) -> trimesh.Trimesh:
    """A closed box with every other face wound backwards (inconsistent normals)."""
    box = trimesh.creation.box(extents=extents)
    faces = np.asarray(box.faces).copy()
    faces[::2] = faces[::2, ::-1]
    return trimesh.Trimesh(box.vertices, faces, process=False)


def open_sheeted_box() -> trimesh.Trimesh:
    """Non-watertight: the top is missing, one side has a duplicated, reversed sheet."""
    box = trimesh.creation.box(extents=(1.0, 0.6, 0.8))
    centers = box.triangles_center
    keep = centers[:, 1] < 0.29  # drop the two top triangles
    faces = np.asarray(box.faces)[keep]
    side = faces[centers[keep][:, 0] > 0.49]
    mesh = trimesh.Trimesh(box.vertices, np.vstack([faces, side[:, ::-1]]), process=False)
    assert not mesh.is_watertight
    return mesh


def model(root: Path, synset: str, name: str, layout: str, mesh: trimesh.Trimesh | None) -> None:
    path = root / synset / name / layout
    if mesh is None:
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text("v 0 0 0\nv 1 oops 0\nf 1 2 3\n")  # unreadable
    else:
        write_multimaterial_obj(path, mesh)


def shapenet_v1(root: Path) -> Path:
    for i in range(4):
        model(root, CHAIR, f"chair{i}", V1, flipped_box((0.5 + 0.1 * i, 1.0, 0.5)))
    model(root, CHAIR, "chair-broken", V1, None)
    model(root, BUS, "bus-open", V1, open_sheeted_box())
    for i in range(2):
        model(root, BUS, f"bus{i}", V1, trimesh.creation.box(extents=(2.0, 0.8, 0.7 + 0.1 * i)))
    (root / "99999999" / "x").mkdir(parents=True)  # not a category of the paper: ignored
    (root / "taxonomy.json").write_text("[]")
    return root


def shapenet_v2(root: Path) -> Path:
    for i in range(3):
        model(root, PLANE, f"plane{i}", V2, trimesh.creation.capsule(0.3, 0.2 + 0.05 * i))
    for i in range(2):
        model(root, BENCH, f"bench{i}", V2, trimesh.creation.box(extents=(1.5, 0.4, 0.4)))
    (root / BENCH / "no-mesh" / "models").mkdir(parents=True)  # v2 ships a few like this
    (root / BENCH / "no-mesh" / "models" / "model_normalized.json").write_text("{}")
    return root


def shapenet(root: Path | None, cache: Path, **options) -> ShapeNetDataset:
    return ShapeNetDataset(ShapeNetOptions(**(TINY | options)), cache, root)


def test_v1_tree_gives_the_papers_categories_and_a_deterministic_split(tmp_path):
    root = shapenet_v1(tmp_path / "v1")
    ds = shapenet(root, tmp_path / "cache")
    assert ds.categories() == [Category("Chair", TRAINED), Category("Bus", NOVEL)]
    train, test, novel = ds.objects(TRAIN), ds.objects(TRAINED), ds.objects(NOVEL)
    # ShapeNet ships no validation split: 2 training models of each trained category (the
    # default) are kept apart for choosing options, and leave training.
    validation = ds.objects(VALIDATION)
    assert ds.validation_splits == (VALIDATION,)
    assert {r.category for r in train + test + validation} == {"Chair"}
    assert len(train) + len(test) + len(validation) == 5 and len(validation) == 2
    assert len(test) == 1 and not {r.id for r in train} & {r.id for r in test}
    assert not {r.id for r in validation} & {r.id for r in train + test}
    everything = shapenet(root, tmp_path / "cache", validation_per_category=0)
    assert {r.id for r in everything.objects(TRAIN)} == {r.id for r in train + validation}
    assert everything.objects(VALIDATION) == []
    assert [r.category for r in novel] == ["Bus"] and len(novel) == 1  # 20% of 3 models
    assert all(r.id.startswith(f"{CHAIR}/") for r in train + test)
    again = shapenet(root, tmp_path / "other-cache")
    assert (again.objects(TRAIN), again.objects(TRAINED), again.objects(NOVEL)) == (
        train,
        test,
        novel,
    )
    assert ds.version == "shapenet-v1-prep1"
    whole = shapenet(root, tmp_path / "cache", test_fraction=1.0)
    assert whole.objects(TRAIN) == [] and len(whole.objects(TRAINED)) == 5
    capped = shapenet(root, tmp_path / "cache", test_fraction=1.0, max_test_per_category=2)
    assert len(capped.objects(TRAINED)) == 2 and len(capped.objects(NOVEL)) == 2


def test_v2_layout_models_without_mesh_and_mixed_trees(tmp_path):
    root = shapenet_v2(tmp_path / "v2")
    ds = shapenet(root, tmp_path / "cache", test_fraction=1.0)
    assert ds.categories() == [Category("Plane", TRAINED), Category("Bench", NOVEL)]
    assert [r.id for r in ds.objects(NOVEL)] == [f"{BENCH}/bench0", f"{BENCH}/bench1"]
    assert ds.version == "shapenet-v2-prep1"
    model(root, CHAIR, "chair-v1", V1, trimesh.creation.box())
    mixed = shapenet(root, tmp_path / "cache")
    assert mixed.version == "shapenet-v1+v2-prep1" and mixed.fingerprint() != ds.fingerprint()


def test_category_selection_by_name_or_synset(tmp_path):
    root = shapenet_v1(tmp_path / "v1")
    ds = shapenet(root, tmp_path / "cache", categories=["chair", BUS])
    assert [c.name for c in ds.categories()] == ["Chair", "Bus"]
    only = shapenet(root, tmp_path / "cache", categories=["Bus"], test_fraction=1.0)
    assert only.objects(TRAINED) == [] and len(only.objects(NOVEL)) == 3
    with pytest.raises(ConfigError, match="Sofaa"):
        shapenet(root, tmp_path / "cache", categories=["Sofaa"])
    with pytest.raises(DataNotFoundError, match="Plane"):
        shapenet(root, tmp_path / "cache", categories=["Plane", "Chair"]).categories()


def test_split_files_and_messy_meshes_fail_alone(tmp_path):
    root = shapenet_v1(tmp_path / "v1")
    splits = tmp_path / "splits"
    splits.mkdir()
    test_ids = [f"{CHAIR}/chair0", f"{CHAIR}/chair-broken", f"{BUS}/bus-open", f"{BUS}/bus0"]
    (splits / "test.txt").write_text("# ids\n" + "\n".join(test_ids) + f"\n{CHAIR}/gone\n")
    deepsdf = {"ShapeNetV1": {CHAIR: ["chair1", "chair2"], BUS: ["bus1"]}}
    (splits / "train.json").write_text(json.dumps(deepsdf))
    # The split files' training models, all of them (no validation split carved from them).
    ds = shapenet(root, tmp_path / "cache", split_dir=str(splits), validation_per_category=0)
    with pytest.warns(UserWarning, match="1 model"):
        trained = ds.objects(TRAINED)
    assert [r.id for r in trained] == [f"{CHAIR}/chair-broken", f"{CHAIR}/chair0"]
    assert [r.id for r in ds.objects(TRAIN)] == [f"{CHAIR}/chair1", f"{CHAIR}/chair2"]
    assert [r.id for r in ds.objects(NOVEL)] == [f"{BUS}/bus-open", f"{BUS}/bus0"]
    before = ds.fingerprint()
    (splits / "test.txt").write_text("\n".join(test_ids[1:]))  # edited in place: new test set
    edited = shapenet(root, tmp_path / "cache", split_dir=str(splits))
    assert edited.fingerprint() != before
    assert edited.cache_root == ds.cache_root  # the objects' arrays stay valid
    assert ds.fingerprint() == before

    broken = ObjectRef(f"{CHAIR}/chair-broken", "Chair")
    with pytest.raises(ObjectLoadError, match="chair-broken/model.obj"):
        ds.load(broken)
    # Every material group is there: 12 triangles of the box, the empty group and line dropped.
    assert len(ds.mesh(ObjectRef(f"{CHAIR}/chair0", "Chair")).faces) == 12
    chair = ds.load(ObjectRef(f"{CHAIR}/chair0", "Chair"))
    # Flipped faces are repaired: visible normals of the (convex, centred) box point out. (A
    # handful of samples within 1e-4 of an edge can come out flipped: see visibility.py.)
    assert len(chair.surface_points) > 2500
    outward = np.einsum("ij,ij->i", chair.surface_points, chair.surface_normals) > 0
    assert outward.mean() > 0.995
    bus = ds.load(ObjectRef(f"{BUS}/bus-open", "Bus"), frozenset({Supervision.SDF_SAMPLES}))
    assert len(bus.surface_points) > 1000 and bus.gt_points.shape == (2000, 3)
    sdf = bus.extra["sdf"]  # non-watertight: signs from the normal vote
    assert sdf.shape[1] == 4 and len(sdf) > 1000 and (sdf[:, 3] < 0).any()


def test_bad_split_dir_is_a_config_error(tmp_path):
    root = shapenet_v1(tmp_path / "v1")
    (tmp_path / "s").mkdir()
    with pytest.raises(ConfigError, match="test.txt"):
        shapenet(root, tmp_path / "cache", split_dir=str(tmp_path / "s")).objects(TRAINED)
    (tmp_path / "s" / "test.txt").write_text("03001627-chair0\n")
    with pytest.raises(ConfigError, match="<synset>/<model>"):
        shapenet(root, tmp_path / "cache", split_dir=str(tmp_path / "s")).objects(TRAINED)


def test_missing_shapenet_explains_how_to_get_it(tmp_path):
    for root in (None, tmp_path / "nowhere"):
        with pytest.raises(DataNotFoundError) as err:
            shapenet(root, tmp_path / "cache").categories()
        text = str(err.value)
        assert "shapenet.org" in text and "SHAPEBENCH_SHAPENET_ROOT" in text and V2 in text
    (tmp_path / "downloads" / "ShapeNetCore.v2" / CHAIR).mkdir(parents=True)
    (tmp_path / "downloads" / "02691156.zip").write_bytes(b"PK")
    with pytest.raises(DataNotFoundError) as err:
        shapenet(tmp_path / "downloads", tmp_path / "cache").objects(TRAINED)
    assert "ShapeNetCore.v2?" in str(err.value) and "extract" in str(err.value)
    assert "shapenet.org" in ShapeNetDataset.obtain_hint and ShapeNetDataset.needs_data_root


def test_dataset_pickles_with_its_listing(tmp_path):
    ds = shapenet(shapenet_v1(tmp_path / "v1"), tmp_path / "cache")
    refs = ds.objects(NOVEL)
    clone = pickle.loads(pickle.dumps(ds))
    assert clone.objects(NOVEL) == refs and clone.fingerprint() == ds.fingerprint()


def test_split_options_keep_the_cache_and_say_what_was_left_out(tmp_path):
    root = shapenet_v1(tmp_path / "v1")
    ds = shapenet(root, tmp_path / "cache")
    ref = ds.objects(TRAINED)[0]
    ds.load(ref)
    cached = ds.cache_path(ref)
    stamp = cached.stat().st_mtime_ns
    other = shapenet(root, tmp_path / "cache", test_fraction=0.5, max_test_per_category=1)
    assert other.fingerprint() != ds.fingerprint()  # another evaluated set
    assert other.cache_root == ds.cache_root  # the same arrays: nothing re-preprocessed
    other.load(ref)
    assert cached.stat().st_mtime_ns == stamp
    notes = " ".join(other.selection_notes(TRAINED))
    assert "at most 1 test models per category" in notes
    model(root, PLANE, "plane-only", V1, trimesh.creation.box(extents=(1.0, 0.3, 0.2)))
    single = shapenet(root, tmp_path / "cache")  # one model: all of it goes to training
    assert "Plane" not in {r.category for r in single.objects(TRAINED)}
    assert "1 category with no test model" in " ".join(single.selection_notes(TRAINED))
    assert "Plane" in " ".join(single.selection_notes(TRAINED))
