"""``shapebench.evaluation.prepare``: parallel preprocessing gives the same arrays, failures are
reported."""

from __future__ import annotations

import os
import pickle
import sys
import types
from pathlib import Path

import numpy as np
import pytest
import trimesh

try:
    import shapebench_meshes  # noqa: F401
except ModuleNotFoundError:  # the checkout was installed before this plugin existed
    sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "datasets"))

from shapebench_iclnuim.dataset import ICLNUIMDataset, ICLNUIMOptions  # noqa: E402
from shapebench_meshes.dataset import MeshFolderDataset, MeshFolderOptions  # noqa: E402
from shapebench_shapenet.dataset import ShapeNetDataset, ShapeNetOptions  # noqa: E402
from shapebench_synthetic.dataset import SyntheticDataset, SyntheticOptions  # noqa: E402

from shapebench.api.dataset import ObjectLoadError  # noqa: E402
from shapebench.api.errors import ConfigError, ShapebenchError  # noqa: E402
from shapebench.api.types import NOVEL, TRAIN, TRAINED  # noqa: E402
from shapebench.evaluation.prepare import prepare  # noqa: E402

TINY = MeshFolderOptions(surface_candidates=2000, gt_points=1500, viewpoints=30)


def make_meshes(root: Path) -> Path:
    (root / "solids").mkdir(parents=True)
    (root / "round").mkdir()
    trimesh.creation.box(extents=(1, 2, 3)).export(root / "solids" / "box.obj")
    trimesh.creation.cylinder(0.5, 2.0).export(root / "solids" / "cylinder.stl")
    trimesh.creation.icosphere(2).export(root / "round" / "sphere.ply")
    trimesh.creation.capsule(1.0, 0.4).export(root / "round" / "capsule.off")
    (root / "round" / "broken.obj").write_text("v 0 0 0\nv 1 oops 0\nf 1 2 3\n")
    return root


def arrays(ds: MeshFolderDataset, ref) -> dict[str, np.ndarray]:
    with np.load(ds.cache_path(ref)) as z:
        return {k: z[k] for k in z.files}


@pytest.mark.slow  # starts worker processes: 3-10 s
def test_two_jobs_give_the_same_arrays_as_one_and_failures_are_reported(tmp_path):
    root = make_meshes(tmp_path / "data")
    parallel = MeshFolderDataset(TINY, tmp_path / "cache-2", root)
    serial = MeshFolderDataset(TINY, tmp_path / "cache-1", root)
    report2 = prepare(parallel, [NOVEL], frozenset(), jobs=2, quiet=True)
    report1 = prepare(serial, [NOVEL], frozenset(), jobs=1, quiet=True)
    for report in (report1, report2):
        assert (report.total, report.ok, report.cached) == (5, 4, 0)
        assert [f.ref.id for f in report.failures] == ["round/broken"]
        assert "broken.obj" in report.failures[0].reason
        assert report.seconds_per_object > 0 and report.per_split == {NOVEL: 5}
    for ref in serial.objects(NOVEL):
        if ref.id == "round/broken":
            continue
        a, b = arrays(parallel, ref), arrays(serial, ref)
        assert a.keys() == b.keys()
        assert all(np.array_equal(a[k], b[k]) for k in a)

    again = prepare(parallel, [NOVEL], frozenset(), jobs=2, quiet=True)  # resumes from the cache
    assert (again.ok, again.cached, again.failed) == (4, 4, 1)
    assert "4/5 objects ready (4 already cached), 1 failed" in again.summary()


