"""OccNet's LightningModule: noisy input points, occupancy queries, BCE on logits."""

from __future__ import annotations

import pytorch_lightning as pl
import torch
from torch.nn import functional as F

from shapebench_occnet.network import DecoderBatchNorm, DecoderCBatchNorm, ResnetPointnet


class OccNetModule(pl.LightningModule):
    def __init__(self, c_dim: int, hidden_dim: int, decoder: str, decoder_hidden: int,
                 lr: float, input_points: int, input_noise: float) -> None:  # fmt: skip
        super().__init__()
        self.save_hyperparameters()
        self.encoder = ResnetPointnet(c_dim, hidden_dim)
        if decoder == "batchnorm":
            self.decoder = DecoderBatchNorm(c_dim, decoder_hidden)
        elif decoder == "cbatchnorm":
            self.decoder = DecoderCBatchNorm(c_dim, decoder_hidden)
        else:
            raise ValueError(f"decoder must be 'batchnorm' or 'cbatchnorm', got {decoder!r}")

    def loss(self, points: torch.Tensor, occupancy: torch.Tensor) -> torch.Tensor:
        """BCE on logits, summed over each object's query points, averaged over objects."""
        logits = self.decoder(occupancy[..., :3], self.encoder(points))
        bce = F.binary_cross_entropy_with_logits(logits, occupancy[..., 3], reduction="none")
        return bce.sum(dim=1).mean()

    def training_step(self, batch: dict[str, torch.Tensor], batch_idx: int) -> torch.Tensor:
        h = self.hparams
        points = batch["points"][:, : h.input_points]
        points = points + h.input_noise * torch.randn_like(points)  # as the paper and official
        loss = self.loss(points, batch["occupancy"])
        self.log("train/loss", loss, on_step=False, on_epoch=True, batch_size=len(points),
                 sync_dist=True)  # fmt: skip
        return loss

    def configure_optimizers(self):
        return torch.optim.Adam(self.parameters(), lr=self.hparams.lr)  # no schedule (official)
