"""What the ground truth of uncached training objects costs alone, against preparing each object.

    python benchmarks/bench_ground_truth.py [--objects 60] [--repeats 3]

The retrieval method indexes the ground truth of every training shape (2,200 at the `standard`
profile), and from an empty cache that read is most of its "training". The baseline, measured in
the same run, is what retrieval did before ``Dataset.ground_truth_points``: the whole object's
preparation (``Dataset.load``: normalisation, ground truth and the visible points' ray casting,
cached), for the same objects of the synthetic benchmark's ``train`` split, each repeat from an
empty cache. Both give the same points bit for bit (checked here too). Prints the median seconds
per object of each and their ratio.
"""

from __future__ import annotations

import argparse
import shutil
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np
from shapebench_synthetic.dataset import SyntheticDataset


def seconds_per_object(objects: int, alone: bool) -> tuple[float, list[np.ndarray]]:
    cache = Path(tempfile.mkdtemp(prefix="bench-gt-"))
    try:
        dataset = SyntheticDataset(SyntheticDataset.Options(), cache, None)
        refs = dataset.objects("train")[:objects]
        start = time.perf_counter()
        clouds = [
            dataset.ground_truth_points(ref) if alone else dataset.load(ref).gt_points
            for ref in refs
        ]
        return (time.perf_counter() - start) / len(refs), clouds
    finally:
        shutil.rmtree(cache, ignore_errors=True)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--objects", type=int, default=60, help="training objects per repeat")
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args()
    whole, alone = [], []
    for _ in range(args.repeats):  # interleaved, so that a change of load affects both
        t_whole, c_whole = seconds_per_object(args.objects, alone=False)
        t_alone, c_alone = seconds_per_object(args.objects, alone=True)
        assert all(np.array_equal(a, b) for a, b in zip(c_whole, c_alone, strict=True))
        whole.append(t_whole)
        alone.append(t_alone)
    m_whole, m_alone = statistics.median(whole), statistics.median(alone)
    print(f"{args.objects} synthetic training objects, {args.repeats} repeats, empty caches")
    print(f"  whole object (load):          {m_whole * 1000:8.1f} ms per object  (baseline)")
    print(f"  ground truth alone:           {m_alone * 1000:8.1f} ms per object")
    print(f"  ratio baseline / alone:       {m_whole / m_alone:8.2f}x  (same points: yes)")
    print(f"  2,200 training shapes (standard): {m_whole * 2200:.0f} s -> {m_alone * 2200:.0f} s")


if __name__ == "__main__":
    main()
