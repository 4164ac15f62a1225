"""The index of the training shapes that ``retrieval`` searches, and the search itself.

The index (one ``.npz`` file, the method's checkpoint) holds, per training object in the order of
the dataset's ``train`` split: its id and category, ``index_points`` points of its ground truth
(a subsample seeded by the trainer seed and the object's id) for the search, and where its whole
ground truth is read back when it is retrieved: the dataset's cached arrays of that object
(``Dataset.cache_path``; checked against the digest of the cloud taken at indexing), or, for a
dataset that keeps no such file, the cloud itself in the index. Referencing the cache keeps the
index small (2,200 shapes of 2,048 points: 54 MB) where copying 30,000-point ground truths would
take 790 MB per seed.

The search is exact: the training shape with the lowest one-sided Chamfer (the mean over the
context points of the squared distance to the nearest index point of the shape), the lowest
index among equal scores. One KD-tree per training shape (built once per process) answers the
nearest-point queries. The context's points are queried in stages (16 on every shape, then 32,
64, ... more), and a shape is dropped as soon as a lower bound of its sum exceeds the best
complete sum: the distances at the points queried so far, and at every other point the distance
of its nearest queried point less the gap between the two (the distance to a set is
1-Lipschitz). Most shapes cost one query of 16 points: on the standard profile's 2,200 shapes,
about 0.1 to 0.25 s of CPU per object (docs/methods.md).
"""

from __future__ import annotations

import json
import os
import sys
import tempfile
import time
from collections import OrderedDict
from pathlib import Path
from typing import Any

import numpy as np
from scipy.spatial import cKDTree

from shapebench.api.dataset import Dataset, ObjectLoadError
from shapebench.api.errors import ShapebenchError
from shapebench.api.types import TRAIN
from shapebench.geometry.nearest import kdtree, nearest_distances
from shapebench.hashing import array_digest, stable_seed

#: The index file's format; a file of another format is refused, not misread.
FORMAT = "shapebench-retrieval-index-1"
#: Context points queried on every shape first; each later stage queries twice as many more.
FIRST_CHUNK = 16
#: A lower bound must exceed the best sum by this factor to drop a shape: rounding (the sums are
#: added in other orders) can never make a bound overtake the exact sum it bounds.
BOUND_MARGIN = 1.0 + 1e-9
#: Retrieved ground truths kept in memory (a context size's cell often retrieves a shape again).
CLOUDS_KEPT = 16


def _digest(points: np.ndarray) -> str:
    return array_digest(np.ascontiguousarray(points))[:32]


def _read_gt(path: str) -> np.ndarray:
    with open(path, "rb") as f, np.load(f, allow_pickle=False) as z:
        return z["gt_points"]


def _cached_gt_matches(path: Path, digest: str) -> bool:
    """Whether ``path`` (the dataset's cache file of an object) holds the ground truth whose
    digest is ``digest``: then the index refers to it instead of copying it."""
    try:
        return _digest(_read_gt(str(path))) == digest
    except Exception:  # no such file, no gt_points in it, not an npz: copy the cloud instead
        return False


