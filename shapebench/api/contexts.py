"""Context points: drawn once per object, stored, identical for every method.

For each test object the visible surface points are put in a random order seeded by
(dataset fingerprint, object id); the context of size k is the first k points of that order.
So contexts are *nested* (the 50 points are among the 100, which are among the 300...) whatever
set of sizes a run asks for, and a run with only ``--contexts 50`` sees the same 50 points as a
full sweep. The order is drawn with numpy on the CPU, never on an accelerator, so it does not
depend on the device. The indices are stored next to the object's cached arrays the first time
and read back afterwards; their SHA-256 goes into every run's tags.

Methods that need randomness get ``Context.seed``, derived from (dataset, object, size, run seed).

Under ``--protocol crop`` (:mod:`shapebench.api.protocol`) the points come from the object's
complete ground-truth cloud instead: the ``crop_fraction`` of its points nearest one of 8 fixed
viewpoints (the cube's corners, one chosen per object by a seed) are removed, and the context of
size k is the first k points of a farthest-point order of the rest, from a seeded start. A
farthest-point order is nested as well (its first 50 points are the farthest-point sample of 50),
and it is stored like the sparse order, as long as the largest size asked for. ``context_noise``
adds seeded Gaussian noise, one draw per point of the source cloud, so a point carries the same
noise at every size and for every method.

Under ``--protocol depth`` the points are those of the complete ground-truth cloud that one
camera sees: one of 16 fixed viewpoints (a Fibonacci lattice on a sphere of radius 3, the
distance of the preprocessing's viewpoints; the one chosen per object by a seed), visibility by
hidden point removal (:mod:`shapebench.geometry.hidden_points`), then the same stored
farthest-point order as ``crop``.
"""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

import numpy as np

from shapebench.api.errors import describe, warn_corrupt
from shapebench.api.protocol import Protocol
from shapebench.api.types import Context, ObjectData
from shapebench.geometry.hidden_points import visible_from
from shapebench.hashing import array_digest, stable_seed
from shapebench.preprocess.visibility import fibonacci_viewpoints

CONTEXTS_VERSION = "contexts-v1"

#: ShapeNet-55's 8 crop viewpoints: the corners of the cube, as unit vectors.
CROP_VIEWPOINTS = np.array(
    [[x, y, z] for x in (1, -1) for y in (1, -1) for z in (1, -1)], dtype=np.float64
) / np.sqrt(3.0)


def crop_viewpoint(fingerprint: str, object_id: str) -> int:
    """Which of :data:`CROP_VIEWPOINTS` crops the object (the same for every method and size)."""
    rng = np.random.default_rng(stable_seed(CONTEXTS_VERSION, "crop-view", fingerprint, object_id))
    return int(rng.integers(len(CROP_VIEWPOINTS)))


#: The 16 cameras of ``--protocol depth`` (Projected-ShapeNet renders 16 views per object), on
#: a sphere of radius 3 around the unit-radius object, like the preprocessing's viewpoints.
DEPTH_VIEWPOINTS = fibonacci_viewpoints(16, 3.0)


def depth_viewpoint(fingerprint: str, object_id: str) -> int:
    """Which of :data:`DEPTH_VIEWPOINTS` scans the object (the same for every method and size)."""
    rng = np.random.default_rng(stable_seed(CONTEXTS_VERSION, "depth-view", fingerprint, object_id))
    return int(rng.integers(len(DEPTH_VIEWPOINTS)))


def crop_keep(points: np.ndarray, viewpoint: np.ndarray, fraction: float) -> np.ndarray:
    """Indices of ``points`` left when the ``fraction`` of them nearest ``viewpoint`` is removed
    (ShapeNet-55's partial shapes), nearest kept first; ties broken by index."""
    distance = np.linalg.norm(np.asarray(points, dtype=np.float64) - viewpoint, axis=1)
    order = np.argsort(distance, kind="stable")
    return order[int(fraction * len(points)) :]


