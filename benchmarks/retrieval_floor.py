"""How far is each test object from its nearest training shape? The recall floor of a training set.

    .venv/bin/python benchmarks/retrieval_floor.py [--sizes 6,20,60,200] [--points 4096]
        [--contexts 50,1000] [--cache-dir DIR]

A learned method that recalls returns a training shape. For each test object of the trained
categories, this scores every training shape of its category (the first N per category, for
each N of ``--sizes``, as ``train_per_category=N`` trains on) against the object's ground truth
with chamfer-l2 x1000 (the benchmark's metric, on ``--points`` seeded subsamples of both clouds,
in the same unit-radius frame) and prints, per N:

* ``oracle``: the nearest training shape by the ground truth itself: the best any recall can do;
* ``retrieve@k``: the training shape nearest to ``k`` seeded surface points of the object
  (one-sided: mean squared distance from those points to the shape), scored against the ground
  truth: a retrieval baseline that sees what a method sees (points drawn from the whole surface
  here, not the benchmark's stored contexts, so compare it in trend, not to the digit).

If the oracle falls towards the learned rows as N grows, the training set holds near-copies of
the test objects and recall looks like completion; issue 27 asks whether 2,200 synthetic shapes
are too alike. Reads the preprocessed objects of the synthetic dataset from the cache (prepare
them first: ``shapebench prepare -d synthetic -D train_per_category=200 -m msc``).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np


def synthetic_objects(cache_dir: str | None, most: str) -> Path:
    """The cache's folder of preprocessed synthetic objects holding the most files matching
    ``most`` (``"*__train-*.npz"``: the largest training split prepared)."""
    from shapebench.config import make_settings

    cache = make_settings(None, cache_dir, None, None).cache_dir / "synthetic"
    folders = sorted(cache.glob("*/objects"), key=lambda d: len(list(d.glob(most))))
    if not folders:
        raise SystemExit(f"no preprocessed synthetic objects under {cache}: prepare them first")
    return folders[-1]


def _subsample(points: np.ndarray, n: int, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return points[rng.choice(len(points), size=min(n, len(points)), replace=False)]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--sizes", default="6,20,60,200", help="training shapes per category")
    parser.add_argument("--points", type=int, default=4096, help="points per cloud for Chamfer")
    parser.add_argument("--contexts", default="50,1000", help="surface points the retrieval sees")
    parser.add_argument("--cache-dir", default=None)
    args = parser.parse_args()

    from shapebench.geometry.nearest import kdtree, nearest_distances

    sizes = [int(s) for s in args.sizes.split(",")]
    contexts = [int(k) for k in args.contexts.split(",")]
    objects = synthetic_objects(args.cache_dir, "*__train-*.npz")
    tests = sorted(p for p in objects.glob("*__test-*.npz"))
    trained = {p.name.split("__")[0] for p in objects.glob("*__train-*.npz")}
    tests = [p for p in tests if p.name.split("__")[0] in trained]
    print(f"{objects}: {len(tests)} test objects of {len(trained)} trained categories")

    def cloud(path: Path) -> np.ndarray:
        return _subsample(np.load(path)["gt_points"], args.points, seed=0)

    shapes: dict[str, list[tuple[np.ndarray, object]]] = {}  # per category: (cloud, tree)
    rows: dict[tuple[str, int], list[float]] = {}
    for test in tests:
        category = test.name.split("__")[0]
        if category not in shapes:  # each category's training shapes are read once
            paths = [objects / f"{category}__train-{i:03d}.npz" for i in range(max(sizes))]
            clouds = [cloud(p) for p in paths if p.exists()]
            shapes[category] = [(c, kdtree(c)) for c in clouds]
        gt = cloud(test)
        gt_tree = kdtree(gt)
        surface = np.load(test)["surface_points"]
        seen = {k: _subsample(surface, k, seed=1) for k in contexts}
        candidates = []
        for shape, tree in shapes[category]:
            score = np.mean(nearest_distances(gt, shape, tree=tree) ** 2) + np.mean(
                nearest_distances(shape, gt, tree=gt_tree) ** 2
            )
            fits = {
                k: np.mean(nearest_distances(p, shape, tree=tree) ** 2) for k, p in seen.items()
            }
            candidates.append((1000 * float(score), fits))
        for n in sizes:
            pool = candidates[:n]
            if len(pool) < n:
                continue
            rows.setdefault(("oracle", n), []).append(min(s for s, _ in pool))
            for k in contexts:
                best = min(pool, key=lambda c, k=k: c[1][k])
                rows.setdefault((f"retrieve@{k}", n), []).append(best[0])

    print(f"chamfer-l2 x1000, mean (median) over {len(tests)} objects; shapes = 11 x N")
    print(f"{'N':>5} {'shapes':>6} " + " ".join(f"{name:>18}" for name in _names(contexts)))
    for n in sizes:
        cells = []
        for name in _names(contexts):
            v = rows.get((name, n))
            cells.append(f"{np.mean(v):8.2f} ({np.median(v):6.2f})" if v else f"{'-':>18}")
        print(f"{n:>5} {11 * n:>6} " + " ".join(f"{c:>18}" for c in cells))


def _names(contexts: list[int]) -> list[str]:
    return ["oracle"] + [f"retrieve@{k}" for k in contexts]


if __name__ == "__main__":
    main()
