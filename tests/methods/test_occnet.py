"""OccNet: occupancy labels on analytic shapes, both decoders, training lowers the loss, and the
paper's training queries (from the SDF samples) against the official uniform ones."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch
import trimesh
from shapebench_occnet.method import OccNet
from shapebench_occnet.module import OccNetModule

from shapebench.api.dataset import Dataset
from shapebench.api.method import TrainerOptions, TrainingContext
from shapebench.api.types import TRAIN, TRAINED, Category, ObjectData, ObjectRef, Supervision
from shapebench.preprocess.samples import occupancy_from_sdf, occupancy_samples, sdf_samples


def _labels_match(mesh: trimesh.Trimesh, truth, margin: float) -> float:
    s = occupancy_samples(mesh, 20_000, np.random.default_rng(0))
    inside_truth, distance = truth(s[:, :3])
    clear = distance > margin  # away from the facets, the answer is unambiguous
    return float((s[clear, 3] == inside_truth[clear]).mean())


def test_occupancy_of_a_sphere_a_box_and_a_mesh_with_a_hole():
    sphere = trimesh.creation.icosphere(subdivisions=3, radius=0.6)

    def in_sphere(p):
        r = np.linalg.norm(p, axis=1)
        return r < 0.6, np.abs(r - 0.6)

    assert _labels_match(sphere, in_sphere, 0.02) == 1.0
    box = trimesh.creation.box((1.0, 0.6, 1.4))

    def in_box(p):
        half = np.array([0.5, 0.3, 0.7])
        gap = half - np.abs(p)
        return (gap > 0).all(axis=1), np.abs(gap).min(axis=1)

    assert _labels_match(box, in_box, 1e-3) == 1.0
    # Four missing triangles: no longer watertight, the three-ray vote must still be right.
    holed = trimesh.Trimesh(sphere.vertices, sphere.faces[:-4], process=False)
    assert not holed.is_watertight
    assert _labels_match(holed, in_sphere, 0.02) > 0.999


@pytest.mark.slow  # trains: 15-20 s per decoder
@pytest.mark.parametrize("decoder", ["batchnorm", "cbatchnorm"])
def test_a_few_training_steps_lower_the_bce(decoder):
    torch.manual_seed(0)
    options = OccNet.Options(
        c_dim=32,
        hidden_dim=32,
        decoder=decoder,
        decoder_hidden=32,
        lr=1e-3,
        input_points=300,
        input_noise=0.005,
    )
    module = OccNet(options).build_module(0)
    assert isinstance(module, OccNetModule) and module.options.decoder == decoder
    sphere = trimesh.creation.icosphere(subdivisions=3, radius=0.6)
    occ = torch.from_numpy(occupancy_samples(sphere, 4096, np.random.default_rng(1)))
    pts = torch.from_numpy(sphere.sample(300).astype(np.float32))
    batch = {"points": pts[None].repeat(4, 1, 1), "occupancy": occ.view(4, 1024, 4)}
    opt = torch.optim.Adam(module.parameters(), lr=1e-3)
    losses = []
    for _ in range(40):
        loss = module.loss(batch["points"], batch["occupancy"])
        opt.zero_grad()
        loss.backward()
        opt.step()
        losses.append(float(loss))
    assert losses[-1] < 0.5 * losses[0]


def test_context_sizes_draw_one_encoder_size_per_batch():
    from shapebench.api.errors import ConfigError

    batch = {"points": torch.zeros(2, 1000, 3)}
    official = OccNet(OccNet.Options(c_dim=8, hidden_dim=8, decoder_hidden=8)).build_module(0)
    assert official.encoder_input(batch).shape == (2, 300, 3)  # input_points, always
    options = OccNet.Options(
        c_dim=8, hidden_dim=8, decoder_hidden=8, context_sizes=(50, 1000), surface_points=1000
    )
    module = OccNet(options).build_module(0)
    gen = torch.Generator().manual_seed(0)
    sizes = {module.encoder_input(batch, gen).shape[1] for _ in range(40)}
    assert sizes == {50, 1000}
    # The largest size must be loaded: one clear error naming the fix.
    with pytest.raises(ConfigError, match="surface_points=1000"):
        OccNet(OccNet.Options(context_sizes=(50, 1000)))


class _OneMesh(Dataset):
    """One training object, a thin box in the unit-sphere frame; answers exactly what is asked."""

    name = "one-mesh"

    def __init__(self, mesh: trimesh.Trimesh) -> None:
        super().__init__(None, Path("."))
        self.mesh = mesh

    def categories(self) -> list[Category]:
        return [Category("box", TRAINED)]

    def objects(self, split: str) -> list[ObjectRef]:
        return [ObjectRef("box/0", "box")] if split == TRAIN else []

    def load(self, ref: ObjectRef, need: frozenset[Supervision] = frozenset()) -> ObjectData:
        rng = np.random.default_rng(0)
        pts, faces = self.mesh.sample(2000, return_index=True)
        extra = {}
        if Supervision.SDF_SAMPLES in need:
            extra["sdf"] = sdf_samples(self.mesh, 20_000, rng)
        if Supervision.OCCUPANCY_SAMPLES in need:
            extra["occupancy"] = occupancy_samples(self.mesh, 20_000, rng)
        return ObjectData(
            ref,
            pts.astype(np.float32),
            self.mesh.face_normals[faces].astype(np.float32),
            pts,
            extra,
        )


def _inside_fraction(recipe: str, tmp_path: Path) -> float:
    box = trimesh.creation.box((0.3, 0.5, 1.8))
    box.apply_scale(1.0 / np.linalg.norm(box.vertices, axis=1).max())  # the unit-sphere frame
    method = OccNet(OccNet.Options(recipe=recipe, query_points=2048, batch_shapes=1))
    ctx = TrainingContext(_OneMesh(box), TrainerOptions(), tmp_path, "", quiet=True)
    data = method.data_module(ctx)
    data.load_objects()
    batch = next(iter(data.train_dataloader()))
    return float(batch["occupancy"][..., 3].mean())


def test_paper_queries_come_from_sdf_samples_and_are_often_inside(tmp_path):
    paper = OccNet(OccNet.Options())  # the default recipe is the paper's
    assert paper.options.queries == "paper"
    assert Supervision.SDF_SAMPLES in paper.needs()
    assert Supervision.OCCUPANCY_SAMPLES not in paper.needs()
    official = OccNet(OccNet.Options(recipe="official"))
    assert official.options.queries == "uniform"
    assert Supervision.OCCUPANCY_SAMPLES in official.needs()
    assert paper.needs() | official.needs() <= OccNet.supervision  # prepare -m builds both
    assert _inside_fraction("paper", tmp_path) > 0.2
    assert _inside_fraction("official", tmp_path) < 0.05  # why the paper's queries matter


def test_occupancy_from_sdf_labels_inside_where_sdf_is_negative():
    sdf = np.array([[0, 0, 0, -0.1], [1, 1, 1, 0.2], [0.5, 0, 0, 0.0]], dtype=np.float32)
    occ = occupancy_from_sdf(sdf)
    assert occ.dtype == np.float32 and occ.shape == (3, 4)
    assert occ[:, 3].tolist() == [1.0, 0.0, 0.0] and np.array_equal(occ[:, :3], sdf[:, :3])
