"""Time chamfer-l2 through shapebench's KD-tree path against the cKDTree path and a brute force.

    python benchmarks/bench_chamfer.py [--points 30000] [--repeat 3] [--brute-repeat N]
        [--threads N] [--seed 0]

Every object of every cell is scored with nearest-neighbour queries, so their cost bounds how
fast a sweep can go, and the claim in ``shapebench.geometry.nearest`` (exact distances in tens
of milliseconds for 30k x 30k points on a CPU) is what makes evaluating on 30k points affordable.
This script measures, on the same two clouds (ground truth: points on a bumpy sphere; prediction:
other points of the same surface plus noise):

* ``cKDTree, cold`` / ``cKDTree, GT tree cached``: the baseline, the path shapebench took before
  pykdtree, inlined here (scipy's cKDTree on float64 points, ``query(k=1, workers=...)``), with
  both trees built, or the ground truth's built once outside the timing;
* ``shapebench (BACKEND), cold``: ``ChamferL2().compute`` on fresh objects, building both trees
  (``BACKEND`` is ``shapebench.geometry.nearest.DEFAULT_BACKEND``: pykdtree when installed);
* ``shapebench (BACKEND), GT tree cached``: a new completion of an object whose GT tree is
  already in ``ObjectData.cache`` (the runner scores every context size of an object against
  one tree);
* ``brute force``: ``brute_force_nearest`` (chunked float64 ``torch.cdist`` on the CPU), the
  reference the tests use;
* ``cuda``: ``nearest_distances`` on CUDA tensors, only when ``torch.cuda.is_available()``.

The four KD-tree rows are timed in rounds (one run of each per round, after one untimed round),
so a change of load on the machine hits them alike. It prints each path's chamfer-l2 and its
relative difference from the brute force (they must agree: a fast wrong answer is no use), the
median time, the speed-up over brute force and over the cKDTree row of the same kind; then
whether shapebench's distances are bitwise identical to cKDTree's (they must be: committed
scores are reproduced with whichever is installed; the script exits with an error if not).

``--threads N`` (default: ``os.cpu_count()``, what ``workers=-1`` means) is the thread count of
both KD-trees: cKDTree's ``workers`` and pykdtree's OpenMP team, set through ``threadpoolctl``
on pykdtree's own OpenMP library (pykdtree has no per-call thread argument).
"""

from __future__ import annotations

import argparse
import contextlib
import os
import platform
import statistics
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass

import numpy as np
import torch
from scipy.spatial import cKDTree

from shapebench.api.types import Completion, Context, ObjectData, ObjectRef
from shapebench.geometry import nearest
from shapebench.geometry.nearest import as_numpy, brute_force_nearest, nearest_distances
from shapebench.metrics.chamfer import ChamferL2

REF = ObjectRef(id="bench", category="bench")


@dataclass
class Row:
    name: str
    #: the largest relative difference from the brute force that still counts as agreement
    tolerance: float
    value: float
    seconds: list[float]
    #: the row whose median this one is compared with in the "vs cKDTree" column
    baseline: Row | None = None

    @property
    def median(self) -> float:
        return statistics.median(self.seconds)


def bumpy_sphere(n: int, rng: np.random.Generator, noise: float = 0.0) -> np.ndarray:
    """``n`` random points on a sphere with smooth radial bumps, optionally with normal noise.

    A surface rather than a uniform box: KD-tree cost depends on how points cluster, and
    completions and ground truths are both surfaces.
    """
    d = rng.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    radius = 1.0 + 0.1 * np.sin(5 * d[:, 0]) * np.cos(3 * d[:, 1]) + 0.05 * d[:, 2] ** 3
    pts = d * radius[:, None] + rng.normal(scale=noise, size=(n, 3))
    pts /= np.linalg.norm(pts, axis=1).max()  # unit-sphere frame, as the datasets use
    return pts.astype(np.float32)


def make_object(gt: np.ndarray) -> ObjectData:
    return ObjectData(
        ref=REF, surface_points=gt[:1], surface_normals=np.zeros_like(gt[:1]), gt_points=gt
    )


