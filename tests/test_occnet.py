"""OccNet: occupancy labels on analytic shapes, both decoders, training lowers the loss."""

from __future__ import annotations

import numpy as np
import pytest
import torch
import trimesh
from shapebench_occnet.module import OccNetModule

from shapebench.preprocess.samples import occupancy_samples


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


@pytest.mark.parametrize("decoder", ["batchnorm", "cbatchnorm"])
def test_a_few_training_steps_lower_the_bce(decoder):
    torch.manual_seed(0)
    module = OccNetModule(c_dim=32, hidden_dim=32, decoder=decoder, decoder_hidden=32, lr=1e-3,
                          input_points=300, input_noise=0.005)  # fmt: skip
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
