"""PCN's losses: an approximate EMD on the coarse cloud and the halved Chamfer on the fine one.

The official coarse term is the EMD of Fan et al.'s ``approxmatch`` CUDA kernel (an iterative
soft assignment). Here it is approximated with entropy-regularised optimal transport (log-domain
Sinkhorn iterations, uniform weights on two sets of the same size): the transport plan is computed
without gradients and the loss is the plan-weighted mean of Euclidean (unsquared) distances, whose
gradient with respect to the points is the matched displacement, as for the exact EMD.
"""

from __future__ import annotations

import math

import torch


def sinkhorn_emd(
    a: torch.Tensor, b: torch.Tensor, eps: float = 0.01, iterations: int = 100
) -> torch.Tensor:
    """Approximate EMD between (B, N, 3) sets of equal size: mean matched distance, (B,)."""
    cost = torch.cdist(a, b)
    n = a.shape[1]
    with torch.no_grad():
        log_k = -cost / eps
        log_mu = torch.full(a.shape[:2], -math.log(n), device=a.device, dtype=a.dtype)
        u = torch.zeros_like(log_mu)
        v = torch.zeros_like(log_mu)
        for _ in range(iterations):
            u = log_mu - torch.logsumexp(log_k + v[:, None, :], dim=2)
            v = log_mu - torch.logsumexp(log_k + u[:, :, None], dim=1)
        plan = torch.exp(log_k + u[:, :, None] + v[:, None, :])
    return (plan * cost).sum(dim=(1, 2))


def chamfer_l1_halved(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """PCN's CD: (mean_a min ||a - b|| + mean_b min ||a - b||) / 2, unsquared, (B,)."""
    d = torch.cdist(a, b)
    return 0.5 * (d.min(dim=2).values.mean(dim=1) + d.min(dim=1).values.mean(dim=1))


def alpha(step: int, boundaries: tuple[int, ...] = (10_000, 20_000, 50_000)) -> float:
    """The official weight of the fine term: 0.01, 0.1, 0.5, then 1.0 at the step boundaries."""
    for value, boundary in zip((0.01, 0.1, 0.5), boundaries, strict=False):
        if step < boundary:
            return value
    return 1.0
