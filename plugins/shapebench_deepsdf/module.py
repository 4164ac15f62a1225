"""DeepSDF's LightningModule: decoder, code embedding, clamped L1 and code regularisation."""

from __future__ import annotations

import math
from collections.abc import Callable

import torch
from torch import nn

from shapebench.implicit.losses import clamped_l1
from shapebench.implicit.networks import DeepSDFDecoder
from shapebench.train.lightning_fit import adam_halving
from shapebench.train.lightning_module import OptionsModule
from shapebench_deepsdf.method import DeepSDFOptions


class DeepSDFModule(OptionsModule):
    Options = DeepSDFOptions
    options: DeepSDFOptions

    def __init__(self, options: DeepSDFOptions | None = None, n_shapes: int = 0, **saved) -> None:
        super().__init__(options, n_shapes, **saved)
        o = self.options
        self.decoder = DeepSDFDecoder(o.latent_dim, o.width, o.depth, o.dropout)
        self.latents = nn.Embedding(n_shapes, o.latent_dim, max_norm=1.0)
        nn.init.normal_(self.latents.weight, 0.0, 1.0 / math.sqrt(o.latent_dim))

    def training_step(self, batch: dict[str, torch.Tensor], batch_idx: int) -> torch.Tensor:
        o = self.options
        z = self.latents(batch["index"])
        sdf = batch["sdf"]
        data = clamped_l1(self.decoder(z, sdf[..., :3]), sdf[..., 3], o.clamp).mean()
        ramp = min(1.0, self.current_epoch / 100)  # the official regulariser ramps up over 100
        reg = o.code_reg * ramp * z.norm(dim=-1).mean()
        loss = data + reg
        self.log_dict(
            {"train/loss": loss, "train/sdf_l1": data},
            on_step=False,
            on_epoch=True,
            batch_size=len(z),
            sync_dist=True,
        )
        return loss

    def configure_optimizers(self):
        o = self.options
        groups = [
            {"params": self.decoder.parameters(), "lr": o.lr},
            {"params": self.latents.parameters(), "lr": o.latent_lr},
        ]
        return adam_halving(groups, o.lr, o.lr_halve_every, o.lr_halve_steps)

    def completion_loss(self, points: torch.Tensor) -> Callable[[torch.Tensor], torch.Tensor]:
        """Only the context points, with SDF 0, and 1e-4 * mean(z^2) (``reconstruct.py``'s
        regulariser)."""
        o = self.options
        target = torch.zeros(points.shape[:2], device=points.device)

        def loss(z: torch.Tensor) -> torch.Tensor:  # the decoder's one-code-per-object forward
            data = clamped_l1(self.decoder.forward_shared(z, points), target, o.clamp)
            return data + o.code_reg * (z**2).mean(dim=1)

        return loss
