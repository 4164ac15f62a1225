"""OccNet's LightningModule: noisy input points, occupancy queries, BCE on logits."""

from __future__ import annotations

import torch

from shapebench.implicit.occupancy_module import OccupancyModule
from shapebench.train.batchnorm import is_final_step, recalibrate_batchnorm
from shapebench_occnet.method import OccNetOptions
from shapebench_occnet.network import DecoderBatchNorm, DecoderCBatchNorm, ResnetPointnet


class OccNetModule(OccupancyModule):
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

    def input_size(self, generator: torch.Generator | None = None) -> int:
        """``input_points``, or one of ``context_sizes`` drawn from ``generator``."""
        o = self.options
        return self.draw_size(o.context_sizes, generator) if o.context_sizes else o.input_points

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
