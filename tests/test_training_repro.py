"""Training is reproducible: the same seed gives bitwise-identical weights, another seed does not;
and every training ends with a summary on stderr and in its MLflow run."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch
import trimesh
from shapebench_msc.method import MSC

from shapebench.api.dataset import Dataset
from shapebench.api.method import TrainerOptions, TrainingContext
from shapebench.api.types import TRAIN, TRAINED, Category, ObjectData, ObjectRef, Supervision

pytestmark = pytest.mark.slow  # every test trains with Lightning

#: A tiny MSC: its training step draws context and target subsets, the reparameterised code and
#: Eikonal samples, and its data module draws surface points and the shuffle order.
TINY_MSC = dict(
    latent_dim=8,
    width=32,
    depth=2,
    encoder_width=16,
    encoder_layers=1,
    epochs=2,
    batch_shapes=2,
    surface_points=64,
    max_target=32,
    lr=1e-3,
)


class _Shapes(Dataset):
    """A handful of small training meshes held in memory."""

    name = "shapes"

    def __init__(self, meshes: list[trimesh.Trimesh]) -> None:
        super().__init__(None, Path("."))
        self.meshes = meshes

    def categories(self) -> list[Category]:
        return [Category("blob", TRAINED)]

    def objects(self, split: str) -> list[ObjectRef]:
        if split != TRAIN:
            return []
        return [ObjectRef(f"blob/{i}", "blob") for i in range(len(self.meshes))]

    def load(self, ref: ObjectRef, need: frozenset[Supervision] = frozenset()) -> ObjectData:
        mesh = self.meshes[int(ref.id.split("/")[1])]
        pts, faces = trimesh.sample.sample_surface(mesh, 500, seed=0)
        normals = mesh.face_normals[faces]
        return ObjectData(
            ref, pts.astype(np.float32), normals.astype(np.float32), pts.astype(np.float32)
        )


def _meshes() -> list[trimesh.Trimesh]:
    return [
        trimesh.creation.icosphere(2, radius=0.5),
        trimesh.creation.box((0.8, 0.5, 0.3)),
        trimesh.creation.capsule(0.6, 0.2),
        trimesh.creation.box((0.3, 0.3, 1.0)),
    ]


def _train(
    tmp_path: Path,
    seed: int,
    name: str,
    tracking_uri: str = "",
    run_id: str | None = None,
    quiet: bool = True,
) -> dict[str, torch.Tensor]:
    """Two epochs of the tiny MSC in this process; the weights it saved."""
    trainer = TrainerOptions(accelerator="cpu", devices=1, seed=seed)
    ctx = TrainingContext(_Shapes(_meshes()), trainer, tmp_path / name, tracking_uri, run_id, quiet)
    path = MSC(MSC.Options(**TINY_MSC)).fit(ctx)
    return torch.load(path, map_location="cpu", weights_only=False)["state_dict"]


def _same(a: dict[str, torch.Tensor], b: dict[str, torch.Tensor]) -> bool:
    return a.keys() == b.keys() and all(torch.equal(a[k], b[k]) for k in a)


def test_same_seed_same_weights_other_seed_other_weights(tmp_path):
    first = _train(tmp_path, seed=3, name="a")
    # Draw from the global generators in between: the second training must not depend on it.
    torch.rand(100)
    np.random.rand(100)
    again = _train(tmp_path, seed=3, name="b")
    other = _train(tmp_path, seed=4, name="c")
    assert _same(first, again)
    assert not _same(first, other)


def test_training_ends_with_a_summary_on_stderr_and_in_mlflow(tmp_path, capsys):
    from mlflow.tracking import MlflowClient

    uri = f"sqlite:///{tmp_path / 'mlflow.db'}"
    client = MlflowClient(uri)
    run_id = client.create_run(client.create_experiment("train")).info.run_id
    _train(tmp_path, seed=0, name="s", tracking_uri=uri, run_id=run_id, quiet=False)
    err = capsys.readouterr().err
    assert "training done" in err and "2 epochs" in err and "4 optimiser steps" in err
    assert "elbo" in err and "eikonal" in err
    metrics = client.get_run(run_id).data.metrics
    assert metrics["summary/epochs"] == 2 and metrics["summary/optimizer_steps"] == 4
    assert metrics["summary/wall_seconds"] > 0 and "summary/final_loss" in metrics
    assert client.get_run(run_id).data.tags["training_device"].startswith("cpu")
