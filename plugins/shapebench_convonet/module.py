"""ConvONet's LightningModule: noisy input points, occupancy queries, BCE on logits."""

from __future__ import annotations

import torch
from torch.nn import functional as F

from shapebench.train.lightning_fit import step_generator
from shapebench.train.lightning_module import OptionsModule
from shapebench_convonet.method import ConvONetOptions
from shapebench_convonet.network import LocalDecoder, LocalPoolPointnet


class ConvONetModule(OptionsModule):
    Options = ConvONetOptions
    options: ConvONetOptions

    def __init__(self, options: ConvONetOptions | None = None, n_shapes: int = 0, **saved) -> None:
        super().__init__(options, n_shapes, **saved)
        o = self.options
        self.encoder = LocalPoolPointnet(
            o.c_dim, o.hidden, o.plane_resolution, o.unet_depth, o.unet_start
        )
        self.decoder = LocalDecoder(o.c_dim, o.hidden)

    def loss(self, points: torch.Tensor, occupancy: torch.Tensor) -> torch.Tensor:
        """BCE on logits, summed over each object's queries, averaged over objects (official)."""
        logits = self.decoder(occupancy[..., :3], self.encoder(points))
        bce = F.binary_cross_entropy_with_logits(logits, occupancy[..., 3], reduction="none")
        return bce.sum(dim=1).mean()

    def training_step(self, batch: dict[str, torch.Tensor], batch_idx: int) -> torch.Tensor:
        o = self.options
        sizes = o.input_points
        k = sizes[int(torch.randint(len(sizes), (1,), generator=step_generator(self)))]
        points = batch["points"][:, :k]
        points = points + o.input_noise * torch.randn_like(points)
        loss = self.loss(points, batch["occupancy"])
        self.log(
            "train/loss", loss, on_step=False, on_epoch=True, batch_size=len(points), sync_dist=True
        )
        return loss

    def configure_optimizers(self):
        return torch.optim.Adam(self.parameters(), lr=self.options.lr)  # no schedule (official)
