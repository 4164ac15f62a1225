"""The index of the training shapes that ``retrieval`` searches, and the search itself.

The index is self-contained: it needs neither the dataset nor its cache once built, so a
workspace (or the index's folder alone) can be moved, copied to another machine or cluster node,
and still serve. It is two files in the training's folder (the method's checkpoint):

* ``index.npz``: per training object, in the order of the dataset's ``train`` split, its id and
  category, ``index_points`` points of its ground truth for the search (a subsample seeded by
  the object's id alone: no trainer setting changes an index), where its ground truth lies in
  the clouds file and that slice's digest; and ``meta``, what the index was built from and with
  (checked on load);
* ``clouds-<digest>.bin``: every training object's whole ground truth, one after the other,
  each coordinate 16-bit fixed point in the object's own bounding box (error at most 1/131,070
  of the box's side: 1.5e-5 on the unit frame's [-1, 1], where float16 would round by up to
  2.4e-4), raw little-endian ``int16`` that a load maps into memory rather than reads: a
  retrieval reads one shape's 180 kB. The standard profile's 2,200 shapes of 30,000 points take
  396 MB (float32 would take 792). The file's name holds the digest of its bytes, so an index
  never meets the clouds of another build.

The search is exact: the training shape with the lowest one-sided Chamfer (the mean over the
context points of the squared distance to the nearest index point of the shape), the lowest
index among equal scores. One KD-tree per training shape (built once per process) answers the
nearest-point queries. The context's points are queried in stages (16 on every shape, then 32,
64, ... more), and a shape is dropped as soon as a lower bound of its sum exceeds the best
complete sum: the distances at the points queried so far, and at every other point the distance
of its nearest queried point less the gap between the two (the distance to a set is
1-Lipschitz). Most shapes cost one query of 16 points (docs/methods.md has the costs).
"""

from __future__ import annotations

import hashlib
import json
import os
import sys
import tempfile
import time
from collections import OrderedDict
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from scipy.spatial import cKDTree

from shapebench.api.dataset import Dataset, ObjectLoadError
from shapebench.api.errors import ShapebenchError
from shapebench.api.types import TRAIN
from shapebench.geometry.nearest import kdtree, nearest_distances
from shapebench.hashing import array_digest, stable_seed

#: The index file's format; a file of another format (the cache-referencing format 1 included)
#: is refused, not misread.
FORMAT = "shapebench-retrieval-index-2"
#: The clouds' storage: int16 fixed point in each shape's bounding box, little-endian.
CLOUD_DTYPE = np.dtype("<i2")
#: Fixed-point levels over a box's side (int16's range).
LEVELS = 65535
#: Context points queried on every shape first; each later stage queries twice as many more.
FIRST_CHUNK = 16
#: A lower bound must exceed the best sum by this factor to drop a shape: rounding (the sums are
#: added in other orders) can never make a bound overtake the exact sum it bounds.
BOUND_MARGIN = 1.0 + 1e-9
#: Retrieved ground truths kept in memory (a context size's cell often retrieves a shape again).
CLOUDS_KEPT = 16
#: The index file (the checkpoint's path) in the training's folder.
INDEX_FILE = "index.npz"
#: What a delete-and-rebuild message tells the user.
REBUILD = "delete {folder} and run again: the index is built again from the training data"


def _digest(array: np.ndarray) -> str:
    return array_digest(np.ascontiguousarray(array))[:32]


