"""What a completion picture costs, against the same picture without its spread panel.

    python benchmarks/bench_pictures.py [--repeats 5]

The runner draws a picture for the fixed objects of every cell (shapebench.evaluation.pictures),
so a picture has to stay cheap beside a completion. The baseline, measured in the same run, is
the picture of the same clouds without the posterior-spread panel (what a method without
posterior samples gets); the ratio says what the spread panel adds. The clouds are 20,000 points
sampled on a mug (a cylinder with a torus handle), the context its first 1,000.
"""

from __future__ import annotations

import argparse
import statistics
import time

import numpy as np
import trimesh

from shapebench.evaluation.pictures import picture_arrays, picture_png


def mug(points: int = 20_000) -> np.ndarray:
    body = trimesh.creation.cylinder(radius=0.5, height=1.0)
    body.apply_transform(trimesh.transformations.rotation_matrix(np.pi / 2, [1, 0, 0]))
    handle = trimesh.creation.torus(0.3, 0.06)
    handle.apply_translation([0.6, 0, 0])
    mesh = trimesh.util.concatenate([body, handle])
    return np.asarray(mesh.sample(points, seed=0), dtype=np.float32)


def median_seconds(arrays: dict, repeats: int) -> float:
    picture_png(arrays)  # warm-up: font cache, colour maps
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        picture_png(arrays, "timed")
        times.append(time.perf_counter() - start)
    return statistics.median(times)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args()
    gt = mug()
    plain = picture_arrays(gt[:1000], gt[::2], gt)
    spread = picture_arrays(gt[:1000], gt[::2], gt, spread=np.abs(gt[::2, 1]))
    base = median_seconds(plain, args.repeats)
    with_spread = median_seconds(spread, args.repeats)
    print(f"picture without spread panel (baseline): median {base:.3f} s")
    print(f"picture with spread panel:               median {with_spread:.3f} s")
    print(f"ratio with / without: {with_spread / base:.2f}")


if __name__ == "__main__":
    main()
