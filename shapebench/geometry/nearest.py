"""Nearest-neighbour distances between point sets: the core of every Chamfer variant.

On the CPU a KD-tree gives exact distances: pykdtree when it is installed (a dependency), scipy's
cKDTree otherwise; on a GPU, when both sets are CUDA tensors, a chunked brute force
(``torch.cdist``) is faster than moving them back. All return Euclidean (not squared) distances.

pykdtree and cKDTree return bitwise-identical float64 distances (both sum the three squared
coordinate differences in order, then take the square root; neither x86_64 wheel uses FMA
instructions), so the choice changes no score, only the time. Measured on a quiet 2-core x86_64
CPU with ``.venv/bin/python benchmarks/bench_chamfer.py --repeat 15 --brute-repeat 0`` (chamfer-l2
of 30k x 30k points, medians of 15 interleaved rounds, both trees on 2 threads; pykdtree 1.4.3,
scipy 1.17.1; load average 0.4):

    path                          median s   vs cKDTree
    cKDTree, cold                   0.0385        1.00x
    cKDTree, GT tree cached         0.0316        1.00x
    shapebench (pykdtree), cold     0.0202        1.90x
    pykdtree, GT tree cached        0.0177        1.79x

distances bitwise identical (0 of 60000 differ). The cached case is the runner's (the ground
truth's tree is built once per object, the completion's once per completion). Under load (a test
suite beside it, load average 1.8 to 3.8) the gain shrank and varied: over 20 runs 1.20x to 2.23x
cold (median 1.33x) and 0.95x to 2.20x cached (median 1.13x); benchmarks/README.md has the runs.

pykdtree is used only for finite, non-empty point sets: on NaN or infinite coordinates it returns
meaningless numbers where cKDTree raises ``ValueError``, and on an empty reference it raises where
cKDTree returns ``inf``; those inputs go to cKDTree, so they fail (or not) exactly as before.

Threads: cKDTree is queried with ``workers=-1`` (``os.cpu_count()`` threads). pykdtree has no
per-call thread argument: its queries run in an OpenMP parallel region of its own bundled
libgomp, whose team size is ``OMP_NUM_THREADS`` read when the library is loaded (the local sweep
launcher sets it to cores // workers for each worker), else one thread per CPU the process may
use. ``threadpoolctl`` can change it at run time (``benchmarks/bench_chamfer.py --threads``).
"""

from __future__ import annotations

from typing import Any

import numpy as np
from scipy.spatial import cKDTree

try:
    from pykdtree.kdtree import KDTree as _PyKDTree
except ImportError:  # an install without pykdtree: the same distances through cKDTree, slower
    _PyKDTree = None

#: The KD-tree ``nearest_distances`` uses by default: ``"pykdtree"``, or ``"scipy"`` without it.
DEFAULT_BACKEND = "scipy" if _PyKDTree is None else "pykdtree"
BACKENDS = ("pykdtree", "scipy")


