"""Point-set losses shared by the training modules of several methods.

A module of ``train/`` stands for its own file in a code digest
(:mod:`shapebench.registry.code_digest`): a method that names it in ``code_modules`` keys its
checkpoints on this file only, not on another method's package, so PoinTr no longer retrains
when PCN's code changes.
"""

from __future__ import annotations

import numpy as np
import torch

from shapebench.geometry.nearest import nearest_indices


def nearest_in(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """For each point of ``a`` (B, N, 3), the index of its nearest point in ``b`` (B, M, 3):
    (B, N) int64, computed without gradient.

    On the CPU an exact float64 KD-tree per set (:func:`shapebench.geometry.nearest
    .nearest_indices`); on a GPU, or where a set is not finite (a diverged training keeps its NaN
    loss), argmin over chunked ``torch.cdist``. The two agree except on near-ties, which the
    tree breaks exactly and the matrix-product form of cdist may not.
    """
    with torch.no_grad():
        if a.device.type == "cpu" and bool(torch.isfinite(a).all() and torch.isfinite(b).all()):
            a64, b64 = a.detach().double().numpy(), b.detach().double().numpy()
            return torch.from_numpy(
                np.stack([nearest_indices(a64[i], b64[i]) for i in range(len(a64))])
            )
        parts = [
            torch.cdist(a[:, s : s + 1024], b).argmin(dim=2) for s in range(0, a.shape[1], 1024)
        ]
        return torch.cat(parts, dim=1)


def nearest_distances_to(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """(B, N): the Euclidean distance from each point of ``a`` to its nearest point in ``b``,
    differentiable in both sets like ``torch.cdist(a, b).min(dim=2)`` (the gradient flows
    through the nearest pair only), without forming the (B, N, M) matrix with gradient."""
    index = nearest_in(a, b)
    nearest = torch.gather(b, 1, index[..., None].expand(-1, -1, b.shape[-1]))
    return (a - nearest).norm(dim=-1)


def chamfer_l1_halved(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """PCN's and PoinTr's training CD between (B, N, 3) and (B, M, 3) sets, (B,):
    ``(mean_a min ||a - b|| + mean_b min ||a - b||) / 2`` with unsquared distances (the
    "CD-L1" of PoinTr's tables, halved as PCN's code computes it).

    The nearest neighbours are found without gradient (:func:`nearest_in`) and only the chosen
    pairs are differentiated: the same loss and gradient as through ``torch.cdist`` and ``min``
    (tests/test_pcn.py), at about a fiftieth of the time at PCN's standard sizes, where cdist's
    backward over the whole matrix was most of a training step (benchmarks/README.md).
    """
    return 0.5 * (nearest_distances_to(a, b).mean(dim=1) + nearest_distances_to(b, a).mean(dim=1))