def quantize(points: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``points`` as int16 fixed point in their bounding box: ``(codes, low, step)`` with
    ``points ~ (codes + 32768) * step + low`` to within ``step / 2``."""
    p = np.asarray(points, dtype=np.float64)
    low = p.min(axis=0)
    span = p.max(axis=0) - low
    step = np.where(span > 0, span / LEVELS, 1.0)  # a flat axis: every code 0, any step
    codes = np.rint((p - low) / step) - 32768
    return np.clip(codes, -32768, 32767).astype(CLOUD_DTYPE), low, step


def dequantize(codes: np.ndarray, low: np.ndarray, step: np.ndarray) -> np.ndarray:
    """The float32 points of :func:`quantize`'s codes."""
    return ((np.asarray(codes, dtype=np.float64) + 32768.0) * step + low).astype(np.float32)


@dataclass(frozen=True)
class Built:
    """What :func:`write_index` wrote: the index file and what building it cost."""

    path: Path
    shapes: int
    skipped: list[str]
    seconds: float


def training_shapes(dataset: Dataset, skipped: list[str]) -> Iterator[tuple[str, str, np.ndarray]]:
    """``(id, category, ground truth)`` of each object of ``dataset``'s ``train`` split that
    loads with a finite ``(n, 3)`` ground truth; the others are appended to ``skipped``."""
    for ref in dataset.objects(TRAIN):
        try:  # the ground truth alone: a mesh dataset skips the visible points' ray casting
            gt = np.asarray(dataset.ground_truth_points(ref))
        except ObjectLoadError as exc:
            skipped.append(f"{ref.id}: {exc}")
            continue
        if gt.ndim != 2 or gt.shape[1] != 3 or not len(gt) or not np.isfinite(gt).all():
            skipped.append(f"{ref.id}: no finite (n, 3) ground truth")
            continue
        yield ref.id, ref.category, gt


def build_index(dataset: Dataset, index_points: int, folder: Path, quiet: bool) -> Built:
    """Index ``dataset``'s ``train`` split into ``folder`` (see the module docstring)."""
    start = time.perf_counter()
    skipped: list[str] = []
    meta = {"dataset": dataset.name, "training_fingerprint": dataset.training_fingerprint()}
    if not quiet:  # a fresh cache reads every ground truth first: ~70 s of CPU at 2,200 shapes
        print(
            f"retrieval: indexing the {len(dataset.objects(TRAIN))} training shapes of "
            f"{dataset.name} (reading the ground truth of those not in the cache yet)",
            file=sys.stderr,
            flush=True,
        )
    built = write_index(training_shapes(dataset, skipped), index_points, folder, meta)
    seconds = time.perf_counter() - start
    if not built.shapes:
        raise ShapebenchError(
            f"dataset {dataset.name!r} has no training object with a ground truth to retrieve"
            + (f" ({len(skipped)} failed to load; first: {skipped[0]})" if skipped else ""),
            "retrieval returns training shapes: use a dataset with training objects",
        )
    if not quiet:
        print(
            f"retrieval: indexed {built.shapes} training shapes (up to {index_points} points "
            f"each) in {seconds:.1f} s"
            + (f"; skipped {len(skipped)}: {skipped[0]}" if skipped else ""),
            file=sys.stderr,
        )
    return Built(built.path, built.shapes, skipped, seconds)


def write_index(
    shapes: Iterable[tuple[str, str, np.ndarray]],
    index_points: int,
    folder: Path,
    meta: dict[str, Any] | None = None,
) -> Built:
    """Write the index of ``shapes`` (``(id, category, ground truth)``) to ``folder``: the clouds
    file as the shapes come (one shape in memory at a time, besides the index points), then
    ``index.npz``, each atomically; a clouds file of an earlier build is removed last. No shape:
    nothing is written (``shapes`` of the result is 0). ``meta`` is recorded with the index's own
    (what :meth:`RetrievalIndex.load` checks)."""
    if index_points < 1:
        raise ShapebenchError(f"index_points must be positive, got {index_points}")
    start = time.perf_counter()
    folder.mkdir(parents=True, exist_ok=True)
    ids, categories, digests, lows, steps, sizes, search = [], [], [], [], [], [], []
    fd, tmp = tempfile.mkstemp(dir=folder, suffix=".tmp.bin")
    whole = hashlib.sha256()
    try:
        with os.fdopen(fd, "wb") as f:
            for object_id, category, gt in shapes:
                codes, low, step = quantize(gt)
                points = dequantize(codes, low, step)  # the search sees what is returned
                rng = np.random.default_rng(stable_seed("retrieval-index", object_id))
                keep = rng.choice(len(points), size=min(index_points, len(points)), replace=False)
                data = codes.tobytes()
                f.write(data)
                whole.update(data)
                ids.append(object_id)
                categories.append(category)
                digests.append(_digest(codes))
                lows.append(low)
                steps.append(step)
                sizes.append(len(codes))
                search.append(points[np.sort(keep)])
            f.flush()
            os.fsync(f.fileno())
        if not ids:
            return Built(folder / INDEX_FILE, 0, [], time.perf_counter() - start)
        clouds = folder / f"clouds-{whole.hexdigest()[:16]}.bin"
        _readable(tmp)
        os.replace(tmp, clouds)
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)
    offsets = _offsets(sizes)
    info = {
        **(meta or {}),
        "index_points": index_points,
        "shapes": len(ids),
        "clouds": clouds.name,
        "cloud_points": int(offsets[-1]),
        "cloud_dtype": CLOUD_DTYPE.str,
    }
    arrays = {
        "format": np.array(FORMAT),
        "meta": np.array(json.dumps(info, sort_keys=True)),
        "ids": np.array(ids),
        "categories": np.array(categories),
        "digests": np.array(digests),
        "low": np.array(lows, dtype=np.float64).reshape(-1, 3),
        "step": np.array(steps, dtype=np.float64).reshape(-1, 3),
        "cloud_offsets": offsets,
        "search": np.concatenate(search).astype(np.float32),
        "search_offsets": _offsets([len(s) for s in search]),
    }
    path = _save_npz(folder / INDEX_FILE, arrays)
    for old in folder.glob("clouds-*.bin"):  # an earlier build's: no index names it any more
        if old.name != clouds.name:
            old.unlink(missing_ok=True)
    return Built(path, len(ids), [], time.perf_counter() - start)


