"""The local tower that replaces each of MSC's per-point MLPs f and g.

MSC's encoder (equation 2) turns every observation (x_n, y_n) into a vote f_n for the latent code
and a precision from g_n, and sums them. The paper's f and g are per-point MLPs, chosen "to test
the sheer efficacy of our meta-approach"; a point alone says little about the shape around it.
Here f_n and g_n are read from the point's *neighbourhood*, as a PointNet++ set-abstraction layer
reads a centre's ball, with every context point a centre (no subsampling, so there is still one
vote and one precision per observation and the posterior's sums are unchanged):

* embed: a linear layer and ReLU on (x_n, y_n);
* ``levels`` rounds over the k nearest neighbours j of n (k = ``neighbours``, or every point of a
  smaller context, n included): each neighbour's feature concatenated with its offset
  x_j - x_n (not divided by a radius, as PointNet++ groups), a shared two-layer MLP, max over the
  neighbours, added to n's feature (a residual, so a round can only add information). Two rounds
  over the same k-NN graph see two hops;
* head: an MLP to the latent size.

k nearest neighbours rather than PointNet++'s ball query: contexts range from 50 to 1000 points,
and a fixed radius that holds neighbours at 50 points holds hundreds at 1000; k neighbours adapt
to the density. The tower is permutation-equivariant, so the encoder stays order-invariant.
"""

from __future__ import annotations

import torch
from torch import nn

from shapebench.implicit.networks import mlp


def knn_indices(points: torch.Tensor, k: int) -> torch.Tensor:
    """(B, N, k) indices of each point's k nearest points (itself first), k <= N."""
    distances = torch.cdist(points, points)
    return distances.topk(min(k, points.shape[1]), dim=-1, largest=False).indices


def gather_rows(values: torch.Tensor, idx: torch.Tensor) -> torch.Tensor:
    """``values`` (B, N, C) at ``idx`` (B, N, k): (B, N, k, C)."""
    b, n, k = idx.shape
    flat = idx.reshape(b, n * k, 1).expand(-1, -1, values.shape[-1])
    return values.gather(1, flat).reshape(b, n, k, values.shape[-1])


class LocalTower(nn.Module):
    """Per-point outputs (B, N, out_dim) from per-point inputs (B, N, in_dim) whose first three
    columns are the point's position (see the module docstring)."""

    def __init__(
        self, in_dim: int, hidden: int, out_dim: int, neighbours: int, levels: int, head_layers: int
    ) -> None:
        super().__init__()
        if neighbours < 1 or levels < 0:
            raise ValueError(f"neighbours must be >= 1 and levels >= 0, got {neighbours}, {levels}")
        self.neighbours = neighbours
        self.embed = nn.Linear(in_dim, hidden)
        self.levels = nn.ModuleList(mlp([hidden + 3, hidden, hidden]) for _ in range(levels))
        self.head = mlp([hidden] * max(head_layers, 1) + [out_dim])

    def forward(self, inp: torch.Tensor) -> torch.Tensor:
        xyz = inp[..., :3]
        h = torch.relu(self.embed(inp))
        if self.levels:
            idx = knn_indices(xyz, self.neighbours)
            offsets = gather_rows(xyz, idx) - xyz[:, :, None, :]
            for level in self.levels:
                message = level(torch.cat([gather_rows(h, idx), offsets], dim=-1))
                h = h + torch.relu(message).max(dim=2).values
        return self.head(h)
