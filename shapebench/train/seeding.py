"""Every random draw of a Lightning training, seeded from the trainer seed.

:func:`seed_training` seeds the global generators before the module is built (its initial
weights); :func:`derived_seed` gives each later stream of draws a seed of its own;
:func:`step_generator` is the generator a training step draws its subsets and sizes from; and
:class:`EpochSeeds` reseeds the per-step draws before every optimiser step and the data draws
(:mod:`shapebench.train.data`) before every epoch. What an epoch computes then depends only on the
weights and optimiser state it starts from.

This module changes what a training computes: it is part of the keys of every Lightning-trained
method (``LightningMethod.code_modules``).
"""

from __future__ import annotations

from typing import Any

import pytorch_lightning as pl
import torch

from shapebench.hashing import stable_seed


def seed_training(seed: int) -> None:
    """Seed Python's, numpy's and torch's global generators (DataLoader workers included): call
    it before building the module, whose initial weights come from them."""
    pl.seed_everything(seed, workers=True, verbose=False)


def derived_seed(seed: int, *parts: object) -> int:
    """A seed for one stream of draws of a training seeded with ``seed`` (63 bits)."""
    return stable_seed("training", seed, *parts)


def global_rank() -> int:
    """This process's rank once DDP is initialised, 0 otherwise."""
    dist = torch.distributed
    return dist.get_rank() if dist.is_available() and dist.is_initialized() else 0


def step_generator(module: pl.LightningModule) -> torch.Generator:
    """The CPU generator a training step draws its subsets and sizes from.

    :func:`~shapebench.train.lightning_fit.fit_lightning` seeds it from the trainer seed, the
    rank and the step (see :class:`EpochSeeds`); a module stepped outside ``fit`` (tests) gets one
    seeded from torch's global seed. Plugins import it from
    :mod:`shapebench.train.lightning_fit`.
    """
    gen = getattr(module, "_step_generator", None)
    if gen is None:
        gen = torch.Generator().manual_seed(derived_seed(torch.initial_seed(), "steps"))
        module._step_generator = gen
    return gen


class EpochSeeds(pl.Callback):
    """Reseeds every stream of random draws from (seed, rank, epoch or step).

    The per-step generator (:func:`step_generator`) and torch's global generator (noise a
    training step draws on the device) are seeded before every optimiser step from (seed, rank,
    global step); the data draws (:class:`~shapebench.train.data.ShapeSamples`) and the shuffle
    order before every epoch from (seed, rank, epoch). What an epoch computes then depends only
    on the weights and optimiser state it starts from, which the checkpoints hold: a training
    resumed from an epoch-end checkpoint gives bitwise the weights of an uninterrupted one.
    """

    def __init__(self, seed: int) -> None:
        self.seed = seed

    def on_train_epoch_start(self, trainer: pl.Trainer, pl_module: pl.LightningModule) -> None:
        from shapebench.train.data import ShapeDataModule  # data imports this module

        data = trainer.datamodule
        if isinstance(data, ShapeDataModule):
            data.start_epoch(trainer.current_epoch)

    def on_train_batch_start(
        self, trainer: pl.Trainer, pl_module: pl.LightningModule, batch: Any, batch_idx: int
    ) -> None:
        seed = derived_seed(self.seed, "steps", trainer.global_rank, trainer.global_step)
        pl_module._step_generator = torch.Generator().manual_seed(seed)
        torch.manual_seed(
            derived_seed(self.seed, "global", trainer.global_rank, trainer.global_step)
        )