def build_index(dataset: Dataset, index_points: int, seed: int, quiet: bool) -> dict[str, Any]:
    """The index arrays of ``dataset``'s ``train`` split (see the module docstring)."""
    if index_points < 1:
        raise ShapebenchError(f"index_points must be positive, got {index_points}")
    start = time.perf_counter()
    refs = dataset.objects(TRAIN)
    ids, categories, sources, digests, sizes = [], [], [], [], []
    search, embedded = [], []
    skipped: list[str] = []
    for ref in refs:
        try:
            data = dataset.load(ref)
        except ObjectLoadError as exc:
            skipped.append(f"{ref.id}: {exc}")
            continue
        gt = np.asarray(data.gt_points)
        if gt.ndim != 2 or gt.shape[1] != 3 or not len(gt) or not np.isfinite(gt).all():
            skipped.append(f"{ref.id}: no finite (n, 3) ground truth")
            continue
        rng = np.random.default_rng(stable_seed("retrieval-index", seed, ref.id))
        keep = np.sort(rng.choice(len(gt), size=min(index_points, len(gt)), replace=False))
        digest = _digest(gt)
        cache = dataset.cache_path(ref)
        referenced = _cached_gt_matches(cache, digest)
        ids.append(ref.id)
        categories.append(ref.category)
        sources.append(str(Path(cache).resolve()) if referenced else "")
        digests.append(digest)
        sizes.append(len(gt))
        search.append(gt[keep].astype(np.float32))
        embedded.append(np.empty((0, 3), np.float32) if referenced else gt.astype(np.float32))
    if not ids:
        raise ShapebenchError(
            f"dataset {dataset.name!r} has no training object with a ground truth to retrieve"
            + (f" ({len(skipped)} failed to load; first: {skipped[0]})" if skipped else ""),
            "retrieval returns training shapes: use a dataset with training objects",
        )
    if not quiet:
        copied = sum(1 for s in sources if not s)
        print(
            f"retrieval: indexed {len(ids)} training shapes (up to {index_points} points each"
            + (f", {copied} ground truths copied into the index" if copied else "")
            + f") in {time.perf_counter() - start:.1f} s"
            + (f"; skipped {len(skipped)}: {skipped[0]}" if skipped else ""),
            file=sys.stderr,
        )
    return {
        "format": np.array(FORMAT),
        "meta": np.array(json.dumps({"index_points": index_points, "seed": seed})),
        "ids": np.array(ids),
        "categories": np.array(categories),
        "sources": np.array(sources),
        "digests": np.array(digests),
        "sizes": np.array(sizes, dtype=np.int64),
        "search": np.concatenate(search),
        "search_offsets": _offsets(search),
        "embedded": np.concatenate(embedded),
        "embedded_offsets": _offsets(embedded),
    }


def _offsets(clouds: list[np.ndarray]) -> np.ndarray:
    return np.concatenate([[0], np.cumsum([len(c) for c in clouds])]).astype(np.int64)


