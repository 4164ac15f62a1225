"""The LightningModule base of the occupancy methods
(:class:`~shapebench.implicit.occupancy.OccupancyMethod`): :class:`OccupancyModule`.

Imports Lightning: only a method's ``module.py`` imports it, lazily.
"""

from __future__ import annotations

import torch
from torch.nn import functional as F

from shapebench.train.lightning_fit import step_generator
from shapebench.train.lightning_module import OptionsModule


class OccupancyModule(OptionsModule):
    """An :class:`~shapebench.train.lightning_module.OptionsModule` with an ``encoder`` from
    (B, k, 3) points to codes and a ``decoder`` from (B, T, 3) queries and codes to (B, T)
    occupancy logits, which a subclass builds from :attr:`options`.

    Each training step gives the encoder the batch's first :meth:`input_size` surface points,
    with Gaussian noise of std ``input_noise``, and minimises the binary cross-entropy of the
    query logits (:meth:`loss`); Adam at ``lr``, no schedule (the official OccNet and ConvONet).
    """

    def input_size(self, generator: torch.Generator | None = None) -> int:
        """How many surface points the encoder reads in one training batch (a size drawn per
        batch comes from :meth:`draw_size`)."""
        raise NotImplementedError(f"{type(self).__name__} defines no input_size()")

    def draw_size(self, sizes: tuple[int, ...], generator: torch.Generator | None = None) -> int:
        """One of ``sizes``, drawn with ``generator`` (default: the training step's seeded
        :func:`~shapebench.train.lightning_fit.step_generator`)."""
        gen = generator if generator is not None else step_generator(self)
        return sizes[int(torch.randint(len(sizes), (1,), generator=gen))]

    def encoder_input(
        self, batch: dict[str, torch.Tensor], generator: torch.Generator | None = None
    ) -> torch.Tensor:
        """A training batch's encoder input: its first :meth:`input_size` points, noised."""
        points = batch["points"][:, : self.input_size(generator)]
        return points + self.options.input_noise * torch.randn_like(points)  # as the papers

    def loss(self, points: torch.Tensor, occupancy: torch.Tensor) -> torch.Tensor:
        """BCE on logits, summed over each object's queries, averaged over objects (official)."""
        logits = self.decoder(occupancy[..., :3], self.encoder(points))
        bce = F.binary_cross_entropy_with_logits(logits, occupancy[..., 3], reduction="none")
        return bce.sum(dim=1).mean()

    def training_step(self, batch: dict[str, torch.Tensor], batch_idx: int) -> torch.Tensor:
        points = self.encoder_input(batch)
        loss = self.loss(points, batch["occupancy"])
        self.log(
            "train/loss", loss, on_step=False, on_epoch=True, batch_size=len(points), sync_dist=True
        )
        return loss

    def configure_optimizers(self):
        return torch.optim.Adam(self.parameters(), lr=self.options.lr)
