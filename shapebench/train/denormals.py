"""Flush subnormal floats to zero while shapebench trains and completes on a CPU.

Why: IGR's decoder (shared by MSC and MSC-hier) uses ``Softplus(beta=100)``. For every
pre-activation below about -0.87, ``exp(100 x)`` falls under float32's smallest normal number
(1.2e-38), and x86 CPUs compute with such subnormal numbers many times slower than with normal
ones: on a 2-core Xeon, ``Softplus(beta=100)`` over 65,536 x 128 standard-normal values took
274 ms, and 45 ms with subnormals flushed to zero (``benchmarks/bench_denormals.py`` measures
what it does to whole training steps and completions). A subnormal is a value below 1.2e-38 in
magnitude: flushing it to zero changes no sum it is added to at float32 precision, so results
do not change; the benchmark checks that weights after training steps and completions are
bitwise equal with and without it. It is a CPU setting (GPUs are not affected), it is process
wide, so it is switched on only around shapebench's own work and switched back off after it,
and nested uses (an evaluation that trains) keep it on until the outermost one ends.
"""

from __future__ import annotations

import sys
from collections.abc import Iterator
from contextlib import contextmanager

_depth = 0


@contextmanager
def flushed_denormals() -> Iterator[None]:
    """Within the block, CPU float arithmetic flushes subnormal numbers to zero.

    A no-op when torch has not been imported (a method without torch pays nothing).
    """
    global _depth
    torch = sys.modules.get("torch")
    if torch is None:
        yield
        return
    if _depth == 0:
        torch.set_flush_denormal(True)
    _depth += 1
    try:
        yield
    finally:
        _depth -= 1
        if _depth == 0:
            torch.set_flush_denormal(False)
