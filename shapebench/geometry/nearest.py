"""Nearest-neighbour distances between point sets: the core of every Chamfer variant.

On the CPU a KD-tree (scipy's cKDTree, queried on all cores) gives exact distances in about 60 ms
for 30k x 30k points on 2 cores; on a GPU, when both sets are CUDA tensors, a chunked brute force
(``torch.cdist``) is faster than moving them back. Both return Euclidean (not squared) distances.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from scipy.spatial import cKDTree


def kdtree(points: np.ndarray) -> cKDTree:
    return cKDTree(np.asarray(points, dtype=np.float64))


def nearest_distances(query: Any, reference: Any, tree: cKDTree | None = None) -> Any:
    """For each point of ``query``, the Euclidean distance to the closest point of ``reference``.

    numpy arrays (or CPU tensors) go through a KD-tree (``tree`` if given, built on
    ``reference``); CUDA tensors stay on the GPU. The result has ``len(query)`` entries.
    """
    if _is_cuda_tensor(query) or _is_cuda_tensor(reference):
        return _torch_nearest(query, reference)
    q = as_numpy(query)
    if tree is None:
        tree = kdtree(as_numpy(reference))
    dist, _ = tree.query(q, k=1, workers=-1)
    return dist


def _is_cuda_tensor(x: Any) -> bool:
    return type(x).__module__.startswith("torch") and getattr(x, "is_cuda", False)


def as_numpy(x: Any) -> np.ndarray:
    """A float64 numpy copy of an array or a (CPU or CUDA) tensor."""
    if type(x).__module__.startswith("torch"):
        x = x.detach().cpu().numpy()
    return np.asarray(x, dtype=np.float64)


def _torch_nearest(query: Any, reference: Any, chunk: int = 4096) -> Any:
    import torch

    device = query.device if _is_cuda_tensor(query) else reference.device
    q = torch.as_tensor(query, device=device, dtype=torch.float32)
    r = torch.as_tensor(reference, device=device, dtype=torch.float32)
    out = torch.empty(len(q), device=device, dtype=torch.float32)
    for start in range(0, len(q), chunk):
        # The matrix-product form of cdist loses ~5e-4 on near-coincident points in float32.
        d = torch.cdist(q[start : start + chunk], r, compute_mode="donot_use_mm_for_euclid_dist")
        out[start : start + chunk] = d.min(dim=1).values
    return out


def brute_force_nearest(query: np.ndarray, reference: np.ndarray, chunk: int = 2048) -> np.ndarray:
    """Reference implementation with torch.cdist on the CPU (tests and benchmarks)."""
    import torch

    q = torch.as_tensor(np.asarray(query, dtype=np.float64))
    r = torch.as_tensor(np.asarray(reference, dtype=np.float64))
    parts = [torch.cdist(q[s : s + chunk], r).min(dim=1).values for s in range(0, len(q), chunk)]
    return torch.cat(parts).numpy()