class PointTree:
    """A KD-tree on one point set, as :func:`kdtree` builds it (``ObjectData.cache["gt_tree"]``).

    :meth:`distances` is the search of :func:`nearest_distances`, through ``backend``
    (pykdtree or scipy's cKDTree; see the module docstring for the inputs that always go to
    cKDTree). :meth:`query` is ``cKDTree.query`` itself (k neighbours, indices, ``workers``...)
    for callers that need more than the distance to the nearest point. Each tree is built on
    first use, so a caller of one kind pays for one tree.
    """

    def __init__(self, points: Any, backend: str | None = None) -> None:
        backend = DEFAULT_BACKEND if backend is None else backend
        if backend not in BACKENDS:
            raise ValueError(f"unknown KD-tree backend {backend!r}; expected one of {BACKENDS}")
        if backend == "pykdtree" and _PyKDTree is None:
            raise ImportError("the pykdtree backend needs pykdtree (pip install pykdtree)")
        self.backend = backend
        self.data = np.ascontiguousarray(points, dtype=np.float64)
        self._scipy: cKDTree | None = None
        self._fast: Any = None
        self._fast_ok: bool | None = None

    @property
    def scipy_tree(self) -> cKDTree:
        if self._scipy is None:
            self._scipy = cKDTree(self.data)
        return self._scipy

    def query(self, x: Any, k: int = 1, **kwargs: Any) -> Any:
        """``cKDTree.query`` on these points (distances and indices)."""
        return self.scipy_tree.query(x, k=k, **kwargs)

    def distances(self, query: np.ndarray) -> np.ndarray:
        """For each row of ``query``, the distance to the closest point (float64)."""
        return self._nearest(query)[0]

    def indices(self, query: np.ndarray) -> np.ndarray:
        """For each row of ``query``, the index of the closest point (int64), from the same
        search as :meth:`distances`. Where two points are equally close the two backends may
        name different ones; the distance is the same."""
        return self._nearest(query)[1].astype(np.int64)

    def _nearest(self, query: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        q = np.ascontiguousarray(query, dtype=np.float64)
        if self._use_pykdtree(q):
            if self._fast is None:
                self._fast = _PyKDTree(self.data)
            return self._fast.query(q, k=1)
        return self.scipy_tree.query(q, k=1, workers=-1)

    def _use_pykdtree(self, q: np.ndarray) -> bool:
        if self.backend != "pykdtree":
            return False
        if self._fast_ok is None:
            d = self.data
            self._fast_ok = d.ndim == 2 and len(d) > 0 and bool(np.isfinite(d).all())
        return (
            self._fast_ok
            and q.ndim == 2
            and q.shape[1] == self.data.shape[1]
            and bool(np.isfinite(q).all())
        )

    def __getstate__(self) -> dict[str, Any]:
        # pykdtree's tree does not pickle: send the points, rebuild on first use.
        return {**self.__dict__, "_fast": None, "_scipy": None}


def kdtree(points: Any, backend: str | None = None) -> PointTree:
    """A :class:`PointTree` on ``points`` (float64) for :func:`nearest_distances`' ``tree``."""
    return PointTree(points, backend)


def nearest_distances(query: Any, reference: Any, tree: PointTree | cKDTree | None = None) -> Any:
    """For each point of ``query``, the Euclidean distance to the closest point of ``reference``.

    numpy arrays (or CPU tensors) go through a KD-tree (``tree`` if given, built on
    ``reference``: a :class:`PointTree` from :func:`kdtree`, or a bare cKDTree); CUDA tensors
    stay on the GPU. The result has ``len(query)`` entries.
    """
    if _is_cuda_tensor(query) or _is_cuda_tensor(reference):
        return torch_nearest(query, reference)[0]
    q = as_numpy(query)
    if tree is None:
        tree = kdtree(as_numpy(reference))
    if isinstance(tree, PointTree):
        return tree.distances(q)
    dist, _ = tree.query(q, k=1, workers=-1)
    return dist


def _is_cuda_tensor(x: Any) -> bool:
    return type(x).__module__.startswith("torch") and getattr(x, "is_cuda", False)


def as_numpy(x: Any) -> np.ndarray:
    """A float64 numpy copy of an array or a (CPU or CUDA) tensor."""
    if type(x).__module__.startswith("torch"):
        x = x.detach().cpu().numpy()
    return np.asarray(x, dtype=np.float64)


def torch_nearest(query: Any, reference: Any, chunk: int = 4096) -> tuple[Any, Any]:
    """For each row of ``query``, the distance to the closest row of ``reference`` (float32)
    and its index (int64), by brute force on the tensors' device in chunks of ``chunk`` rows:
    the GPU path of :func:`nearest_distances` and of the training losses."""
    import torch

    device = query.device if _is_cuda_tensor(query) else reference.device
    q = torch.as_tensor(query, device=device, dtype=torch.float32)
    r = torch.as_tensor(reference, device=device, dtype=torch.float32)
    dist = torch.empty(len(q), device=device, dtype=torch.float32)
    index = torch.empty(len(q), device=device, dtype=torch.int64)
    for start in range(0, len(q), chunk):
        # The matrix-product form of cdist loses ~5e-4 on near-coincident points in float32.
        d = torch.cdist(q[start : start + chunk], r, compute_mode="donot_use_mm_for_euclid_dist")
        dist[start : start + chunk], index[start : start + chunk] = d.min(dim=1)
    return dist, index


def brute_force_nearest(query: np.ndarray, reference: np.ndarray, chunk: int = 2048) -> np.ndarray:
    """Reference implementation with torch.cdist on the CPU (tests and benchmarks)."""
    import torch

    q = torch.as_tensor(np.asarray(query, dtype=np.float64))
    r = torch.as_tensor(np.asarray(reference, dtype=np.float64))
    parts = [torch.cdist(q[s : s + chunk], r).min(dim=1).values for s in range(0, len(q), chunk)]
    return torch.cat(parts).numpy()
