"""The point-cloud method base (PointCloudMethod, PointCloudModule): the ~40-line example of
docs/plugins.md ("A point-cloud method") registers without torch, trains a step or two on tiny data,
and completes an object, with no core code of its own; and PCN and PoinTr stand on the same base."""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from conftest import ROOT
from tiny_datasets import Blobs  # three small meshes with their complete clouds

from shapebench.api.method import TrainerOptions, TrainingContext
from shapebench.api.types import Context, ObjectRef, Supervision
from shapebench.registry.code_digest import digest_sources
from shapebench.train.point_cloud_method import PointCloudMethod

PACKAGE = "shapebench_pointmlp"


def _docs_example(root: Path) -> dict[str, str]:
    """The example's files as docs/plugins.md shows them, written under ``root``."""
    doc = (ROOT / "docs" / "plugins.md").read_text()
    doc = doc.split("### A point-cloud method")[1].split("\n## ")[0]
    package = root / PACKAGE
    package.mkdir()
    (package / "__init__.py").write_text("")
    files = {}
    for name in ("method.py", "module.py"):
        block = re.search(rf"`{PACKAGE}/{name}`:\n\n```python\n(.*?)```", doc, re.DOTALL)
        assert block, f"docs/plugins.md has no block for {PACKAGE}/{name}"
        files[name] = block.group(1)
        (package / name).write_text(files[name])
    return files


def test_the_docs_example_is_about_forty_lines(tmp_path):
    files = _docs_example(tmp_path)
    lines = [line for text in files.values() for line in text.splitlines() if line.strip()]
    assert len(lines) <= 45, f"the docs promise about 40 lines, the example has {len(lines)}"


def test_pcn_and_pointr_stand_on_the_base_and_its_files_are_in_their_keys():
    from shapebench_pcn.method import PCN
    from shapebench_pointr.method import PoinTr

    for cls in (PCN, PoinTr):
        assert issubclass(cls, PointCloudMethod)
        sources = digest_sources(cls)
        for name in ("point_cloud_method", "point_cloud_module", "lightning_method"):
            assert f"shapebench.train.{name}.py" in sources, (cls.__name__, name)


@pytest.mark.slow  # trains with Lightning: a few seconds
def test_the_docs_example_trains_and_completes_an_object(tmp_path, monkeypatch):
    _docs_example(tmp_path)
    monkeypatch.syspath_prepend(str(tmp_path))
    probe = (
        f"import sys; import {PACKAGE}.method; "
        "assert 'torch' not in sys.modules, 'method.py imports torch'"
    )
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(tmp_path), *sys.path])}
    subprocess.run([sys.executable, "-c", probe], check=True, env=env)
    from shapebench_pointmlp.method import PointMLP

    options = PointMLP.Options(
        width=16,
        output_points=64,
        context_sizes=(20, 50),
        surface_points=50,
        target_points=128,
        epochs=1,
        batch_shapes=2,
    )
    method = PointMLP(options)
    assert method.sample_sizes() == {
        Supervision.SURFACE_POINTS: 50,
        Supervision.COMPLETE_POINTS: 128,
    }
    trainer = TrainerOptions(accelerator="cpu", devices=1, seed=0)
    ctx = TrainingContext(Blobs(), trainer, tmp_path / "train", "", quiet=True)
    path = method.fit(ctx)  # one epoch of three objects in batches of two: two steps
    summary = json.loads((ctx.workdir / "summary.json").read_text())
    assert summary["optimizer_steps"] == 2
    assert {"train/loss", "train/chamfer"} <= set(summary["final"])  # each term is logged
    fresh = PointMLP(method.options)
    fresh.load_checkpoint(path)
    blob = Blobs().load(ObjectRef("blob/1", "blob"))
    context = Context(blob.ref, blob.surface_points[:30], None, seed=0)
    results = fresh.complete_batch([context, context], n_points=500)
    assert all(not isinstance(r, Exception) for r in results), results
    points = results[0].points
    assert points.shape == (64, 3) and points.dtype == np.float32  # the method's own size
    assert np.isfinite(points).all()
    assert np.array_equal(points, results[1].points)
