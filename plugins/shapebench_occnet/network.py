"""OccNet's encoder and decoders, as the official ``im2mesh`` code.

* :class:`ResnetPointnet` (``encoder/pointnet.py``): Linear 3 -> 2h, five ResnetBlockFC(2h -> h)
  with max-pooling, broadcast and concatenation after each of the first four, a final max-pool,
  ReLU and Linear h -> c_dim.
* :class:`DecoderBatchNorm` (the class the paper names): the query points through a 1x1
  convolution plus the code through a linear layer, five residual blocks of BatchNorm, ReLU and
  1x1 convolutions (the second zero-initialised), then BatchNorm, ReLU, 1x1 convolution to logits.
* :class:`DecoderCBatchNorm` (the official point-cloud configuration): the same with conditional
  batch norm: parameter-free BatchNorm whose scale and shift are 1x1 convolutions of the code
  (initialised to 1 and 0).
"""

from __future__ import annotations

import torch
from torch import nn
from torch.nn import functional as F

from shapebench.train.blocks import ResnetBlockFC


class ResnetPointnet(nn.Module):
    def __init__(self, c_dim: int = 512, hidden_dim: int = 512) -> None:
        super().__init__()
        self.fc_pos = nn.Linear(3, 2 * hidden_dim)
        self.blocks = nn.ModuleList(ResnetBlockFC(2 * hidden_dim, hidden_dim) for _ in range(5))
        self.fc_c = nn.Linear(hidden_dim, c_dim)

    def forward(self, points: torch.Tensor) -> torch.Tensor:
        net = self.fc_pos(points)
        for block in self.blocks[:-1]:
            net = block(net)
            pooled = net.max(dim=1, keepdim=True).values.expand_as(net)
            net = torch.cat([net, pooled], dim=2)
        net = self.blocks[-1](net).max(dim=1).values
        return self.fc_c(F.relu(net))


class CBatchNorm1d(nn.Module):
    def __init__(self, c_dim: int, features: int) -> None:
        super().__init__()
        self.bn = nn.BatchNorm1d(features, affine=False)
        self.conv_gamma = nn.Conv1d(c_dim, features, 1)
        self.conv_beta = nn.Conv1d(c_dim, features, 1)
        nn.init.zeros_(self.conv_gamma.weight)
        nn.init.ones_(self.conv_gamma.bias)
        nn.init.zeros_(self.conv_beta.weight)
        nn.init.zeros_(self.conv_beta.bias)

    def forward(self, x: torch.Tensor, c: torch.Tensor) -> torch.Tensor:
        c = c[:, :, None]
        return self.conv_gamma(c) * self.bn(x) + self.conv_beta(c)


class ResnetBlockConv1d(nn.Module):
    def __init__(self, size: int, c_dim: int | None = None) -> None:
        super().__init__()
        conditional = c_dim is not None
        self.bn_0 = CBatchNorm1d(c_dim, size) if conditional else nn.BatchNorm1d(size)
        self.bn_1 = CBatchNorm1d(c_dim, size) if conditional else nn.BatchNorm1d(size)
        self.fc_0 = nn.Conv1d(size, size, 1)
        self.fc_1 = nn.Conv1d(size, size, 1)
        self.conditional = conditional
        nn.init.zeros_(self.fc_1.weight)

    def _bn(self, bn: nn.Module, x: torch.Tensor, c: torch.Tensor) -> torch.Tensor:
        return bn(x, c) if self.conditional else bn(x)

    def forward(self, x: torch.Tensor, c: torch.Tensor) -> torch.Tensor:
        net = self.fc_0(F.relu(self._bn(self.bn_0, x, c)))
        return x + self.fc_1(F.relu(self._bn(self.bn_1, net, c)))


class DecoderBatchNorm(nn.Module):
    """Occupancy logits (B, T) for query points (B, T, 3) given codes (B, c_dim)."""

    def __init__(self, c_dim: int = 512, hidden: int = 256, conditional: bool = False) -> None:
        super().__init__()
        self.conditional = conditional
        self.fc_p = nn.Conv1d(3, hidden, 1)
        self.fc_c = None if conditional else nn.Linear(c_dim, hidden)
        cond = c_dim if conditional else None
        self.blocks = nn.ModuleList(ResnetBlockConv1d(hidden, cond) for _ in range(5))
        self.bn = CBatchNorm1d(c_dim, hidden) if conditional else nn.BatchNorm1d(hidden)
        self.fc_out = nn.Conv1d(hidden, 1, 1)

    def forward(self, points: torch.Tensor, c: torch.Tensor) -> torch.Tensor:
        net = self.fc_p(points.transpose(1, 2))
        if self.fc_c is not None:
            net = net + self.fc_c(c)[:, :, None]
        for block in self.blocks:
            net = block(net, c)
        net = self.bn(net, c) if self.conditional else self.bn(net)
        return self.fc_out(F.relu(net)).squeeze(1)


def DecoderCBatchNorm(c_dim: int = 512, hidden: int = 256) -> DecoderBatchNorm:  # noqa: N802
    """The official point-cloud decoder: conditional batch norm everywhere."""
    return DecoderBatchNorm(c_dim, hidden, conditional=True)
