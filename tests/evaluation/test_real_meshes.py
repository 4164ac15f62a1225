"""Real third-party meshes (../shared/data) next to broken files: failures stay per object."""

from __future__ import annotations

from pathlib import Path

import pandas as pd
import pytest
import trimesh

from shapebench.api.dataset import MeshDataset, ObjectLoadError
from shapebench.api.types import NOVEL, Category, ObjectRef
from shapebench.config import make_settings
from shapebench.evaluation.plan import RunPlan
from shapebench.evaluation.runner import Runner
from shapebench.registry.discovery import get_registry
from shapebench.registry.resolve import resolve_method, resolve_metrics
from shapebench.store.tracking import Tracker

SHARED = Path(__file__).resolve().parents[3] / "shared" / "data" / "meshes"
REAL = ["common-3d-test-models/data/spot.obj", "common-3d-test-models/data/suzanne.obj"]

pytestmark = [
    pytest.mark.skipif(not SHARED.exists(), reason="../shared/data (real meshes) is not present"),
    pytest.mark.slow,  # scores real meshes through the Runner and MLflow: about 6 s
]


class FilesDataset(MeshDataset):
    """A minimal mesh dataset over explicit files, all in one novel category."""

    name = "files"

    def __init__(self, options, cache_dir, files: dict[str, Path]) -> None:
        super().__init__(options, cache_dir)
        self.files = files

    def categories(self):
        return [Category("misc", NOVEL)]

    def objects(self, split):
        return [ObjectRef(k, "misc") for k in self.files] if split == NOVEL else []

    def mesh(self, ref):
        return trimesh.load(self.files[ref.id], force="mesh")


def test_broken_files_fail_alone_and_real_meshes_are_scored(tmp_path):
    corrupt = tmp_path / "corrupt.obj"
    corrupt.write_text("v 0 0 0\nv 1 oops 0\nf 1 2 3\n")
    empty = tmp_path / "empty.obj"
    empty.write_text("")
    files = {Path(p).stem: SHARED / p for p in REAL} | {"corrupt": corrupt, "empty": empty}
    options = FilesDataset.Options(surface_candidates=4000, gt_points=3000)
    dataset = FilesDataset(options, tmp_path / "cache", files)

    settings = make_settings(
        f"sqlite:///{tmp_path / 'db.sqlite'}", tmp_path / "cache", "quick", tmp_path
    )
    registry = get_registry()
    method = resolve_method(registry, "gauss", settings)
    plan = RunPlan(method, dataset, [NOVEL], [50, 100], [0], resolve_metrics(registry, None))
    tracker = Tracker(settings)
    cells = Runner(tracker, echo=lambda _: None).run(plan, method.instantiate)
    assert [c.metrics["failures"] for c in cells] == [2.0, 2.0]

    run_id = cells[0].run_id
    path = tracker.client.download_artifacts(run_id, "per_object.csv", str(tmp_path))
    table = pd.read_csv(path, keep_default_na=False).set_index("object")
    assert table.loc["spot", "status"] == table.loc["suzanne", "status"] == "ok"
    assert float(table.loc["spot", "chamfer-l2"]) > 0
    assert table.loc["empty", "status"] == "failed" and "no faces" in table.loc["empty", "error"]
    assert table.loc["corrupt", "status"] == "failed" and table.loc["corrupt", "error"]
    # The reason is cached with the data version, so later runs do not re-read the bad file.
    with pytest.raises(ObjectLoadError, match="no faces"):
        dataset.load(ObjectRef("empty", "misc"))
    assert dataset.cache_path(ObjectRef("empty", "misc")).with_suffix(".error.txt").exists()
