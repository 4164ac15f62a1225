"""PCN's coarse loss, an approximate EMD, and the weight schedule of its fine term (the fine term,
the halved Chamfer, is shared with PoinTr: :func:`shapebench.train.losses.chamfer_l1_halved`).

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
    """Approximate EMD between (B, N, 3) sets of equal size: mean matched distance, (B,).

    The Sinkhorn iterations run on the kernel ``exp(-cost / eps)`` in float64, where they are
    two matrix-vector products, instead of log-domain ``logsumexp`` passes over (B, N, N): the
    same iterations (plans equal to ~1e-7), about 2 to 3 times faster on a CPU. float64 keeps
    the kernel's entries above underflow for distances up to ``700 * eps`` (7 at the default:
    seven times a unit-diameter shape); beyond that the log-domain iterations are used.
    """
    cost = torch.cdist(a, b)
    with torch.no_grad():
        plan = _sinkhorn_plan(cost, eps, iterations)
    return (plan * cost).sum(dim=(1, 2))


def _sinkhorn_plan(cost: torch.Tensor, eps: float, iterations: int) -> torch.Tensor:
    n = cost.shape[1]
    if float(cost.max()) < 700 * eps:
        kernel = torch.exp(-cost.double() / eps)
        u = torch.ones(cost.shape[:2], device=cost.device, dtype=torch.float64)
        v = torch.ones_like(u)
        for _ in range(iterations):
            u = (1.0 / n) / (kernel * v[:, None, :]).sum(dim=2)
            v = (1.0 / n) / (kernel * u[:, :, None]).sum(dim=1)
        plan = u[:, :, None] * kernel * v[:, None, :]
        if bool(torch.isfinite(plan).all()):
            return plan.to(cost.dtype)
    return _sinkhorn_plan_log(cost, eps, iterations)


def _sinkhorn_plan_log(cost: torch.Tensor, eps: float, iterations: int) -> torch.Tensor:
    """The log-domain iterations: stable at any distance, slower."""
    n = cost.shape[1]
    log_k = -cost / eps
    log_mu = torch.full(cost.shape[:2], -math.log(n), device=cost.device, dtype=cost.dtype)
    u = torch.zeros_like(log_mu)
    v = torch.zeros_like(log_mu)
    for _ in range(iterations):
        u = log_mu - torch.logsumexp(log_k + v[:, None, :], dim=2)
        v = log_mu - torch.logsumexp(log_k + u[:, :, None], dim=1)
    return torch.exp(log_k + u[:, :, None] + v[:, None, :])


def alpha(step: int, boundaries: tuple[int, ...] = (10_000, 20_000, 50_000)) -> float:
    """The official weight of the fine term: 0.01, 0.1, 0.5, then 1.0 at the step boundaries."""
    for value, boundary in zip((0.01, 0.1, 0.5), boundaries, strict=False):
        if step < boundary:
            return value
    return 1.0
