"""ConvONet's LightningModule: noisy input points, occupancy queries, BCE on logits."""

from __future__ import annotations

import torch

from shapebench.implicit.occupancy_module import OccupancyModule
from shapebench_convonet.method import ConvONetOptions
from shapebench_convonet.network import LocalDecoder, LocalPoolPointnet


class ConvONetModule(OccupancyModule):
    Options = ConvONetOptions
    options: ConvONetOptions

    def __init__(self, options: ConvONetOptions | None = None, n_shapes: int = 0, **saved) -> None:
        super().__init__(options, n_shapes, **saved)
        o = self.options
        self.encoder = LocalPoolPointnet(
            o.c_dim, o.hidden, o.plane_resolution, o.unet_depth, o.unet_start
        )
        self.decoder = LocalDecoder(o.c_dim, o.hidden)

    def input_size(self, generator: torch.Generator | None = None) -> int:
        """One of ``input_points``, drawn per batch."""
        return self.draw_size(self.options.input_points, generator)