def _offsets(sizes: list[int]) -> np.ndarray:
    return np.concatenate([[0], np.cumsum(sizes, dtype=np.int64)]).astype(np.int64)


def _save_npz(path: Path, arrays: dict[str, Any]) -> Path:
    """Write ``arrays`` to ``path`` atomically (a killed build leaves no half-written file)."""
    fd, tmp = tempfile.mkstemp(dir=path.parent, suffix=".tmp.npz")
    try:
        with os.fdopen(fd, "wb") as f:
            np.savez(f, **arrays)
            f.flush()
            os.fsync(f.fileno())
        _readable(tmp)
        os.replace(tmp, path)
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)
    return path


def _readable(path: str) -> None:
    """The permissions a plain ``open`` would give (``mkstemp`` makes files only their owner
    may read): a shared workspace's other users load the index too."""
    umask = os.umask(0)
    os.umask(umask)
    os.chmod(path, 0o666 & ~umask)


#: The arrays of ``index.npz`` besides ``format`` and ``meta``, and how many rows each has
#: (``n``: one per shape; ``n+1``: offsets).
_ARRAYS = {
    "ids": "n",
    "categories": "n",
    "digests": "n",
    "low": "n",
    "step": "n",
    "cloud_offsets": "n+1",
    "search_offsets": "n+1",
    "search": None,
}


