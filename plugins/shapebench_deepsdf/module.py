"""DeepSDF's LightningModule: decoder, code embedding, clamped L1 and code regularisation."""

from __future__ import annotations

import math
from collections.abc import Callable

import pytorch_lightning as pl
import torch
from torch import nn

from shapebench.implicit.losses import clamped_l1
from shapebench.implicit.networks import DeepSDFDecoder
from shapebench.lightning_fit import adam_halving


class DeepSDFModule(pl.LightningModule):
    def __init__(
        self,
        n_shapes: int,
        latent_dim: int,
        width: int,
        depth: int,
        dropout: float,
        lr: float,
        latent_lr: float,
        lr_halve_every: int,
        clamp: float,
        code_reg: float,
    ) -> None:
        super().__init__()
        self.save_hyperparameters()
        self.decoder = DeepSDFDecoder(latent_dim, width, depth, dropout)
        self.latents = nn.Embedding(n_shapes, latent_dim, max_norm=1.0)
        nn.init.normal_(self.latents.weight, 0.0, 1.0 / math.sqrt(latent_dim))

    def training_step(self, batch: dict[str, torch.Tensor], batch_idx: int) -> torch.Tensor:
        h = self.hparams
        z = self.latents(batch["index"])
        sdf = batch["sdf"]
        data = clamped_l1(self.decoder(z, sdf[..., :3]), sdf[..., 3], h.clamp).mean()
        ramp = min(1.0, self.current_epoch / 100)  # the official regulariser ramps up over 100
        reg = h.code_reg * ramp * z.norm(dim=-1).mean()
        loss = data + reg
        self.log_dict({"train/loss": loss, "train/sdf_l1": data}, on_step=False, on_epoch=True,
                      batch_size=len(z), sync_dist=True)  # fmt: skip
        return loss

    def configure_optimizers(self):
        h = self.hparams
        groups = [
            {"params": self.decoder.parameters(), "lr": h.lr},
            {"params": self.latents.parameters(), "lr": h.latent_lr},
        ]
        return adam_halving(groups, h.lr, h.lr_halve_every)

    def completion_loss(self, points: torch.Tensor) -> Callable[[torch.Tensor], torch.Tensor]:
        """Only the context points, with SDF 0, and 1e-4 * mean(z^2) (``reconstruct.py``'s
        regulariser)."""
        h = self.hparams
        target = torch.zeros(points.shape[:2], device=points.device)

        def loss(z: torch.Tensor) -> torch.Tensor:
            data = clamped_l1(self.decoder(z, points), target, h.clamp)
            return data + h.code_reg * (z**2).mean(dim=1)

        return loss
