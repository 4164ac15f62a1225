"""Asking a method for completions: a chunk of contexts through ``complete_batch`` at once, timed,
with subnormal floats flushed and freed memory kept for reuse; a crash of the batch fails its
objects, not the cell."""

from __future__ import annotations

import ctypes
import os
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


#: glibc ``mallopt`` parameters (malloc.h) and the values :func:`keep_freed_memory` sets.
_M_TRIM_THRESHOLD, _M_MMAP_THRESHOLD = -1, -3
_MMAP_THRESHOLD = 64 << 20
_TRIM_THRESHOLD = 256 << 20
#: The prefix of the environment variables with which a user tunes glibc's allocator
#: (``MALLOC_TRIM_THRESHOLD_``, ``MALLOC_ARENA_MAX``...): one set, the allocator is left alone.
_ALLOCATOR_SETTINGS = "MALLOC_"
_allocator_kept: bool | None = None


def keep_freed_memory() -> bool:
    """Have glibc's allocator keep the memory of freed tensors for the next ones, once per
    process; True when it does. Values are unchanged: only where memory comes from.

    A test-time latent search allocates and frees tensors of a few MB at every step, and the mesh
    extractor's field calls as many. glibc serves blocks above its mmap threshold (128 kB, raised
    only as large blocks are freed) from fresh ``mmap`` pages, and hands heap memory back above
    its trim threshold (128 kB): each such tensor then costs page faults on first touch. Served
    from the heap and kept (thresholds of 64 MB and 256 MB), an IGR run spent 0.8 s of system
    time instead of 4.6 and ran 1.06x faster, with the same peak memory (benchmarks/README.md,
    "Points per field call"). A process whose user tunes the allocator (a ``MALLOC_*`` variable
    or ``glibc.malloc`` tunables), or that is not linked against glibc, is left alone.
    """
    global _allocator_kept
    if _allocator_kept is None:
        _allocator_kept = _set_allocator_thresholds()
    return _allocator_kept


def _set_allocator_thresholds() -> bool:
    if not sys.platform.startswith("linux"):
        return False
    if any(name.startswith(_ALLOCATOR_SETTINGS) for name in os.environ):
        return False
    if "glibc.malloc" in os.environ.get("GLIBC_TUNABLES", ""):
        return False
    try:
        libc = ctypes.CDLL("libc.so.6")
        libc.gnu_get_libc_version  # noqa: B018 (glibc's, absent from musl and others)
        mallopt = libc.mallopt
    except (OSError, AttributeError):
        return False
    mallopt.argtypes, mallopt.restype = [ctypes.c_int, ctypes.c_int], ctypes.c_int
    return bool(
        mallopt(_M_MMAP_THRESHOLD, _MMAP_THRESHOLD) and mallopt(_M_TRIM_THRESHOLD, _TRIM_THRESHOLD)
    )


def complete_chunk(method: Method, contexts: list[Context], n_points: int):
    """The method's outputs for a chunk of contexts, and the seconds spent per object."""
    keep_freed_memory()
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