def farthest_point_order(points: np.ndarray, k: int, start: int) -> np.ndarray:
    """The first ``k`` indices of the farthest-point order of ``points`` from index ``start``:
    each next point is the one farthest from those already taken (ties: the lowest index)."""
    pts = np.asarray(points, dtype=np.float64)
    k = min(k, len(pts))
    order = np.empty(k, dtype=np.int64)
    order[0] = start
    nearest = np.sum((pts - pts[start]) ** 2, axis=1)
    for i in range(1, k):
        order[i] = int(np.argmax(nearest))
        np.minimum(nearest, np.sum((pts - pts[order[i]]) ** 2, axis=1), out=nearest)
    return order


def context_order(fingerprint: str, object_id: str, n_visible: int) -> np.ndarray:
    rng = np.random.default_rng(stable_seed(CONTEXTS_VERSION, fingerprint, object_id))
    return rng.permutation(n_visible)


class ContextStore:
    """Reads and writes the per-object context order under a dataset's cache root."""

    def __init__(self, root: Path, fingerprint: str) -> None:
        self.root = Path(root) / CONTEXTS_VERSION
        self.fingerprint = fingerprint

    def path(self, data: ObjectData) -> Path:
        """Where the object's order is stored."""
        return self.root / (data.ref.id.replace("/", "__") + ".npy")

    def order(self, data: ObjectData) -> np.ndarray:
        """The object's stored order, drawn and stored on first use.

        A stored order that cannot be read, or is not a permutation of the visible points
        (truncated, garbled), is reported in one line naming the file and drawn again: the
        draw is deterministic, so the new order is the one that was lost.
        """
        path = self.path(data)
        n = len(data.surface_points)
        order = _read_order(path, n)
        if order is None:
            order = context_order(self.fingerprint, data.ref.id, n)
            _save_atomic(path, order)
        return order

    def partial_points(self, data: ObjectData, protocol: Protocol) -> np.ndarray:
        """Indices into ``data.gt_points`` of the partial cloud a ``crop`` or ``depth`` context
        is sampled from (what a crop leaves; what the camera sees)."""
        if protocol.context == "depth":
            view = DEPTH_VIEWPOINTS[depth_viewpoint(self.fingerprint, data.ref.id)]
            return visible_from(data.gt_points, view)
        view = CROP_VIEWPOINTS[crop_viewpoint(self.fingerprint, data.ref.id)]
        return crop_keep(data.gt_points, view, protocol.crop_fraction)

    def crop_order(self, data: ObjectData, fraction: float, size: int) -> np.ndarray:
        """Indices into ``data.gt_points`` of the crop context of ``size`` points (the stored
        farthest-point order, extended and stored again when a larger size is asked for)."""
        return self.partial_order(data, Protocol(context="crop", crop_fraction=fraction), size)

    def partial_order(self, data: ObjectData, protocol: Protocol, size: int) -> np.ndarray:
        """Indices into ``data.gt_points`` of the ``crop`` or ``depth`` context of ``size``
        points (the stored farthest-point order of the partial cloud, extended and stored again
        when a larger size is asked for)."""
        n = len(data.gt_points)
        keep = self.partial_points(data, protocol)
        if size > len(keep):
            if protocol.context == "depth":
                why = f"points of {n} ground-truth points visible from the depth camera"
            else:
                why = f"points left of {n} ground-truth points after cropping "
                why += f"{protocol.crop_fraction:g}"
            raise ValueError(f"context size {size} exceeds the {len(keep)} {why}")
        folder = "depth" if protocol.context == "depth" else f"crop-{protocol.crop_fraction:g}"
        path = self.root / folder / (data.ref.id.replace("/", "__") + ".npy")
        stored = _read_order(path, len(keep), prefix_problem, f"the {protocol.context} order")
        if stored is None or len(stored) < size:
            rng = np.random.default_rng(
                stable_seed(
                    CONTEXTS_VERSION, f"{protocol.context}-start", self.fingerprint, data.ref.id
                )
            )
            start = int(rng.integers(len(keep)))
            stored = farthest_point_order(data.gt_points[keep], size, start)
            _save_atomic(path, stored)
        return keep[stored[:size]]

    def noise(self, data: ObjectData, source: str, sd: float) -> np.ndarray:
        """Seeded Gaussian noise of standard deviation ``sd``, one row per point of the source
        cloud (``surface`` or ``gt``): a point's noise does not depend on the context size."""
        n = len(data.surface_points if source == "surface" else data.gt_points)
        rng = np.random.default_rng(
            stable_seed(CONTEXTS_VERSION, "noise", source, self.fingerprint, data.ref.id)
        )
        return sd * rng.standard_normal((n, 3))

    def context(
        self,
        data: ObjectData,
        size: int,
        run_seed: int,
        normals: bool = False,
        protocol: Protocol | None = None,
    ) -> Context:
        """The context of ``size`` points under ``protocol`` (default: the paper's sparse one):
        the first ``size`` points of the object's stored order, with their normals only when the
        protocol gives methods normals."""
        protocol = protocol or Protocol(context_normals=normals)
        normals = normals or protocol.context_normals
        seed = stable_seed("method", self.fingerprint, data.ref.id, size, run_seed)
        if protocol.context in ("crop", "depth"):
            idx = self.partial_order(data, protocol, size)
            points, source = data.gt_points[idx], "gt"
            point_normals = None
        else:
            n = len(data.surface_points)
            if size > n:
                raise ValueError(f"context size {size} exceeds the {n} visible points")
            idx = self.order(data)[:size]
            points, source = data.surface_points[idx], "surface"
            point_normals = data.surface_normals[idx] if normals else None
        if protocol.context_noise:
            noisy = points + self.noise(data, source, protocol.context_noise)[idx]
            points = noisy.astype(points.dtype)
        return Context(ref=data.ref, points=points, normals=point_normals, seed=seed)


