"""Point-set losses shared by the training modules of several methods.

A module of ``train/`` stands for its own file in a code digest
(:mod:`shapebench.registry.code_digest`): a method that names it in ``code_modules`` keys its
checkpoints on this file only, not on another method's package, so PoinTr no longer retrains
when PCN's code changes.
"""

from __future__ import annotations

import torch


def chamfer_l1_halved(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """PCN's and PoinTr's training CD between (B, N, 3) and (B, M, 3) sets, (B,):
    ``(mean_a min ||a - b|| + mean_b min ||a - b||) / 2`` with unsquared distances (the
    "CD-L1" of PoinTr's tables, halved as PCN's code computes it)."""
    d = torch.cdist(a, b)
    return 0.5 * (d.min(dim=2).values.mean(dim=1) + d.min(dim=1).values.mean(dim=1))
