"""PCN: folding grid, losses, training lowers the loss, completion beats the raw context."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from shapebench_pcn.losses import alpha, sinkhorn_emd
from shapebench_pcn.method import PCN
from shapebench_pcn.module import PCNModule
from shapebench_pcn.network import PCNNetwork, folding_grid

from shapebench.api.types import Completion, ObjectData, ObjectRef
from shapebench.metrics.chamfer import ChamferL2
from shapebench.train.losses import chamfer_l1_halved


def test_folding_grid_has_the_official_shape_and_spacing():
    grid = folding_grid(4, 0.05)
    assert grid.shape == (16, 2)
    xs = torch.unique(grid[:, 0])
    assert torch.allclose(xs, torch.linspace(-0.05, 0.05, 4))
    assert torch.allclose(xs[1:] - xs[:-1], torch.full((3,), 0.1 / 3))
    net = PCNNetwork(feature=64, num_coarse=32, grid_size=4)
    coarse, fine = net(torch.randn(2, 50, 3))
    assert coarse.shape == (2, 32, 3) and fine.shape == (2, 512, 3)
    # Each coarse point owns 16 consecutive fine points, folded from its own grid.
    assert torch.allclose(fine.view(2, 32, 16, 3).mean(dim=2), coarse, atol=0.5)


def _linear_widths(layers: torch.nn.Module) -> list[int]:
    return [m.out_features for m in layers.modules() if isinstance(m, torch.nn.Linear)]


def _weights_outside_coarse(net: torch.nn.Module) -> int:
    return sum(p.numel() for n, p in net.named_parameters() if not n.startswith("coarse"))


def test_decoder_width_sizes_the_coarse_decoder_only():
    """``decoder_width`` (standard: 768, for weights that ship under 5 MB) changes the two hidden
    layers of the coarse decoder and nothing else; the default is the official 1024."""
    official = PCNNetwork(feature=256, num_coarse=256, grid_size=4)
    narrow = PCNNetwork(feature=256, num_coarse=256, grid_size=4, decoder_width=768)
    assert _linear_widths(narrow.coarse) == [768, 768, 3 * 256]
    assert _linear_widths(official.coarse) == [1024, 1024, 3 * 256]
    assert _weights_outside_coarse(narrow) == _weights_outside_coarse(official)
    assert narrow(torch.randn(2, 50, 3))[1].shape == (2, 4096, 3)


def _forward_by_concatenation(net: PCNNetwork, points: torch.Tensor):
    """The official code's forward: the per-shape vectors concatenated onto every point."""
    b = points.shape[0]
    local = net.encoder_0(points)
    pooled = local.max(dim=1, keepdim=True).values.expand_as(local)
    feature = net.encoder_1(torch.cat([local, pooled], dim=-1)).max(dim=1).values
    coarse = net.coarse(feature).view(b, net.num_coarse, 3)
    centre = coarse.repeat_interleave(len(net.grid), dim=1)
    grid = net.grid.repeat(net.num_coarse, 1)[None].expand(b, -1, -1)
    glob = feature[:, None, :].expand(-1, centre.shape[1], -1)
    return coarse, net.folding(torch.cat([grid, centre, glob], dim=-1)) + centre


def test_the_split_concatenations_compute_the_official_forward_and_gradient():
    # In float64: the two forms sum in different orders, and in float32 one gradient element
    # in 30,000 differed by 1.3e-5 on one CPU (5e-4 relative) while agreeing on another. The
    # claim is algebraic equality, which float64 checks with a tolerance that cannot hide a bug.
    torch.manual_seed(0)
    net = PCNNetwork(feature=64, num_coarse=32, grid_size=4, decoder_width=96).double()
    points = torch.randn(3, 70, 3, dtype=torch.float64)
    results = []
    for forward in (net.forward, lambda x: _forward_by_concatenation(net, x)):
        net.zero_grad()
        coarse, fine = forward(points)
        (coarse.square().sum() + fine.sin().sum()).backward()
        results.append((coarse, fine, [p.grad.clone() for p in net.parameters()]))
    (c1, f1, g1), (c2, f2, g2) = results
    torch.testing.assert_close(c1, c2)
    torch.testing.assert_close(f1, f2)
    for a, b in zip(g1, g2, strict=True):
        torch.testing.assert_close(a, b, rtol=1e-9, atol=1e-11)


def test_emd_and_chamfer_on_known_cases():
    torch.manual_seed(0)
    a = torch.rand(1, 200, 3)
    perm = a[:, torch.randperm(200)]
    assert sinkhorn_emd(a, perm).item() < 0.01  # a permutation is a perfect match
    shift = torch.tensor([0.3, 0.0, 0.0])
    assert abs(sinkhorn_emd(a, a + shift).item() - 0.3) < 0.02
    assert abs(chamfer_l1_halved(a, a + 0.001).item() - 0.001 * 3**0.5) < 1e-3
    assert [alpha(s) for s in (0, 10_000, 20_000, 50_000)] == [0.01, 0.1, 0.5, 1.0]