class RetrievalIndex:
    """A loaded index: :meth:`nearest` searches it, :meth:`cloud` returns a shape's ground
    truth."""

    def __init__(self, arrays: dict[str, np.ndarray], clouds: np.ndarray, path: Path) -> None:
        self.path = path
        self.meta: dict[str, Any] = json.loads(str(arrays["meta"]))
        self.ids = [str(i) for i in arrays["ids"]]
        self.categories = [str(c) for c in arrays["categories"]]
        self.digests = [str(d) for d in arrays["digests"]]
        self._low, self._step = arrays["low"], arrays["step"]
        self._offsets = arrays["cloud_offsets"]
        self._codes = clouds
        search, so = arrays["search"], arrays["search_offsets"]
        # One tree per training shape, on float64 copies of its index points.
        self.trees = [kdtree(search[so[i] : so[i + 1]]) for i in range(len(self.ids))]
        self._clouds: OrderedDict[int, np.ndarray] = OrderedDict()

    @classmethod
    def load(cls, path: Path, index_points: int | None = None) -> RetrievalIndex:
        """The index at ``path``, checked before any search: its format, its arrays' sizes
        against each other and its ``meta``, the clouds file beside it (present, of the size
        ``meta`` says), and, given ``index_points`` (the method's option), that it was built
        with that many. Anything else is one :class:`ShapebenchError` saying what to do."""
        path = Path(path)
        rebuild = REBUILD.format(folder=path.parent)
        try:
            with open(path, "rb") as f, np.load(f, allow_pickle=False) as z:
                arrays = {k: z[k] for k in z.files}
        except Exception as exc:
            raise ShapebenchError(
                f"{path} is not a retrieval index ({type(exc).__name__}: {exc})", rebuild
            ) from exc
        found = str(arrays.get("format", ""))
        if found != FORMAT:
            raise ShapebenchError(
                f"{path} is not a retrieval index of format {FORMAT!r} (it is {found!r})", rebuild
            )
        problem = _problem(arrays, index_points)
        if problem:
            raise ShapebenchError(f"the retrieval index {path} {problem}", rebuild)
        meta = json.loads(str(arrays["meta"]))
        clouds = path.parent / meta["clouds"]
        expected = meta["cloud_points"] * 3 * CLOUD_DTYPE.itemsize
        size = clouds.stat().st_size if clouds.is_file() else None
        if size != expected:
            state = "is missing" if size is None else f"has {size} bytes, not {expected}"
            raise ShapebenchError(
                f"the retrieval index {path} keeps the ground truths of its training shapes in "
                f"{clouds.name} beside it, which {state} (the folder was copied in part?)",
                rebuild,
            )
        codes = np.memmap(clouds, dtype=CLOUD_DTYPE, mode="r", shape=(meta["cloud_points"], 3))
        return cls(arrays, codes, path)

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
        """The whole ground truth of training shape ``i`` (float32, as stored: within 1.5e-5 of
        the dataset's on the unit frame), checked against the digest taken at indexing."""
        if i in self._clouds:
            self._clouds.move_to_end(i)
            return self._clouds[i]
        codes = np.asarray(self._codes[self._offsets[i] : self._offsets[i + 1]])
        if _digest(codes) != self.digests[i]:
            raise RuntimeError(
                f"the clouds file of {self.path} no longer holds training shape {self.ids[i]} as "
                f"indexed; {REBUILD.format(folder=self.path.parent)}"
            )
        gt = dequantize(codes, self._low[i], self._step[i])
        self._clouds[i] = gt
        while len(self._clouds) > CLOUDS_KEPT:
            self._clouds.popitem(last=False)
        return gt


def _problem(arrays: dict[str, np.ndarray], index_points: int | None) -> str | None:
    """What is wrong with the arrays of an ``index.npz`` (their sizes, ``meta``), or None."""
    missing = [k for k in ("meta", *_ARRAYS) if k not in arrays]
    if missing:
        return f"lacks the arrays {', '.join(missing)}"
    try:
        meta = json.loads(str(arrays["meta"]))
        n, points = int(meta["shapes"]), int(meta["cloud_points"])
        built_with = int(meta["index_points"])
        named = str(meta["clouds"])
        dtype = str(meta["cloud_dtype"])
    except (ValueError, KeyError, TypeError) as exc:
        return f"has an unreadable meta ({type(exc).__name__}: {exc})"
    if dtype != CLOUD_DTYPE.str or Path(named).name != named or not named.startswith("clouds-"):
        return f"names clouds {named!r} of dtype {dtype!r}, not this version's"
    for name, rows in _ARRAYS.items():
        if rows and len(arrays[name]) != (n if rows == "n" else n + 1):
            return f"has {len(arrays[name])} rows of {name!r} for {n} shapes"
    if int(arrays["cloud_offsets"][-1]) != points or np.any(np.diff(arrays["cloud_offsets"]) < 1):
        return f"has cloud offsets that do not add up to its {points} points"
    if int(arrays["search_offsets"][-1]) != len(arrays["search"]):
        return "has search offsets that do not match its index points"
    if index_points is not None and built_with != index_points:
        return f"was built with index_points={built_with}, and the method has {index_points}"
    return None
