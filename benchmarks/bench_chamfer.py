"""Time chamfer-l2 through shapebench's KD-tree path against a brute-force reference.

    python benchmarks/bench_chamfer.py [--points 30000] [--repeat 3] [--brute-repeat N] [--seed 0]

Every object of every cell is scored with nearest-neighbour queries, so their cost bounds how
fast a sweep can go, and the claim in ``shapebench.geometry.nearest`` (exact distances in tens
of milliseconds for 30k x 30k points on a CPU) is what makes evaluating on 30k points affordable.
This script measures, on the same two clouds (ground truth: points on a bumpy sphere; prediction:
other points of the same surface plus noise):

* ``kdtree, cold``: ``ChamferL2().compute`` on fresh objects, building both KD-trees;
* ``kdtree, GT tree cached``: a new completion of an object whose GT tree is already in
  ``ObjectData.cache`` (the runner scores every context size of an object against one tree);
* ``brute force``: ``brute_force_nearest`` (chunked float64 ``torch.cdist`` on the CPU), the
  reference the tests use;
* ``cuda``: ``nearest_distances`` on CUDA tensors, only when ``torch.cuda.is_available()``.

It prints each path's chamfer-l2 and its relative difference from the brute force (they must
agree: a fast wrong answer is no use), the median time and the speed-up over brute force.
"""

from __future__ import annotations

import argparse
import os
import platform
import statistics
import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import torch

from shapebench.geometry.nearest import brute_force_nearest, nearest_distances
from shapebench.metrics.chamfer import ChamferL2
from shapebench.types import Completion, Context, ObjectData, ObjectRef

REF = ObjectRef(id="bench", category="bench")


@dataclass
class Row:
    name: str
    #: the largest relative difference from the brute force that still counts as agreement
    tolerance: float
    value: float
    seconds: list[float]

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
    for _ in range(warmup):
        fn()
    times, value = [], float("nan")
    for _ in range(repeat):
        start = time.perf_counter()
        value = fn()
        times.append(time.perf_counter() - start)
    return value, times


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--points", type=int, default=30000, help="points in each cloud")
    parser.add_argument("--repeat", type=int, default=3, help="timed runs per path (median)")
    parser.add_argument(
        "--brute-repeat",
        type=int,
        default=None,
        help="timed runs of the brute force (default: --repeat); ~10-20 s each at 30k on 2 cores",
    )
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)

    rng = np.random.default_rng(args.seed)
    gt = bumpy_sphere(args.points, rng)
    pred = bumpy_sphere(args.points, rng, noise=0.005)
    ctx = Context(ref=REF, points=gt[:1], normals=gt[:1], seed=0)
    metric = ChamferL2()
    rows: list[Row] = []

    def kdtree_cold() -> float:
        return metric.compute(Completion(points=pred), make_object(gt), ctx)

    rows.append(Row("kdtree, cold", 1e-9, *timed(kdtree_cold, args.repeat, warmup=1)))

    shared = make_object(gt)
    metric.compute(Completion(points=pred), shared, ctx)  # builds shared.cache["gt_tree"]
    assert "gt_tree" in shared.cache

    def kdtree_cached() -> float:
        return metric.compute(Completion(points=pred), shared, ctx)

    rows.append(Row("kdtree, GT tree cached", 1e-9, *timed(kdtree_cached, args.repeat, warmup=1)))

    def brute() -> float:
        g2p = brute_force_nearest(gt, pred)
        p2g = brute_force_nearest(pred, gt)
        return float(np.mean(g2p**2) + np.mean(p2g**2))

    brute_repeat = args.repeat if args.brute_repeat is None else args.brute_repeat
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
    header = f"{'path':<30} {'chamfer-l2':>14} {'rel. diff':>10} {'median s':>10} {'speed-up':>9}"
    print(header)
    print("-" * len(header))
    disagree = []
    for row in rows:
        rel = abs(row.value - reference.value) / abs(reference.value)
        speedup = reference.median / row.median
        print(
            f"{row.name:<30} {row.value:>14.8e} {rel:>10.1e} {row.median:>10.4f} {speedup:>8.1f}x"
        )
        if rel > row.tolerance:
            disagree.append(f"{row.name}: relative difference {rel:.1e} > {row.tolerance:g}")
    if disagree:
        raise SystemExit("values disagree with the brute force: " + "; ".join(disagree))


if __name__ == "__main__":
    main()