def test_categories_and_splits_are_checked(tmp_path):
    ds = MeshFolderDataset(TINY, tmp_path / "cache", make_meshes(tmp_path / "data"))
    report = prepare(ds, [NOVEL], frozenset(), jobs=1, quiet=True, categories=["Solids"])
    assert (report.total, report.ok) == (2, 2)
    with pytest.raises(ConfigError, match="no category 'chairs'"):
        prepare(ds, [NOVEL], frozenset(), jobs=1, quiet=True, categories=["chairs"])
    with pytest.raises(ConfigError, match="no split 'all'"):
        prepare(ds, ["all"], frozenset(), jobs=1, quiet=True)
    trained = MeshFolderDataset(
        MeshFolderOptions(surface_candidates=2000, gt_points=1500, train_fraction=0.5),
        tmp_path / "cache",
        tmp_path / "data",
    )
    report = prepare(trained, [TRAIN, TRAINED], frozenset(), jobs=1, quiet=True)
    assert report.total == 5 and sum(report.per_split.values()) == 5


class CrashingDataset(MeshFolderDataset):
    """Kills its process on ``solids/box`` (unless told not to) and has a plain bug on
    ``round/sphere``."""

    def mesh(self, ref):
        if ref.id == "solids/box" and not os.environ.get("SHAPEBENCH_TEST_NO_CRASH"):
            os._exit(3)
        if ref.id == "round/sphere":
            raise KeyError("a bug, not an ObjectLoadError")
        return super().mesh(ref)


@pytest.mark.slow  # starts worker processes: 3-10 s
def test_a_dying_worker_fails_only_its_object(tmp_path):
    ds = CrashingDataset(TINY, tmp_path / "cache", make_meshes(tmp_path / "data"))
    report = prepare(ds, [NOVEL], frozenset(), jobs=2, quiet=True)
    reasons = {f.ref.id: f.reason for f in report.failures}
    assert sorted(reasons) == ["round/broken", "round/sphere", "solids/box"]
    assert "worker process died" in reasons["solids/box"]
    assert "a bug" in reasons["round/sphere"]  # recorded by the dataset, not raised
    assert report.ok == 2


def test_failures_in_process_are_reported_not_raised(tmp_path, monkeypatch):
    monkeypatch.setenv("SHAPEBENCH_TEST_NO_CRASH", "1")
    ds = CrashingDataset(TINY, tmp_path / "cache", make_meshes(tmp_path / "data"))
    report = prepare(ds, [NOVEL], frozenset(), jobs=1, quiet=True)
    assert report.ok == 3 and sorted(f.ref.id for f in report.failures) == [
        "round/broken",
        "round/sphere",
    ]
    with pytest.raises(ObjectLoadError):  # the reason stays cached with the object
        ds.load(next(r for r in ds.objects(NOVEL) if r.id == "round/sphere"))


def test_every_builtin_dataset_pickles(tmp_path):
    """Workers receive the dataset by pickle (spawn): options, paths and listings only."""
    datasets = [
        MeshFolderDataset(TINY, tmp_path, make_meshes(tmp_path / "data")),
        ShapeNetDataset(ShapeNetOptions(categories=["Chair"]), tmp_path, tmp_path / "shapenet"),
        ICLNUIMDataset(ICLNUIMOptions(), tmp_path, tmp_path / "icl"),
        SyntheticDataset(SyntheticOptions(), tmp_path),
    ]
    datasets[0].objects(NOVEL)  # with its listing loaded
    for ds in datasets:
        clone = pickle.loads(pickle.dumps(ds))
        assert type(clone) is type(ds) and clone.options == ds.options


@pytest.mark.slow  # starts worker processes: 3-10 s
def test_workers_that_cannot_start_stop_prepare_at_once(tmp_path, monkeypatch):
    """A dataset class that only exists in this process cannot be rebuilt by a worker."""
    module = types.ModuleType("shapebench_test_only_here")
    ns = {"MeshFolderDataset": MeshFolderDataset}
    exec("class Here(MeshFolderDataset):\n    pass\n", ns)
    module.Here = ns["Here"]
    ns["Here"].__module__ = module.__name__
    monkeypatch.setitem(sys.modules, module.__name__, module)
    ds = module.Here(TINY, tmp_path / "cache", make_meshes(tmp_path / "data"))
    with pytest.raises(ShapebenchError, match="cannot load dataset") as err:
        prepare(ds, [NOVEL], frozenset(), jobs=2, quiet=True)
    assert "--jobs 1" in str(err.value)
