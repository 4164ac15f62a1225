"""MSC with a hierarchical encoder (issue 30): the local tower by hand (neighbours, the pooled
maximum and its gradient against the naive gather, permutation equivariance, a per-point MLP when
it pools nothing), and equation 2 unchanged around it (order invariance, variance shrinking as
points are added)."""

from __future__ import annotations

import torch
from shapebench_mschier.method import MSCHierNoOpt, MSCHierOptions
from shapebench_mschier.module import MSCHierModule
from shapebench_mschier.network import LocalTower, gather_rows, knn_indices, neighbourhood_max


def test_knn_by_hand_itself_first_and_capped_by_the_context() -> None:
    # Points on a line at 0, 1, 3, 7: the 2 nearest of 3 are 3 itself and 1 (distance 2).
    x = torch.tensor([[[0.0, 0, 0], [1.0, 0, 0], [3.0, 0, 0], [7.0, 0, 0]]])
    idx = knn_indices(x, 2)
    assert idx[0, :, 0].tolist() == [0, 1, 2, 3]
    assert idx[0, 2].tolist() == [2, 1] and idx[0, 3].tolist() == [3, 2]
    assert knn_indices(x, 16).shape == (1, 4, 4)  # a 4-point context: every point


def test_the_pooled_maximum_and_its_gradient_equal_the_naive_gather() -> None:
    torch.manual_seed(0)
    values = torch.randn(2, 40, 8, requires_grad=True)
    idx = knn_indices(torch.randn(2, 40, 3), 5)
    naive = torch.stack([values[i][idx[i]] for i in range(2)])  # (B, N, k, C)
    assert torch.equal(gather_rows(values, idx), naive)
    weights = torch.arange(8.0)
    fast = neighbourhood_max(values, idx)
    (g_fast,) = torch.autograd.grad((fast * weights).sum(), values)
    slow = naive.max(dim=2).values
    (g_slow,) = torch.autograd.grad((slow * weights).sum(), values)
    assert torch.equal(fast, slow) and torch.allclose(g_fast, g_slow)


def test_the_tower_is_permutation_equivariant_and_local() -> None:
    torch.manual_seed(1)
    tower = LocalTower(4, 32, 6, neighbours=4, levels=2, head_layers=1)
    inp = torch.randn(1, 60, 4)
    perm = torch.randperm(60)
    assert torch.allclose(tower(inp)[:, perm], tower(inp[:, perm]), atol=1e-5)
    # One round of pooling is local: moving point 0 far away changes exactly the points whose
    # neighbourhood held it (and point 0 itself); every other output stays bit for bit.
    one = LocalTower(4, 32, 6, neighbours=4, levels=1, head_layers=1)
    moved = inp.clone()
    moved[0, 0, :3] += 100.0
    changed = (one(moved) - one(inp)).abs().amax(dim=-1)[0] > 0
    held = (knn_indices(inp[:, :, :3], 4)[0] == 0).any(dim=1)
    held[0] = True
    assert torch.equal(changed, held) and held.sum() > 1
    levels0 = LocalTower(4, 32, 6, neighbours=4, levels=0, head_layers=1)
    single = levels0(inp[:, :1])
    assert torch.allclose(levels0(inp)[:, :1], single)  # no pooling: a per-point MLP


def test_equation_2_around_the_towers_order_invariant_and_shrinking() -> None:
    torch.manual_seed(2)
    options = MSCHierOptions(latent_dim=8, width=32, depth=2, encoder_width=16, neighbours=4)
    module = MSCHierModule(options)
    # The votes start at zero: the first codes are the prior mean.
    pts = torch.randn(1, 100, 3)
    mean, var = module.encoder(pts)
    assert torch.allclose(mean, torch.zeros_like(mean))
    with torch.no_grad():
        module.encoder.f.head[-1].weight.normal_()
    mean, var = module.encoder(pts)
    perm = torch.randperm(100)
    mean_p, var_p = module.encoder(pts[:, perm])
    assert torch.allclose(mean, mean_p, atol=1e-5) and torch.allclose(var, var_p, atol=1e-6)
    _, var_few = module.encoder(pts[:, :10])
    assert (var < var_few).all()  # more points, more precision
    assert MSCHierNoOpt.checkpoint_family == "msc-hier"
