"""The lowest Chamfer a completion of N points can score: a perfect N-point output.

    .venv/bin/python benchmarks/output_floor.py [--sizes 1024,4096,16384] [--split trained]
        [--cache-dir DIR]

A point-cloud method (PCN, PoinTr) emits a fixed number of points. Even points lying exactly on
the true surface leave gaps between them, and ``chamfer-l2`` (mean over the ground truth of the
squared distance to the output, plus the reverse) charges those gaps. For each test object this
takes N of its own ground-truth points (seeded, without replacement: the reverse term is then
zero) and scores them against the whole ground truth, as the benchmark's metric does, x1000, in
the unit-radius frame. A row cannot score below its output size's floor, so a ratio asked of it
(issue 27: "PCN improves 5x from 50 to 1000 points") is reachable only if its 50-point score is
at least that ratio times the floor.

Reads the preprocessed objects from the cache: the folder with the most test objects (the
``standard`` profile's 10 per category; prepare them first: ``shapebench prepare -d synthetic``).
"""

from __future__ import annotations

import argparse

import numpy as np


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--sizes", default="1024,4096,16384", help="output sizes N")
    parser.add_argument(
        "--split", default="trained", choices=("trained", "novel"), help="test categories"
    )
    parser.add_argument("--cache-dir", default=None)
    args = parser.parse_args()

    from retrieval_floor import synthetic_objects  # this folder is on the path of its scripts
    from shapebench_synthetic.shapes import novel_categories

    from shapebench.geometry.nearest import nearest_distances

    sizes = [int(s) for s in args.sizes.split(",")]
    objects = synthetic_objects(args.cache_dir, "*__test-*.npz")

    novel = set(novel_categories())

    def wanted(name: str) -> bool:
        return (name.split("__")[0] in novel) == (args.split == "novel")

    tests = sorted(p for p in objects.glob("*__test-*.npz") if wanted(p.name))
    if not tests:
        raise SystemExit(f"no {args.split} test objects in {objects}")
    floors: dict[int, list[float]] = {n: [] for n in sizes}
    for test in tests:
        gt = np.load(test)["gt_points"]
        for n in sizes:
            rng = np.random.default_rng(n)  # each size its own draw: rows do not depend on --sizes
            subset = gt[rng.choice(len(gt), size=min(n, len(gt)), replace=False)]
            floors[n].append(1000 * float(np.mean(nearest_distances(gt, subset) ** 2)))
    print(f"{objects}: {len(tests)} {args.split} test objects, {len(gt)} ground-truth points each")
    print("chamfer-l2 x1000 of a perfect N-point output, mean (median):")
    for n in sizes:
        print(f"{n:>7}: {np.mean(floors[n]):.3f} ({np.median(floors[n]):.3f})")


if __name__ == "__main__":
    main()