def _chamfer_through_cdist(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """The loss as it was written before the nearest pairs were searched apart: the whole
    (B, N, M) matrix, differentiated through ``min``."""
    d = torch.cdist(a, b, compute_mode="donot_use_mm_for_euclid_dist")
    return 0.5 * (d.min(dim=2).values.mean(dim=1) + d.min(dim=1).values.mean(dim=1))


@pytest.mark.parametrize("shapes", [((2, 300, 3), (2, 500, 3)), ((3, 1000, 3), (3, 64, 3))])
def test_chamfer_by_nearest_pairs_has_the_loss_and_gradient_of_the_whole_matrix(shapes):
    g = torch.Generator().manual_seed(1)
    a0, b0 = torch.randn(shapes[0], generator=g), 0.5 * torch.randn(shapes[1], generator=g)
    grads = []
    for loss in (chamfer_l1_halved, _chamfer_through_cdist):
        a, b = a0.clone().requires_grad_(), b0.clone().requires_grad_()
        value = loss(a, b)
        value.sum().backward()
        grads.append((value.detach(), a.grad, b.grad))
    (v1, ga1, gb1), (v2, ga2, gb2) = grads
    assert v1.shape == (shapes[0][0],)
    torch.testing.assert_close(v1, v2, rtol=1e-5, atol=1e-7)
    torch.testing.assert_close(ga1, ga2, rtol=1e-4, atol=1e-7)
    torch.testing.assert_close(gb1, gb2, rtol=1e-4, atol=1e-7)


def test_chamfer_of_coincident_points_has_zero_gradient_and_nan_stays_nan():
    a = torch.rand(1, 50, 3, requires_grad=True)
    chamfer_l1_halved(a, a.detach().clone()).sum().backward()
    assert torch.equal(a.grad, torch.zeros_like(a))  # not NaN: the norm's subgradient at 0
    broken = torch.rand(1, 50, 3)
    broken[0, 7] = float("nan")  # a diverged network: the loss says so instead of raising
    assert torch.isnan(chamfer_l1_halved(broken, torch.rand(1, 40, 3))).all()


def _sphere(n: int, seed: int) -> torch.Tensor:
    v = torch.randn(n, 3, generator=torch.Generator().manual_seed(seed))
    return 0.7 * v / v.norm(dim=1, keepdim=True)


@pytest.mark.slow  # trains PCN: about a minute
def test_training_lowers_the_loss_and_completion_beats_the_raw_context():
    torch.manual_seed(1)
    options = PCN.Options(
        feature=64,
        num_coarse=64,
        grid_size=2,
        grid_scale=0.05,
        lr=1e-3,
        lr_decay=0.7,
        lr_decay_steps=1000,
        alpha_steps=(0, 0, 0),
        context_sizes=(50,),
    )
    module = PCNModule(options)
    target = _sphere(512, 2)[None]
    context = _sphere(50, 3)[None]
    opt = torch.optim.Adam(module.parameters(), lr=3e-3)
    first = None
    for _ in range(150):
        terms = module.losses(context, target)
        loss = terms["coarse"] + terms["fine"]
        first = loss.item() if first is None else first
        opt.zero_grad()
        loss.backward()
        opt.step()
    assert float(loss) < 0.5 * first
    with torch.no_grad():
        _, fine = module.network(context)
    gt = ObjectData(ObjectRef("s", "c"), np.zeros((1, 3)), np.zeros((1, 3)), target[0].numpy())
    metric = ChamferL2()
    completed = metric.compute(Completion(fine[0].numpy()), gt, None)
    raw = metric.compute(Completion(context[0].numpy()), gt, None)
    assert completed < raw


def test_sinkhorn_kernel_iterations_equal_the_log_domain_ones_and_far_sets_fall_back():
    from shapebench_pcn.losses import _sinkhorn_plan, _sinkhorn_plan_log

    gen = torch.Generator().manual_seed(0)
    a = torch.rand(3, 64, 3, generator=gen) - 0.5
    b = torch.rand(3, 64, 3, generator=gen) - 0.5
    cost = torch.cdist(a, b)
    fast, log = _sinkhorn_plan(cost, 0.01, 100), _sinkhorn_plan_log(cost, 0.01, 100)
    assert fast.dtype == torch.float32
    assert torch.allclose(fast, log, rtol=1e-4, atol=1e-9)
    assert torch.allclose(fast.sum(dim=(1, 2)), torch.ones(3))  # a transport plan
    # Sets 20 apart: exp(-cost / eps) underflows even in float64; the log domain takes over.
    far = torch.cdist(a, b + 20.0)
    plan = _sinkhorn_plan(far, 0.01, 100)
    assert torch.isfinite(plan).all()
    assert torch.allclose(plan.sum(dim=(1, 2)), torch.ones(3), atol=1e-4)