def save_index(path: Path, arrays: dict[str, Any]) -> Path:
    """Write the index to ``path`` atomically (a killed training leaves no half-written file)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, suffix=".tmp.npz")
    try:
        with os.fdopen(fd, "wb") as f:
            np.savez(f, **arrays)
        os.replace(tmp, path)
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)
    return path


class RetrievalIndex:
    """A loaded index: :meth:`nearest` searches it, :meth:`cloud` reads a shape's ground truth."""

    def __init__(self, arrays: dict[str, np.ndarray], path: Path) -> None:
        self.path = path
        self.ids = [str(i) for i in arrays["ids"]]
        self.categories = [str(c) for c in arrays["categories"]]
        self.sources = [str(s) for s in arrays["sources"]]
        self.digests = [str(d) for d in arrays["digests"]]
        self.sizes = arrays["sizes"]
        search, so = arrays["search"], arrays["search_offsets"]
        self._embedded, self._eo = arrays["embedded"], arrays["embedded_offsets"]
        # One tree per training shape, on float64 copies of its index points.
        self.trees = [kdtree(search[so[i] : so[i + 1]]) for i in range(len(self.ids))]
        self._clouds: OrderedDict[int, np.ndarray] = OrderedDict()

    @classmethod
    def load(cls, path: Path) -> RetrievalIndex:
        """The index at ``path``; a file of another format, or one whose referenced cache files
        are gone, is refused with a message saying what to do."""
        try:
            with open(path, "rb") as f, np.load(f, allow_pickle=False) as z:
                arrays = {k: z[k] for k in z.files}
        except Exception as exc:
            raise ShapebenchError(
                f"{path} is not a retrieval index ({type(exc).__name__}: {exc})"
            ) from exc
        if str(arrays.get("format", "")) != FORMAT:
            raise ShapebenchError(f"{path} is not a retrieval index of format {FORMAT!r}")
        missing = [s for s in arrays["sources"] if str(s) and not os.path.exists(str(s))]
        if missing:
            raise ShapebenchError(
                f"the retrieval index {path} reads the ground truth of its training shapes from "
                f"the dataset's cache, and {len(missing)} of those files are gone "
                f"(first: {missing[0]})",
                f"delete {Path(path).parent} and run again: the index is built again",
            )
        return cls(arrays, Path(path))

    def __len__(self) -> int:
        return len(self.ids)

    def nearest(self, points: np.ndarray) -> tuple[int, float, int]:
        """The index of the training shape nearest to ``points`` (one-sided Chamfer: the mean
        squared distance from each point to the shape's nearest index point; the lowest index
        among equal scores), that score, and how many shapes were searched to the end.

        Exact, with pruning: the context's points are queried in stages (the first
        :data:`FIRST_CHUNK`, then twice as many more at each stage). After a stage, a shape's
        distances at the points queried so far bound those at the others from below (the
        distance to a set moves no faster than the point: ``d(p) >= d(p') - |p - p'|`` for the
        nearest queried ``p'``), so its sum is bounded from below; a shape whose bound exceeds
        the best complete sum is dropped. Shapes are visited in the order of their first bound.
        """
        q = np.ascontiguousarray(points, dtype=np.float64)
        k = len(q)
        if k == 0:
            raise ValueError("an empty context has no nearest training shape")
        ends = [0]
        size = FIRST_CHUNK
        while ends[-1] < k:
            ends.append(min(k, ends[-1] + size))
            size *= 2
        # After stage j (the first ends[j] points queried): each later point's nearest queried
        # point and its distance, shared by every shape.
        reach = {}
        for end in ends[1:-1]:
            gap, nearest = cKDTree(q[:end]).query(q[end:], k=1)
            reach[end] = (nearest, gap)

        def bound(dist: np.ndarray) -> np.ndarray:
            """The lower bound of the sum over all points, from the first distances (the last
            axis); the exact sum once every point is queried."""
            known = np.sum(dist**2, axis=-1)
            if dist.shape[-1] == k:
                return known
            nearest, gap = reach[dist.shape[-1]]
            return known + np.sum(np.maximum(dist[..., nearest] - gap, 0.0) ** 2, axis=-1)

        def query(i: int, a: int, b: int) -> np.ndarray:
            return nearest_distances(q[a:b], None, tree=self.trees[i])

        first = np.stack([query(i, 0, ends[1]) for i in range(len(self.trees))])
        bounds = bound(first)
        best, best_sum, finished = -1, np.inf, 0
        # The bounds hold up to rounding, far below this margin.
        for i in np.lexsort((np.arange(len(bounds)), bounds)):
            if bounds[i] > best_sum * BOUND_MARGIN:  # this shape and every later one: beaten
                break
            dist = first[i]
            for a, b in zip(ends[1:-1], ends[2:], strict=True):
                dist = np.concatenate([dist, query(i, a, b)])
                if bound(dist) > best_sum * BOUND_MARGIN:
                    break
            if len(dist) < k:
                continue
            finished += 1
            total = float(np.sum(dist**2))
            if total < best_sum or (total == best_sum and i < best):
                best, best_sum = int(i), total
        return best, best_sum / k, finished

    def cloud(self, i: int) -> np.ndarray:
        """The whole ground truth of training shape ``i`` (float32), read from the dataset's
        cache or the index, and checked against the digest taken when the index was built."""
        if i in self._clouds:
            self._clouds.move_to_end(i)
            return self._clouds[i]
        a, b = self._eo[i], self._eo[i + 1]
        if b > a:
            gt = self._embedded[a:b]
        else:
            source = self.sources[i]
            try:
                gt = _read_gt(source)
            except Exception as exc:
                raise RuntimeError(
                    f"cannot read the ground truth of training shape {self.ids[i]} from {source} "
                    f"({type(exc).__name__}: {exc}); delete {self.path.parent} to index again"
                ) from exc
            if _digest(gt) != self.digests[i]:
                raise RuntimeError(
                    f"{source} no longer holds the ground truth of training shape "
                    f"{self.ids[i]} that was indexed; delete {self.path.parent} to index again"
                )
        gt = np.asarray(gt, dtype=np.float32)
        self._clouds[i] = gt
        while len(self._clouds) > CLOUDS_KEPT:
            self._clouds.popitem(last=False)
        return gt
