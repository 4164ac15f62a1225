"""The local tower that replaces each of MSC's per-point MLPs f and g.

MSC's encoder (equation 2) turns every observation (x_n, y_n) into a vote f_n for the latent code
and a precision from g_n, and sums them. The paper's f and g are per-point MLPs, chosen "to test
the sheer efficacy of our meta-approach"; a point alone says little about the shape around it.
Here f_n and g_n are read from the point's *neighbourhood*, as a PointNet++ set-abstraction layer
reads a centre's ball, with every context point a centre (no subsampling, so there is still one
vote and one precision per observation and the posterior's sums are unchanged):

* embed: a linear layer and ReLU on (x_n, y_n);
* ``levels`` rounds over the k nearest neighbours j of n (k = ``neighbours``, or every point of a
  smaller context, n included): a shared layer on each neighbour's feature concatenated with its
  offset x_j - x_n (not divided by a radius, as PointNet++ groups), ReLU, max over the
  neighbours, a second layer, added to n's feature (a residual, so a round can only add
  information). Two rounds over the same k-NN graph see two hops. The shared layer is linear in
  (h_j, x_j - x_n), so it is computed once per point and only its maximum over the neighbours is
  gathered: a PointNet++ layer's two-layer shared MLP before the max made MSC's training step 9x
  slower on a CPU (1.49 s against 0.16; docs/methods.md has this layout's cost);
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
    """``values`` (B, N, C) at ``idx`` (B, N, k): (B, N, k, C). Rows are copied whole by
    ``index_select`` on the flattened batch (measured 1.7x faster than ``gather`` on a CPU)."""
    b, n, k = idx.shape
    base = torch.arange(b, device=idx.device).view(b, 1, 1) * values.shape[1]
    rows = values.reshape(-1, values.shape[-1]).index_select(0, (idx + base).reshape(-1))
    return rows.view(b, n, k, values.shape[-1])


def neighbourhood_max(values: torch.Tensor, idx: torch.Tensor) -> torch.Tensor:
    """Per point and channel, the largest value of ``values`` (B, N, C) over the point's
    neighbours ``idx`` (B, N, k): (B, N, C).

    The same values and gradients as ``gather_rows(values, idx).max(dim=2).values``, which keeps a
    (B, N, k, C) tensor for the backward pass: here the maximum is located without gradients and
    only the winning entries are gathered again with them (k times less memory traffic; the
    backward pass of the full gather dominated the step on a CPU).
    """
    with torch.no_grad():
        # (B, N, C): which neighbour, per channel (max(dim).indices: argmax over a middle
        # dimension is several times slower on a CPU)
        winner = gather_rows(values, idx).max(dim=2).indices
        source = idx.gather(2, winner)  # (B, N, C): that neighbour's point index
    return values.gather(1, source)


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
        # Per level: the shared layer on (h_j, x_j - x_n), split into its feature and offset
        # parts, and the layer after the max.
        self.shared = nn.ModuleList(nn.Linear(hidden, hidden) for _ in range(levels))
        self.offset = nn.ModuleList(nn.Linear(3, hidden, bias=False) for _ in range(levels))
        self.after = nn.ModuleList(nn.Linear(hidden, hidden) for _ in range(levels))
        self.head = mlp([hidden] * max(head_layers, 1) + [out_dim])

    def forward(self, inp: torch.Tensor) -> torch.Tensor:
        xyz = inp[..., :3]
        h = torch.relu(self.embed(inp))
        if len(self.shared):
            idx = knn_indices(xyz, self.neighbours)
            for shared, offset, after in zip(self.shared, self.offset, self.after, strict=True):
                # W [h_j, x_j - x_n] + b = (W_h h_j + W_x x_j + b) - W_x x_n, and since ReLU is
                # monotone, max_j ReLU(p_j - m_n) = ReLU(max_j p_j - m_n) per channel.
                moved = offset(xyz)
                pooled = neighbourhood_max(shared(h) + moved, idx)
                h = h + after(torch.relu(pooled - moved))
        return self.head(torch.relu(h))