def timed(fn: Callable[[], float], repeat: int, warmup: int = 0) -> tuple[float, list[float]]:
    """Run ``fn`` ``warmup`` times untimed, then ``repeat`` times; return its value and times."""
    (value, times), *_ = timed_rounds([fn], repeat, warmup)
    return value, times


def timed_rounds(
    fns: list[Callable[[], float]], repeat: int, warmup: int = 0
) -> list[tuple[float, list[float]]]:
    """Like :func:`timed` for several functions, run in turn in each round."""
    values, times = [float("nan")] * len(fns), [[] for _ in fns]
    for r in range(warmup + repeat):
        for i, fn in enumerate(fns):
            start = time.perf_counter()
            values[i] = fn()
            if r >= warmup:
                times[i].append(time.perf_counter() - start)
    return list(zip(values, times, strict=True))


@contextlib.contextmanager
def pykdtree_threads(threads: int) -> Iterator[str]:
    """Set pykdtree's OpenMP thread count for the block; yield a description of it."""
    if nearest.DEFAULT_BACKEND != "pykdtree":
        yield "pykdtree not installed"
        return
    try:
        from threadpoolctl import ThreadpoolController
    except ImportError:
        if threads != os.cpu_count():
            raise SystemExit("--threads needs threadpoolctl (or set OMP_NUM_THREADS)") from None
        env = os.environ.get("OMP_NUM_THREADS")
        yield f"pykdtree: OpenMP default (OMP_NUM_THREADS={env}), threadpoolctl not installed"
        return
    controller = ThreadpoolController()
    own = [c.filepath for c in controller.lib_controllers if "pykdtree" in c.filepath]
    chosen = controller.select(filepath=own) if own else controller.select(user_api="openmp")
    with chosen.limit(limits=threads):
        names = ", ".join(os.path.basename(i["filepath"]) for i in chosen.info())
        yield f"pykdtree: {threads} OpenMP threads ({names or 'no OpenMP library found'})"


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--points", type=int, default=30000, help="points in each cloud")
    parser.add_argument("--repeat", type=int, default=3, help="timed runs per path (median)")
    parser.add_argument(
        "--brute-repeat",
        type=int,
        default=None,
        help="timed runs of the brute force (default: --repeat; 0: skip it); ~10-20 s each at 30k "
        "on 2 cores",
    )
    parser.add_argument(
        "--threads",
        type=int,
        default=os.cpu_count() or 1,
        help="threads of both KD-trees (default: all cores, as workers=-1)",
    )
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)

    rng = np.random.default_rng(args.seed)
    gt = bumpy_sphere(args.points, rng)
    pred = bumpy_sphere(args.points, rng, noise=0.005)
    ctx = Context(ref=REF, points=gt[:1], normals=gt[:1], seed=0)
    metric = ChamferL2()
    backend = nearest.DEFAULT_BACKEND
    rows: list[Row] = []

    def ckdtree_chamfer(gt_tree: cKDTree | None = None) -> tuple[np.ndarray, np.ndarray]:
        """The distances of the path shapebench took before pykdtree (a cKDTree per set)."""
        g, p = as_numpy(gt), as_numpy(pred)
        g2p = cKDTree(p).query(g, k=1, workers=args.threads)[0]
        gt_tree = cKDTree(g) if gt_tree is None else gt_tree
        return g2p, gt_tree.query(p, k=1, workers=args.threads)[0]

    def value_of(g2p: np.ndarray, p2g: np.ndarray) -> float:
        return float(np.mean(g2p**2) + np.mean(p2g**2))  # as ChamferL2.compute

    ckdtree_gt = cKDTree(as_numpy(gt))
    shared = make_object(gt)
    metric.compute(Completion(points=pred), shared, ctx)  # builds shared.cache["gt_tree"]
    assert "gt_tree" in shared.cache

    def shapebench_cold() -> float:
        return metric.compute(Completion(points=pred), make_object(gt), ctx)

    def shapebench_cached() -> float:
        return metric.compute(Completion(points=pred), shared, ctx)

    with pykdtree_threads(args.threads) as thread_note:
        (cold, cached, sb_cold, sb_cached) = timed_rounds(
            [
                lambda: value_of(*ckdtree_chamfer()),
                lambda: value_of(*ckdtree_chamfer(ckdtree_gt)),
                shapebench_cold,
                shapebench_cached,
            ],
            args.repeat,
            warmup=1,
        )
        # The distances themselves, for the bitwise comparison.
        old = ckdtree_chamfer(ckdtree_gt)
        probe = Completion(points=pred)
        metric.compute(probe, make_object(gt), ctx)
        new = probe.cache["gt_to_pred"], probe.cache["pred_to_gt"]

    rows.append(Row("cKDTree, cold", 1e-9, *cold))
    rows.append(Row("cKDTree, GT tree cached", 1e-9, *cached))
    rows.append(Row(f"shapebench ({backend}), cold", 1e-9, *sb_cold, baseline=rows[0]))
    rows.append(Row(f"{backend}, GT tree cached", 1e-9, *sb_cached, baseline=rows[1]))
    rows[0].baseline, rows[1].baseline = rows[0], rows[1]

    def brute() -> float:
        g2p = brute_force_nearest(gt, pred)
        p2g = brute_force_nearest(pred, gt)
        return float(np.mean(g2p**2) + np.mean(p2g**2))

    brute_repeat = args.repeat if args.brute_repeat is None else args.brute_repeat
    reference = None  # --brute-repeat 0: no brute force, no column against it
    if brute_repeat > 0:
        rows.append(Row("brute force (cdist, cpu f64)", 0.0, *timed(brute, brute_repeat)))
        reference = rows[-1]

    if torch.cuda.is_available():
        gt_cuda, pred_cuda = torch.from_numpy(gt).cuda(), torch.from_numpy(pred).cuda()

        def cuda() -> float:
            g2p = nearest_distances(gt_cuda, pred_cuda)
            p2g = nearest_distances(pred_cuda, gt_cuda)
            return float((g2p.double() ** 2).mean() + (p2g.double() ** 2).mean())  # waits for it

        rows.append(Row("cuda (cdist f32)", 1e-3, *timed(cuda, args.repeat, warmup=1)))
        device = torch.cuda.get_device_name(0)
    else:
        device = "no CUDA device: cuda path skipped"

    print(
        f"chamfer-l2, {args.points} x {args.points} points, median of {args.repeat} "
        f"(brute force: {brute_repeat}); "
        f"{os.cpu_count()} CPU cores ({platform.processor() or platform.machine()}), "
        f"torch {torch.__version__} ({torch.get_num_threads()} threads); {device}"
    )
    print(f"KD-tree threads: cKDTree workers={args.threads}; {thread_note}")
    header = (
        f"{'path':<34} {'chamfer-l2':>14} {'rel. diff':>10} {'median s':>10} {'speed-up':>9}"
        f" {'vs cKDTree':>10}"
    )
    print(header)
    print("-" * len(header))
    disagree = []
    for row in rows:
        vs = f"{row.baseline.median / row.median:>9.2f}x" if row.baseline else f"{'-':>10}"
        if reference is None:
            rel, against = float("nan"), f"{'-':>10} {row.median:>10.4f} {'-':>9}"
        else:
            rel = abs(row.value - reference.value) / abs(reference.value)
            speedup = reference.median / row.median
            against = f"{rel:>10.1e} {row.median:>10.4f} {speedup:>8.1f}x"
        print(f"{row.name:<34} {row.value:>14.8e} {against} {vs}")
        if rel > row.tolerance:
            disagree.append(f"{row.name}: relative difference {rel:.1e} > {row.tolerance:g}")
    same = [np.array_equal(a, b) for a, b in zip(old, new, strict=True)]
    differ = sum(int((a != b).sum()) for a, b in zip(old, new, strict=True))
    print(
        f"shapebench ({backend}) distances bitwise identical to cKDTree's: "
        f"{'yes' if all(same) else 'NO'} ({differ} of {sum(len(a) for a in old)} differ); "
        f"chamfer-l2 {'equal' if rows[0].value == rows[2].value else 'DIFFERENT'}"
    )
    if not all(same) or rows[0].value != rows[2].value:
        disagree.append(f"shapebench ({backend}) is not bitwise identical to cKDTree")
    if disagree:
        raise SystemExit("values disagree: " + "; ".join(disagree))


if __name__ == "__main__":
    main()
