"""Point-set losses shared by the training modules of several methods.

A module of ``train/`` stands for its own file in a code digest
(:mod:`shapebench.registry.code_digest`): a method that names it in ``code_modules`` keys its
checkpoints on this file only, not on another method's package, so PoinTr no longer retrains
when PCN's code changes.
"""

from __future__ import annotations

import numpy as np
import torch

from shapebench.geometry.nearest import PointTree, torch_nearest


def nearest_pairs(a: torch.Tensor, b: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """For sets ``a`` (B, N, 3) and ``b`` (B, M, 3): the index in ``b`` of each point of ``a``'s
    nearest neighbour (B, N), and the index in ``a`` of each point of ``b``'s (B, M), int64,
    computed without gradient.

    On the CPU an exact float64 KD-tree per set (:meth:`shapebench.geometry.nearest.PointTree
    .indices`); on a GPU, or where a set is not finite (a diverged training keeps its NaN loss),
    chunked ``torch.cdist`` in its exact form (:func:`~shapebench.geometry.nearest
    .torch_nearest`). The two agree except on exact ties, which each breaks its own way.
    """
    with torch.no_grad():
        if a.device.type == "cpu" and bool(torch.isfinite(a).all() and torch.isfinite(b).all()):
            a64, b64 = a.detach().double().numpy(), b.detach().double().numpy()
            to_b, to_a = zip(
                *(
                    (PointTree(y).indices(x), PointTree(x).indices(y))
                    for x, y in zip(a64, b64, strict=True)
                ),
                strict=True,
            )
            return torch.from_numpy(np.stack(to_b)), torch.from_numpy(np.stack(to_a))
        to_b, to_a = zip(
            *((torch_nearest(x, y)[1], torch_nearest(y, x)[1]) for x, y in zip(a, b, strict=True)),
            strict=True,
        )
        return torch.stack(to_b), torch.stack(to_a)


def distances_to(a: torch.Tensor, b: torch.Tensor, index: torch.Tensor) -> torch.Tensor:
    """(B, N): the Euclidean distance from each point of ``a`` to the point of ``b`` that
    ``index`` names, differentiable in both sets (the gradient of ``torch.cdist(a, b).min(2)``
    when ``index`` holds the nearest points), without forming the (B, N, M) matrix."""
    chosen = torch.gather(b, 1, index[..., None].expand(-1, -1, b.shape[-1]))
    return (a - chosen).norm(dim=-1)


def chamfer_l1_halved(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """PCN's and PoinTr's training CD between (B, N, 3) and (B, M, 3) sets, (B,):
    ``(mean_a min ||a - b|| + mean_b min ||a - b||) / 2`` with unsquared distances (the
    "CD-L1" of PoinTr's tables, halved as PCN's code computes it).

    The nearest neighbours are found without gradient (:func:`nearest_pairs`) and only the chosen
    pairs are differentiated: the same loss and gradient as through ``torch.cdist`` and ``min``
    (tests/methods/test_pcn.py), at about a fiftieth of the time at PCN's standard sizes, where
    cdist's backward over the whole matrix was most of a training step (benchmarks/README.md).
    """
    to_b, to_a = nearest_pairs(a, b)
    return 0.5 * (distances_to(a, b, to_b).mean(dim=1) + distances_to(b, a, to_a).mean(dim=1))
