"""PCN's network, as the official TensorFlow code (``models/pcn_emd.py``): no batch norm, ReLU,
Xavier-uniform weights and zero biases.

Encoder: per-point 3 -> 128 -> 256, max-pooled global feature concatenated back to every point,
512 -> 512 -> ``feature``, max-pooled again. Decoder: fully connected ``feature`` ->
``decoder_width`` -> ``decoder_width`` -> 3 * ``num_coarse`` (the coarse cloud; the official
width is 1024), then folding: every coarse point is repeated once per cell of a ``grid_size`` x
``grid_size`` grid spanning [-grid_scale, grid_scale]^2; [grid, coarse point, global feature] ->
512 -> 512 -> 3, added to the coarse point (the fine cloud).
"""

from __future__ import annotations

import torch
from torch import nn

from shapebench.implicit.networks import mlp


def folding_grid(grid_size: int, grid_scale: float) -> torch.Tensor:
    """The (grid_size^2, 2) folding seed: a regular grid over [-grid_scale, grid_scale]^2."""
    axis = torch.linspace(-grid_scale, grid_scale, grid_size)
    gx, gy = torch.meshgrid(axis, axis, indexing="ij")
    return torch.stack([gx.reshape(-1), gy.reshape(-1)], dim=1)


class PCNNetwork(nn.Module):
    def __init__(
        self,
        feature: int = 1024,
        num_coarse: int = 1024,
        grid_size: int = 4,
        grid_scale: float = 0.05,
        decoder_width: int = 1024,
    ) -> None:
        super().__init__()
        self.num_coarse = num_coarse
        self.encoder_0 = mlp([3, 128, 256])
        self.encoder_1 = mlp([512, 512, feature])
        self.coarse = mlp([feature, decoder_width, decoder_width, 3 * num_coarse])
        self.folding = mlp([2 + 3 + feature, 512, 512, 3])
        self.register_buffer("grid", folding_grid(grid_size, grid_scale))
        for m in self.modules():
            if isinstance(m, nn.Linear):
                nn.init.xavier_uniform_(m.weight)
                nn.init.zeros_(m.bias)

    def forward(self, points: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """(B, k, 3) context -> coarse (B, num_coarse, 3) and fine (B, num_coarse * g^2, 3)."""
        b = points.shape[0]
        local = self.encoder_0(points)
        pooled = local.max(dim=1, keepdim=True).values.expand_as(local)
        feature = self.encoder_1(torch.cat([local, pooled], dim=-1)).max(dim=1).values
        coarse = self.coarse(feature).view(b, self.num_coarse, 3)
        cells = len(self.grid)
        centre = coarse.repeat_interleave(cells, dim=1)
        grid = self.grid.repeat(self.num_coarse, 1)[None].expand(b, -1, -1)
        glob = feature[:, None, :].expand(-1, centre.shape[1], -1)
        fine = self.folding(torch.cat([grid, centre, glob], dim=-1)) + centre
        return coarse, fine
