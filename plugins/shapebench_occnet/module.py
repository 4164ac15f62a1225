"""OccNet's LightningModule: noisy input points, occupancy queries, BCE on logits."""

from __future__ import annotations

import torch
from torch.nn import functional as F

from shapebench.train.batchnorm import is_final_step, recalibrate_batchnorm
from shapebench.train.lightning_fit import step_generator
from shapebench.train.lightning_module import OptionsModule
from shapebench_occnet.method import OccNetOptions
from shapebench_occnet.network import DecoderBatchNorm, DecoderCBatchNorm, ResnetPointnet


class OccNetModule(OptionsModule):
    Options = OccNetOptions
    options: OccNetOptions

    def __init__(self, options: OccNetOptions | None = None, n_shapes: int = 0, **saved) -> None:
        super().__init__(options, n_shapes, **saved)
        o = self.options
        self.encoder = ResnetPointnet(o.c_dim, o.hidden_dim)
        if o.decoder == "batchnorm":
            self.decoder = DecoderBatchNorm(o.c_dim, o.decoder_hidden)
        elif o.decoder == "cbatchnorm":
            self.decoder = DecoderCBatchNorm(o.c_dim, o.decoder_hidden)
        else:
            raise ValueError(f"decoder must be 'batchnorm' or 'cbatchnorm', got {o.decoder!r}")

    def loss(self, points: torch.Tensor, occupancy: torch.Tensor) -> torch.Tensor:
        """BCE on logits, summed over each object's query points, averaged over objects."""
        logits = self.decoder(occupancy[..., :3], self.encoder(points))
        bce = F.binary_cross_entropy_with_logits(logits, occupancy[..., 3], reduction="none")
        return bce.sum(dim=1).mean()

    def encoder_input(
        self, batch: dict[str, torch.Tensor], generator: torch.Generator | None = None
    ) -> torch.Tensor:
        """A training batch's encoder input: its first ``input_points`` points, or as many as
        one of ``context_sizes`` drawn from ``generator``, noised."""
        o = self.options
        k = o.input_points
        if o.context_sizes:
            gen = generator if generator is not None else step_generator(self)
            k = o.context_sizes[int(torch.randint(len(o.context_sizes), (1,), generator=gen))]
        points = batch["points"][:, :k]
        return points + o.input_noise * torch.randn_like(points)  # as the paper and official

    def training_step(self, batch: dict[str, torch.Tensor], batch_idx: int) -> torch.Tensor:
        points = self.encoder_input(batch)
        loss = self.loss(points, batch["occupancy"])
        self.log(
            "train/loss", loss, on_step=False, on_epoch=True, batch_size=len(points), sync_dist=True
        )
        return loss

    def on_train_batch_end(self, outputs, batch, batch_idx: int) -> None:
        # The decoder's BatchNorm statistics, recomputed for the final weights before the last
        # checkpoint is written (shapebench.train.batchnorm says why).
        if self.options.precise_bn_batches and is_final_step(self.trainer):
            recalibrate_batchnorm(
                self,
                lambda b, gen: self.loss(self.encoder_input(b, gen), b["occupancy"]),
                self.trainer.train_dataloader,
                self.options.precise_bn_batches,
            )

    def configure_optimizers(self):
        return torch.optim.Adam(self.parameters(), lr=self.options.lr)  # no schedule (official)
