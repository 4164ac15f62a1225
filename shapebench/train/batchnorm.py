"""BatchNorm statistics that match the trained weights ("precise BN").

A network with BatchNorm layers normalises with each batch's own statistics while it trains and
with running averages (an exponential average, momentum 0.1) once it is evaluated. Those averages
trail the weights: over a long training at a small learning rate (the official recipes: OccNet
hundreds of thousands of steps at 1e-4, PoinTr 300 epochs with a BN-momentum schedule) the lag
is small; over a CPU budget of a few thousand steps at 1e-3 it is not. Measured on the shipped
`quick` references (22 validation objects, chamfer-l2 x1000 at 50 / 1000 points), the same
weights with their statistics recomputed: PoinTr 19.27 / 6.18 -> 8.85 / 3.63, OccNet
69.76 / 60.94 -> 42.93 / 36.76 (docs/methods.md, "BatchNorm statistics").

:func:`recalibrate_batchnorm` recomputes them once training ends, as Wu and Johnson recommend
("Rethinking 'Batch' in BatchNorm", 2021, PreciseBN): every BatchNorm layer's running mean and
variance become the plain average over ``limit`` training batches, passed through the final
weights without gradients. The weights do not change; only the evaluation does.

A module of ``train/`` is keyed on its own file (:mod:`shapebench.train.losses`): the methods
that call this name it in their ``code_modules``.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Mapping
from typing import Any

import torch
from torch import nn


def batchnorm_layers(module: nn.Module) -> list[nn.modules.batchnorm._BatchNorm]:
    """The BatchNorm layers of ``module`` that keep running statistics."""
    return [
        m
        for m in module.modules()
        if isinstance(m, nn.modules.batchnorm._BatchNorm) and m.track_running_stats
    ]


def is_final_step(trainer: Any) -> bool:
    """Whether the optimiser step just taken (in ``on_train_batch_end``) is the training's last:
    its step budget reached, or the last batch of its last epoch."""
    if trainer.max_steps not in (None, -1) and trainer.global_step >= trainer.max_steps:
        return True
    epochs = trainer.max_epochs
    last_epoch = epochs not in (None, -1) and trainer.current_epoch + 1 >= epochs
    return bool(last_epoch and trainer.is_last_batch)


@torch.no_grad()
def recalibrate_batchnorm(
    module: nn.Module,
    forward: Callable[[Mapping[str, torch.Tensor], torch.Generator], Any],
    batches: Iterable[Mapping[str, torch.Tensor]],
    limit: int,
    seed: int = 0,
) -> int:
    """Replace the running statistics of ``module``'s BatchNorm layers by their average over
    the first ``limit`` of ``batches`` (a training loader, cycled if shorter), each passed
    through ``forward(batch, generator)`` as a training step would pass it (the same input
    sizes, noise and subsets, drawn from ``generator`` and torch's generator, both seeded from
    ``seed`` and restored afterwards). Returns the number of batches used (0: no BatchNorm
    layer, or ``limit`` is 0). The other layers stay as they were; the modes are restored."""
    layers = batchnorm_layers(module)
    if not layers or limit <= 0:
        return 0
    modes = [(m, m.training) for m in module.modules()]
    momenta = [layer.momentum for layer in layers]
    device = next(module.parameters()).device
    module.eval()
    for layer in layers:
        layer.reset_running_stats()
        layer.momentum = None  # cumulative average: every batch weighs the same
        layer.train()
    used = 0
    try:
        with torch.random.fork_rng(devices=[] if device.type == "cpu" else [device]):
            torch.manual_seed(seed)
            generator = torch.Generator().manual_seed(seed)
            while used < limit:
                before = used
                for batch in batches:
                    forward({k: v.to(device) for k, v in batch.items()}, generator)
                    used += 1
                    if used >= limit:
                        break
                if used == before:
                    raise ValueError("recalibrate_batchnorm: the training loader gave no batch")
    finally:
        for layer, momentum in zip(layers, momenta, strict=True):
            layer.momentum = momentum
        for m, training in modes:
            m.train(training)
    return used
