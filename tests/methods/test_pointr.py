"""PoinTr (issue 30): farthest-point sampling by hand, the grouper's proxies (capped by the
context), the output layout (folded points around the predicted centres, then the input itself),
the optimiser's groups and schedule, and a few steps that lower the loss."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from conftest import load_benchmark
from shapebench_pointr.method import PoinTrOptions
from shapebench_pointr.module import PoinTrModule
from shapebench_pointr.network import (
    Block,
    DGCNNGrouper,
    Folding,
    PoinTrNetwork,
    farthest_point_sample,
    gather_points,
    knn,
)

TINY = dict(dim=16, heads=2, depth=(1, 1), num_query=4, fold_step=2, global_dim=32, proxies=8)


def test_farthest_point_sample_by_hand() -> None:
    # A unit square's corners and its centre, from index 0 (the official kernel's start): the
    # opposite corner, then the nearer of the two others by index, then the last corner.
    pts = torch.tensor([[[0.0, 0, 0], [0.5, 0.5, 0], [1.0, 0, 0], [0.0, 1, 0], [1.0, 1, 0]]])
    assert farthest_point_sample(pts, 4)[0].tolist() == [0, 4, 2, 3]


def test_gather_and_knn_by_hand() -> None:
    values = torch.arange(12.0).view(1, 4, 3)
    assert gather_points(values, torch.tensor([[2, 0]]))[0].tolist() == [[6, 7, 8], [0, 1, 2]]
    line = torch.tensor([[[0.0, 0, 0], [1.0, 0, 0], [3.0, 0, 0]]])
    assert knn(line[:, :1], line, 2)[0, 0].tolist() == [0, 1]


def test_proxies_are_capped_by_the_context() -> None:
    grouper = DGCNNGrouper(first=16, proxies=8)
    centres, features = grouper(torch.randn(2, 50, 3))
    assert centres.shape == (2, 8, 3) and features.shape == (2, 8, 128)
    centres, _ = grouper(torch.randn(2, 5, 3))  # five points: five proxies
    assert centres.shape == (2, 5, 3)


def test_the_output_is_folded_points_then_the_input() -> None:
    torch.manual_seed(0)
    net = PoinTrNetwork(**TINY).eval()
    context = torch.randn(3, 20, 3)
    coarse, fine = net(context)
    assert coarse.shape == (3, 4 + 4, 3)  # centres and an FPS of the input
    assert fine.shape == (3, 4 * 2 * 2 + 20, 3)
    assert torch.equal(fine[:, -20:], context)  # the observed points are kept exactly
    grid = Folding(8, 3).grid
    assert grid.shape == (2, 9) and grid.min() == -1 and grid.max() == 1


def test_each_patch_is_its_centre_plus_the_folded_offsets() -> None:
    # The layout benchmarks/pointr_patch_spread.py reads: the first M x S dense points are M
    # patches, patch j = centre j (the coarse cloud's first M points) + the folding head's S
    # offsets for proxy j, with no scale between them (official: relative_xyz + coarse).
    torch.manual_seed(0)
    net = PoinTrNetwork(**TINY).eval()
    captured = []
    net.folding.register_forward_hook(lambda mod, inp, out: captured.append(out))
    coarse, fine = net(torch.randn(2, 20, 3))
    m, s = net.num_query, net.folding.grid.shape[1]
    offsets = captured[0].view(2, m, s, 3)
    patches = fine[:, : m * s].view(2, m, s, 3)
    assert torch.equal(patches, coarse[:, :m, None, :] + offsets)


def test_patch_statistics_by_hand() -> None:
    stats = load_benchmark("pointr_patch_spread").patch_statistics
    # Two flat 2 x 2 squares of side 0.2 (RMS from their centroid sqrt(2) x 0.1), their centres
    # 1 apart; the second patch sits 0.5 away from its centre.
    square = np.array([[-0.1, -0.1, 0], [0.1, -0.1, 0], [-0.1, 0.1, 0], [0.1, 0.1, 0]])
    centres = np.array([[0.0, 0, 0], [1.0, 0, 0]])
    patches = np.stack([square, square + [1.0, 0.5, 0]])
    rows = stats(centres, patches, radius=2.0)
    rms = 0.1 * 2**0.5
    np.testing.assert_allclose(rows[:, 0], rms)
    np.testing.assert_allclose(rows[:, 1], 0, atol=1e-12)  # flat: no spread along z
    np.testing.assert_allclose(rows[:, 2], 1)  # a square, not a line
    np.testing.assert_allclose(rows[:, 3], rms)  # over the 1.0 gap between the centres
    np.testing.assert_allclose(rows[:, 4], rms / 2)
    np.testing.assert_allclose(rows[:, 5], [0, 0.5])
    line = np.array([[x, 0, 0] for x in (-0.1, 0, 0.1)])
    assert stats(centres, np.stack([line, line + [1.0, 0, 0]]), 1.0)[0, 2] == 0
    blob = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)]) * 0.1
    assert stats(centres, np.stack([blob, blob + [1.0, 0, 0]]), 1.0)[0, 1] == pytest.approx(1)


def test_the_transformer_is_laid_out_and_initialised_as_the_official() -> None:
    torch.manual_seed(0)
    net = PoinTrNetwork(**{**TINY, "dim": 64, "depth": (2, 2)})
    attention = [m for m in net.modules() if m.__class__.__name__ == "Attention"]
    assert len(attention) == 2 + 2 * 2  # encoder self; decoder self and cross
    assert all(
        a.q.bias is None and a.kv.bias is None and a.proj.bias is not None for a in attention
    )
    # The geometry branches: the first block of each, and the first decoder block's cross too.
    assert [b.geometry is not None for b in net.encoder] == [True, False]
    assert [b.cross_geometry is not None for b in net.decoder] == [True, False]
    # Truncated-normal (std 0.02) Linear weights in the transformer, Xavier in its 1x1 convs,
    # PyTorch's default (uniform, bound 1/sqrt(fan_in)) in the rebuild layers.
    mlp = net.encoder[0].mlp[0].weight
    assert abs(mlp.std().item() - 0.02) < 0.002 and net.encoder[0].mlp[0].bias.abs().sum() == 0
    conv = net.query_mlp[0].weight  # Xavier normal: std sqrt(2 / (fan_in + fan_out))
    expected = (2 / sum(conv.shape)) ** 0.5
    assert abs(conv.std().item() - expected) < 0.1 * expected
    reduce = net.reduce_map.weight
    assert reduce.abs().max() <= reduce.shape[1] ** -0.5 and reduce.std() > 0.03
    # init="torch" (the ablation) leaves every layer at PyTorch's default: the same MLP layer
    # is uniform with bound 1/sqrt(fan_in), and its bias is not zero.
    torch.manual_seed(0)
    plain = PoinTrNetwork(**{**TINY, "dim": 64, "depth": (2, 2)}, init="torch")
    mlp = plain.encoder[0].mlp[0]
    assert mlp.weight.abs().max() <= mlp.weight.shape[1] ** -0.5 and mlp.bias.abs().sum() > 0
    assert mlp.weight.std().item() > 0.05


def test_an_unknown_init_is_one_clear_error() -> None:
    from shapebench_pointr.method import PoinTr

    from shapebench.api.errors import ConfigError

    with pytest.raises(ConfigError, match="init must be one of"):
        PoinTr(PoinTrOptions(init="xavier"))


def test_the_fine_loss_scores_the_whole_output_or_the_folded_points_alone() -> None:
    from shapebench.train.losses import chamfer_l1_halved

    torch.manual_seed(0)
    context, target = torch.randn(2, 10, 3), torch.randn(2, 64, 3)
    official = PoinTrModule(PoinTrOptions(**TINY_OPTIONS)).eval()
    folded = PoinTrModule(PoinTrOptions(**TINY_OPTIONS, fine_loss="folded")).eval()
    folded.load_state_dict(official.state_dict())
    _, fine = official.network(context)
    # Official: the folded points and the input copied into the output, against the target.
    expected = chamfer_l1_halved(fine, target).mean()
    assert torch.equal(official.losses(context, target)["fine"], expected)
    # The ablation leaves the input's copy out: only the 4 x 2 x 2 folded points are scored.
    expected = chamfer_l1_halved(fine[:, :16], target).mean()
    assert torch.equal(folded.losses(context, target)["fine"], expected)


def test_an_unknown_fine_loss_is_one_clear_error() -> None:
    from shapebench_pointr.method import PoinTr

    from shapebench.api.errors import ConfigError

    with pytest.raises(ConfigError, match="fine_loss must be one of"):
        PoinTr(PoinTrOptions(fine_loss="dense"))


def test_the_first_decoder_block_reads_the_encoder_centres_nearest_each_query() -> None:
    torch.manual_seed(0)
    block = Block(16, 2, 2.0, cross=True, geometric=True).eval()
    q, q_xyz = torch.randn(1, 4, 16), torch.randn(1, 4, 3)
    memory, memory_xyz = torch.randn(1, 12, 16), torch.randn(1, 12, 3)
    out = block(q, q_xyz, memory, memory_xyz)
    # Attention ignores where the memory tokens sit; the cross geometry branch does not.
    moved = block(q, q_xyz, memory, memory_xyz.flip(1))
    assert not torch.allclose(out, moved)
    plain = Block(16, 2, 2.0, cross=True, geometric=False).eval()
    assert torch.allclose(
        plain(q, q_xyz, memory, memory_xyz), plain(q, q_xyz, memory, memory_xyz.flip(1))
    )


def test_optimiser_groups_and_schedule() -> None:
    module = PoinTrModule(PoinTrOptions(**{**TINY_OPTIONS, "lr_decay_steps": 10}))
    setup = module.configure_optimizers()
    decay, plain = setup["optimizer"].param_groups
    assert decay["weight_decay"] == 5e-4 and plain["weight_decay"] == 0
    assert all(p.ndim > 1 for p in decay["params"]) and all(p.ndim <= 1 for p in plain["params"])
    schedule = setup["lr_scheduler"]["scheduler"].lr_lambdas[0]
    assert schedule(0) == 1.0 and abs(schedule(10) - 0.9) < 1e-12 and schedule(10**6) == 0.02


TINY_OPTIONS = dict(
    dim=16,
    heads=2,
    encoder_depth=1,
    decoder_depth=1,
    num_query=4,
    fold_step=2,
    global_dim=32,
    proxies=8,
)


@pytest.mark.slow  # 60 optimiser steps
def test_a_few_steps_lower_the_loss_on_one_shape() -> None:
    torch.manual_seed(0)
    module = PoinTrModule(PoinTrOptions(**TINY_OPTIONS))
    opt = torch.optim.Adam(module.parameters(), lr=3e-3)
    target = torch.randn(1, 200, 3)
    target = target / target.norm(dim=-1, keepdim=True)  # a sphere
    context = target[:, :30]
    first = None
    for _ in range(60):
        terms = module.losses(context, target)
        loss = terms["coarse"] + terms["fine"]
        first = loss.item() if first is None else first
        opt.zero_grad()
        loss.backward()
        opt.step()
    assert loss.item() < 0.6 * first
