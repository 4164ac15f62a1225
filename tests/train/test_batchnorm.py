"""Precise BatchNorm statistics (shapebench.train.batchnorm): the running mean and variance
become the plain average over training batches passed through the final weights; nothing else
changes; PoinTr's training recomputes them at its last step, its weights as without it."""

from __future__ import annotations

from copy import deepcopy

import pytest
import torch
from torch import nn

from shapebench.train.batchnorm import recalibrate_batchnorm


def _net() -> nn.Sequential:
    torch.manual_seed(0)
    return nn.Sequential(nn.Linear(3, 4), nn.BatchNorm1d(4), nn.ReLU(), nn.Linear(4, 2))


def _batches(n: int) -> list[dict[str, torch.Tensor]]:
    gen = torch.Generator().manual_seed(1)
    return [{"x": torch.randn(16, 3, generator=gen) * (i + 1) + i} for i in range(n)]


def test_the_statistics_are_the_average_over_the_batches_and_nothing_else_changes() -> None:
    net = _net()
    net[1].running_mean.fill_(5.0)  # stale statistics
    state = net.state_dict().items()
    weights = {k: v.clone() for k, v in state if "running" not in k and "tracked" not in k}
    batches = _batches(3)
    rng = torch.get_rng_state()

    used = recalibrate_batchnorm(net, lambda b, gen: net(b["x"]), batches, limit=3)

    assert used == 3
    features = [net[0](b["x"]).detach() for b in batches]
    mean = torch.stack([f.mean(dim=0) for f in features]).mean(dim=0)
    var = torch.stack([f.var(dim=0, unbiased=True) for f in features]).mean(dim=0)
    torch.testing.assert_close(net[1].running_mean, mean)
    torch.testing.assert_close(net[1].running_var, var)
    assert net[1].momentum == 0.1 and net.training  # as they were
    for k, v in net.state_dict().items():
        if k in weights:
            assert torch.equal(v, weights[k]), k
    assert torch.equal(torch.get_rng_state(), rng)  # the training's draws are left alone


def test_a_short_loader_is_cycled_and_a_network_without_batchnorm_is_left_alone() -> None:
    net = _net()
    seen = []
    assert recalibrate_batchnorm(net, lambda b, gen: seen.append(net(b["x"])), _batches(2), 5) == 5
    assert len(seen) == 5
    plain = nn.Sequential(nn.Linear(3, 2))
    assert recalibrate_batchnorm(plain, lambda b, gen: plain(b["x"]), _batches(2), 5) == 0
    assert recalibrate_batchnorm(net, lambda b, gen: net(b["x"]), _batches(2), 0) == 0


def _train_pointr(precise: int):
    import pytorch_lightning as pl
    from shapebench_pointr.method import PoinTr, PoinTrOptions
    from shapebench_pointr.module import PoinTrModule
    from torch.utils.data import DataLoader

    gen = torch.Generator().manual_seed(2)
    shapes = [torch.randn(120, 3, generator=gen) for _ in range(6)]
    data = [{"points": s[:20], "complete": s} for s in shapes]
    sizes = {"context_sizes": (20,), "precise_bn_batches": precise}
    options = PoinTrOptions(**{**PoinTr.check_options, **sizes})  # its tiny network
    torch.manual_seed(0)
    module = PoinTrModule(options)
    trainer = pl.Trainer(
        max_steps=12,
        accelerator="cpu",
        devices=1,
        logger=False,
        enable_checkpointing=False,
        enable_progress_bar=False,
        enable_model_summary=False,
    )
    loader = DataLoader(data, batch_size=2, shuffle=False)
    trainer.fit(module, train_dataloaders=loader)
    return module, loader


@pytest.mark.slow  # two tiny Lightning trainings of 12 steps
def test_pointr_recomputes_its_statistics_at_its_last_step_with_the_same_weights() -> None:
    plain, _ = _train_pointr(0)
    precise, loader = _train_pointr(3)
    state, reference = precise.state_dict(), plain.state_dict()
    running = [k for k in state if "running_" in k]
    assert running
    for k in state:
        if k not in running and "num_batches_tracked" not in k:
            assert torch.equal(state[k], reference[k]), k  # the weights trained are the same
    assert any(not torch.equal(state[k], reference[k]) for k in running)

    # The statistics are the final network's own over the first 3 training batches, every
    # BatchNorm layer in training mode at once (as precise BN computes them: a layer sees its
    # input normalised by the batch statistics of the layers before it), on a copy, whose own
    # running averages this forward pass moves.
    copy = deepcopy(precise)
    bn = precise.network.folding.fold1[1]
    outputs = []
    hook = copy.network.folding.fold1[0].register_forward_hook(
        lambda m, i, o: outputs.append(o.detach())
    )
    copy.train()
    with torch.no_grad():
        for batch, _ in zip(loader, range(3), strict=False):
            copy.network(batch["points"])
    hook.remove()
    means = torch.stack([o.mean(dim=(0, 2)) for o in outputs]).mean(dim=0)
    torch.testing.assert_close(bn.running_mean, means, rtol=1e-4, atol=1e-6)
