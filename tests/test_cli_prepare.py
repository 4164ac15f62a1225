"""`shapebench prepare` on a folder of meshes, one of them broken."""

from __future__ import annotations

import pytest
import trimesh

pytestmark = pytest.mark.slow  # runs the CLI in a subprocess


def test_prepare_reports_ready_and_failed_objects(shapebench, tmp_path):
    root = tmp_path / "scans"
    (root / "boxes").mkdir(parents=True)
    trimesh.creation.box((1, 2, 3)).export(root / "boxes" / "a.obj")
    trimesh.creation.icosphere().export(root / "boxes" / "b.ply")
    (root / "boxes" / "broken.obj").write_text("f 1 2 3\n")
    args = ["prepare", "-d", "meshes", "--data-root", str(root), "-D", "surface_candidates=2000",
            "-D", "gt_points=1000", "-q"]  # fmt: skip
    res = shapebench(*args, "--jobs", "2")
    assert res.returncode == 0, res.stderr
    assert "2/3 objects ready (0 already cached), 1 failed" in res.stdout
    assert "failed: boxes/broken" in res.stdout
    again = shapebench(*args)
    assert "(2 already cached)" in again.stdout  # an interrupted or repeated prepare resumes
