"""Losses of IGR, DeepSDF and MSC, and the off-surface samplers they use."""

from __future__ import annotations

import math

import torch


def gradient(y: torch.Tensor, x: torch.Tensor) -> torch.Tensor:
    """dy/dx with a graph, so losses on the gradient can be trained (double backprop)."""
    return torch.autograd.grad(y, x, torch.ones_like(y), create_graph=True)[0]


def eikonal(grad: torch.Tensor) -> torch.Tensor:
    """IGR's Eikonal term, mean of (||grad|| - 1)^2 per object: (B,).

    The paper's equation writes E[||grad|| - 1] without a square, which is minimised by a zero
    gradient; the official code squares it, and so do we.
    """
    return ((grad.norm(dim=-1) - 1.0) ** 2).mean(dim=-1)


def normal_term(grad: torch.Tensor, normals: torch.Tensor) -> torch.Tensor:
    """IGR's normal term per object: mean of ||grad f - n|| (a norm, not squared): (B,)."""
    return (grad - normals).norm(dim=-1).mean(dim=-1)


def offsurface_samples(
    surface: torch.Tensor,
    mode: str,
    local_sigma: float = 0.01,
    global_bound: float = 1.8,
    paper_count: int = 5000,
    paper_variance: float = 0.04,
    count: int = 0,
) -> torch.Tensor:
    """Points near and around the surface where the Eikonal term is evaluated.

    ``mode="paper"`` (Appendix A.1): ``paper_count`` of the surface points (at most all of them),
    each moved by a Gaussian of variance 0.04. ``mode="official"`` (IGR's ``NormalPerPoint``):
    every surface point moved by a Gaussian of std ``local_sigma``, plus N/8 points uniform in
    [-global_bound, global_bound]^3.

    ``count`` > 0 replaces the mode's choice of base points by ``count`` points drawn from
    ``surface`` with replacement, in one draw: the same distribution, estimated with a sample
    count that does not shrink with the surface's (IGR's test-time ``opt_eikonal_samples``).
    """
    b, n, _ = surface.shape
    if count > 0:
        surface, n = _pick(surface, count), count
        if mode == "paper":  # the base points are drawn: only the move is left
            return surface + torch.randn_like(surface) * math.sqrt(paper_variance)
    if mode == "paper":
        base = _pick(surface, min(paper_count, n))
        return base + torch.randn_like(base) * math.sqrt(paper_variance)
    if mode == "official":
        local = surface + torch.randn_like(surface) * local_sigma
        glob = (torch.rand(b, max(n // 8, 1), 3, device=surface.device) * 2 - 1) * global_bound
        return torch.cat([local, glob], dim=1)
    raise ValueError(f"off-surface mode must be 'paper' or 'official', got {mode!r}")


def _pick(points: torch.Tensor, count: int) -> torch.Tensor:
    """``count`` of each object's points, drawn uniformly with replacement: (B, count, 3)."""
    idx = torch.randint(0, points.shape[1], (points.shape[0], count), device=points.device)
    return torch.gather(points, 1, idx[..., None].expand(-1, -1, 3))


def clamped_l1(pred: torch.Tensor, target: torch.Tensor, delta: float = 0.1) -> torch.Tensor:
    """DeepSDF's data term per object: both sides clamped to [-delta, delta]: (B,)."""
    return (pred.clamp(-delta, delta) - target.clamp(-delta, delta)).abs().mean(dim=-1)


def gaussian_kl(
    mq: torch.Tensor, vq: torch.Tensor, mp: torch.Tensor, vp: torch.Tensor
) -> torch.Tensor:
    """KL(N(mq, vq) || N(mp, vp)) for diagonal Gaussians, summed over dimensions: (B,)."""
    return 0.5 * (torch.log(vp / vq) + (vq + (mq - mp) ** 2) / vp - 1.0).sum(dim=-1)
