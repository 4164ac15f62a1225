"""PCN's network, as the official TensorFlow code (``models/pcn_emd.py``): no batch norm, ReLU,
Xavier-uniform weights and zero biases.

Encoder: per-point 3 -> 128 -> 256, max-pooled global feature concatenated back to every point,
512 -> 512 -> ``feature``, max-pooled again. Decoder: fully connected ``feature`` ->
``decoder_width`` -> ``decoder_width`` -> 3 * ``num_coarse`` (the coarse cloud; the official
width is 1024), then folding: every coarse point is repeated once per cell of a ``grid_size`` x
``grid_size`` grid spanning [-grid_scale, grid_scale]^2; [grid, coarse point, global feature] ->
512 -> 512 -> 3, added to the coarse point (the fine cloud).

The two concatenations of a per-shape vector onto every point are computed without forming them
(:func:`linear_of_concat`): the same layers and weights as the official code, a third less time
per training step at the standard profile's 4,096 output points (benchmarks/README.md).
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

from shapebench.implicit.networks import mlp


def folding_grid(grid_size: int, grid_scale: float) -> torch.Tensor:
    """The (grid_size^2, 2) folding seed: a regular grid over [-grid_scale, grid_scale]^2."""
    axis = torch.linspace(-grid_scale, grid_scale, grid_size)
    gx, gy = torch.meshgrid(axis, axis, indexing="ij")
    return torch.stack([gx.reshape(-1), gy.reshape(-1)], dim=1)


def linear_of_concat(
    layer: nn.Linear, per_point: torch.Tensor, per_shape: torch.Tensor
) -> torch.Tensor:
    """``layer(cat([per_point, per_shape repeated on every point], -1))`` for (B, P, a) and
    (B, c): the weight's columns split, the per-shape product taken once per shape instead of
    once per point (PCN's global feature is 256 of the folding layer's 261 inputs)."""
    a = per_point.shape[-1]
    points = F.linear(per_point, layer.weight[:, :a], layer.bias)
    return points + F.linear(per_shape, layer.weight[:, a:])[:, None, :]


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
        pooled = local.max(dim=1).values
        hidden = linear_of_concat(self.encoder_1[0], local, pooled)
        feature = self.encoder_1[1:](hidden).max(dim=1).values
        coarse = self.coarse(feature).view(b, self.num_coarse, 3)
        cells = len(self.grid)
        centre = coarse.repeat_interleave(cells, dim=1)
        grid = self.grid.repeat(self.num_coarse, 1)[None].expand(b, -1, -1)
        hidden = linear_of_concat(self.folding[0], torch.cat([grid, centre], dim=-1), feature)
        fine = self.folding[1:](hidden) + centre
        return coarse, fine
