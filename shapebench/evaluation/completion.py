"""Asking a method for completions: a chunk of contexts through ``complete_batch`` at once, timed,
with subnormal floats flushed; a crash of the batch fails its objects, not the cell."""

from __future__ import annotations

import sys
import time
from collections.abc import Iterator
from contextlib import contextmanager

from shapebench.api.method import Method
from shapebench.api.types import Context


@contextmanager
def subnormals_flushed() -> Iterator[None]:
    """Subnormal floats flushed to zero in torch's CPU arithmetic on this thread, for the span of
    a completion; the setting it found is restored after.

    Softplus(beta=100), the activation of IGR's, MSC's and MSC-hier's decoders, computes
    ``exp(100 x)``, which is subnormal for x below about -0.87: everywhere far from the surface,
    where meshing evaluates the field most. x86 CPUs compute on subnormals many times slower.
    Flushed, a one-thread completion is 2.1x (IGR) to 3.2x (MSC w/o opt) faster, with bitwise the
    same points (benchmarks/bench_completion.py; benchmarks/README.md). The flag is per thread:
    torch's own worker threads keep subnormals, so the gain is a one-thread worker's (``sweep
    -j 2`` on 2 cores), hardly a two-thread process's (1.02-1.07x). Nothing here imports torch:
    a method that uses it has imported it by now. Training is left as it is (its weights are what
    keys name).
    """
    torch = sys.modules.get("torch")
    if torch is None:
        yield
        return
    flushed = bool((torch.tensor([1e-39]) * 1.0).item() == 0.0)  # no getter for the flag
    torch.set_flush_denormal(True)
    try:
        yield
    finally:
        torch.set_flush_denormal(flushed)


def complete_chunk(method: Method, contexts: list[Context], n_points: int):
    """The method's outputs for a chunk of contexts, and the seconds spent per object."""
    start = time.perf_counter()
    try:
        with subnormals_flushed():
            outputs = method.complete_batch(contexts, n_points)
        if len(outputs) != len(contexts):
            raise RuntimeError(
                f"complete_batch returned {len(outputs)} results for {len(contexts)} contexts"
            )
    except Exception as exc:  # a crash of the whole batch fails these objects only
        outputs = [exc] * len(contexts)
    return outputs, (time.perf_counter() - start) / max(len(contexts), 1)
