"""Network blocks shared by several methods' networks.

A module of ``train/`` is keyed on its own file (:mod:`shapebench.train.losses`): OccNet and
ConvONet both build on :class:`ResnetBlockFC` and name this file in their ``code_modules``, so an
edit of one method's package no longer moves the other's checkpoint keys (ConvONet used to
import the block from OccNet's package, which put all of OccNet's code in its keys).
"""

from __future__ import annotations

import torch
from torch import nn
from torch.nn import functional as F


class ResnetBlockFC(nn.Module):
    """OccNet's fully connected residual block (official ``im2mesh/layers.py``): ReLU, Linear
    ``size_in -> min(size_in, size_out)``, ReLU, Linear to ``size_out`` (zero-initialised), plus
    the input, through a bias-free Linear when the sizes differ."""

    def __init__(self, size_in: int, size_out: int) -> None:
        super().__init__()
        size_h = min(size_in, size_out)
        self.fc_0 = nn.Linear(size_in, size_h)
        self.fc_1 = nn.Linear(size_h, size_out)
        self.shortcut = nn.Linear(size_in, size_out, bias=False) if size_in != size_out else None
        nn.init.zeros_(self.fc_1.weight)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        dx = self.fc_1(F.relu(self.fc_0(F.relu(x))))
        return (self.shortcut(x) if self.shortcut is not None else x) + dx
