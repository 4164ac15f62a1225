"""What a completion costs with and without subnormal floats, at one and two threads.

    .venv/bin/python benchmarks/bench_completion.py -m msc-noopt --checkpoint PATH \
        [--profile standard] [--objects 4] [--contexts 50,1000] [--rounds 2]

For a trained method (resolved with its profile and options as ``ladder.py`` resolves them)
and the synthetic benchmark's validation objects it completes the same contexts (the runs'
nested first ``k`` points) under four settings, interleaved over ``--rounds``, and prints each
one's best time and its ratio to the baseline measured in the same
run (two threads, subnormals as they come: the default of a ``shapebench sweep`` on 2 cores):

* threads 2 and 1, each as torch computes by default and inside
  :func:`shapebench.evaluation.completion.subnormals_flushed` (what runs do since 2026-11-29);

and whether every setting's completions are bitwise those of the baseline's thread count
without the flush (the flush must change no point; the thread count may, and is reported
apart). Nothing is logged; the checkpoint is only read.
"""

from __future__ import annotations

import argparse
import contextlib
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).parent))
from ladder import resolve  # noqa: E402


def main(argv: list[str] | None = None) -> dict[tuple[int, bool], float]:
    """Print the table; return {(threads, flushed): best seconds}."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--method", "-m", required=True)
    parser.add_argument("--checkpoint", type=Path, required=True, help="trained weights")
    parser.add_argument("--profile", default="quick")
    parser.add_argument("--objects", type=int, default=4)
    parser.add_argument("--contexts", default="50,1000")
    parser.add_argument("--rounds", type=int, default=2)
    parser.add_argument("--points", type=int, default=30000, help="points per completion")
    parser.add_argument("--cache-dir", default=None)
    parser.add_argument("-O", action="append", default=[], help="method option KEY=VALUE")
    parser.add_argument("-D", action="append", default=[], help="dataset option KEY=VALUE")
    args = parser.parse_args(argv)

    import torch

    from shapebench.api.contexts import ContextStore
    from shapebench.evaluation.completion import subnormals_flushed

    resolved, dataset = resolve(args)
    method = resolved.cls(resolved.options)
    method.load_checkpoint(args.checkpoint)
    refs = dataset.objects("validation")
    refs = refs[:: max(len(refs) // args.objects, 1)][: args.objects]
    store = ContextStore(dataset.cache_root, dataset.data_fingerprint())
    contexts = []
    for ref in refs:
        data = dataset.load(ref)
        contexts += [store.context(data, int(k), 0) for k in args.contexts.split(",")]

    settings_list = [(2, False), (2, True), (1, False), (1, True)]
    times: dict[tuple[int, bool], list[float]] = {s: [] for s in settings_list}
    points: dict[tuple[int, bool], list[np.ndarray]] = {}
    before = torch.get_num_threads()
    method.complete_batch(contexts[:1], args.points)  # warm-up: lazy imports, first allocations
    for _ in range(args.rounds):
        for threads, flushed in settings_list:
            torch.set_num_threads(threads)
            start = time.perf_counter()
            with subnormals_flushed() if flushed else contextlib.nullcontext():
                out = [method.complete_batch([c], args.points)[0] for c in contexts]
            times[(threads, flushed)].append(time.perf_counter() - start)
            points[(threads, flushed)] = [getattr(o, "points", None) for o in out]
    torch.set_num_threads(before)

    def same(a: list, b: list) -> bool:
        return all(
            x is not None and y is not None and np.array_equal(x, y)
            for x, y in zip(a, b, strict=True)
        )

    base = min(times[(2, False)])
    print(
        f"{args.method}: {len(contexts)} completions of {len(refs)} validation objects, best of "
        f"{args.rounds} interleaved rounds"
    )
    print(f"{'threads':>7} {'flushed':>8} {'seconds':>8} {'vs 2, as is':>12}  points as unflushed")
    for threads, flushed in settings_list:
        best = min(times[(threads, flushed)])
        equal = same(points[(threads, flushed)], points[(threads, False)])
        print(
            f"{threads:>7} {str(flushed):>8} {best:>8.2f} {base / best:>11.2f}x  "
            f"{'bitwise equal' if equal else 'DIFFER'}"
        )
    across = same(points[(1, False)], points[(2, False)])
    print(f"1 thread against 2 (unflushed): {'bitwise equal' if across else 'differ'}")
    return {s: min(v) for s, v in times.items()}


if __name__ == "__main__":
    main()
