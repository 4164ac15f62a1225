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
    args = [
        "prepare",
        "-d",
        "meshes",
        "--data-root",
        str(root),
        "-D",
        "surface_candidates=2000",
        "-D",
        "gt_points=1000",
        "-q",
    ]
    res = shapebench(*args, "--jobs", "2")
    assert res.returncode == 0, res.stderr
    assert "2/3 objects ready (0 already cached), 1 failed" in res.stdout
    assert "failed: boxes/broken" in res.stdout
    again = shapebench(*args)
    assert "(2 already cached)" in again.stdout  # an interrupted or repeated prepare resumes


def test_prepare_shards_objects_over_submitit_jobs(shapebench, tmp_path):
    """The cluster path of prepare (submitit's local executor): each object in one shard."""
    root = tmp_path / "scans"
    (root / "shapes").mkdir(parents=True)
    for i in range(5):
        trimesh.creation.box((1, 1 + i, 2)).export(root / "shapes" / f"box{i}.obj")
    args = [
        "prepare",
        "-d",
        "meshes",
        "--data-root",
        str(root),
        "-D",
        "surface_candidates=2000",
        "-D",
        "gt_points=1000",
        "-q",
    ]
    res = shapebench(*args, "--launcher", "submitit-local", "--shards", "2", timeout=600)
    assert res.returncode == 0, res.stdout + res.stderr
    assert "2 prepare jobs" in res.stdout
    ready = [line for line in res.stdout.splitlines() if "objects ready" in line]
    assert sorted(line.split("] ", 1)[1].split(" objects")[0] for line in ready) == ["2/2", "3/3"]
    again = shapebench(*args)
    assert "5/5 objects ready (5 already cached)" in again.stdout