def order_problem(order: np.ndarray, n: int) -> str | None:
    """Why ``order`` is not a valid context order for ``n`` visible points, or None."""
    if order.ndim != 1 or not np.issubdtype(order.dtype, np.integer):
        return f"holds a {order.dtype} array of shape {order.shape}, not a list of indices"
    if len(order) != n:
        return f"holds {len(order)} indices for {n} visible points"
    # Every index exactly once: a garbled entry would repeat a point and drop another.
    if not np.array_equal(np.sort(order), np.arange(n)):
        return f"is not a permutation of the {n} visible points"
    return None


def prefix_problem(order: np.ndarray, n: int) -> str | None:
    """Why ``order`` is not a stored farthest-point order (distinct indices below ``n``)."""
    ok = order.ndim == 1 and np.issubdtype(order.dtype, np.integer) and len(order) > 0
    if ok and order.min() >= 0 and order.max() < n and len(np.unique(order)) == len(order):
        return None
    return f"is not a list of distinct indices below {n}"


def _read_order(
    path: Path, n: int, problem_of=order_problem, what: str = "the context order"
) -> np.ndarray | None:
    """The valid order stored at ``path`` (``problem_of`` says what valid is); None when there
    is none (a damaged file is reported and deleted, so the caller draws and stores the order
    again)."""
    try:
        order = np.load(path, allow_pickle=False)
    except FileNotFoundError:
        return None
    except Exception as exc:  # truncated: ValueError/EOFError from numpy's reader
        problem = describe(exc)
    else:
        problem = problem_of(order, n)
        if problem is None:
            return order
    warn_corrupt(path, problem, f"drawing {what} again (the draw is deterministic)")
    path.unlink(missing_ok=True)
    return None


def _save_atomic(path: Path, order: np.ndarray) -> None:
    """Write ``order`` so that readers never see a partial file: a temporary file of its own
    (two processes may store the same object at once), flushed to disk, then renamed."""
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, suffix=".tmp.npy")
    try:
        with os.fdopen(fd, "wb") as f:
            np.save(f, order)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)


def contexts_digest(contexts: list[Context]) -> str:
    """SHA-256 over every context of a cell, in order: equal digests mean equal inputs."""
    return array_digest(*[c.points for c in contexts])
