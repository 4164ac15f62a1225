"""Context points: drawn once per object, stored, identical for every method.

For each test object the visible surface points are put in a random order seeded by
(dataset fingerprint, object id); the context of size k is the first k points of that order.
So contexts are *nested* (the 50 points are among the 100, which are among the 300...) whatever
set of sizes a run asks for, and a run with only ``--contexts 50`` sees the same 50 points as a
full sweep. The order is drawn with numpy on the CPU, never on an accelerator, so it does not
depend on the device. The indices are stored next to the object's cached arrays the first time
and read back afterwards; their SHA-256 goes into every run's tags.

Methods that need randomness get ``Context.seed``, derived from (dataset, object, size, run seed).
"""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

import numpy as np

from shapebench.api.errors import describe, warn_corrupt
from shapebench.api.types import Context, ObjectData
from shapebench.hashing import array_digest, stable_seed

CONTEXTS_VERSION = "contexts-v1"


def context_order(fingerprint: str, object_id: str, n_visible: int) -> np.ndarray:
    rng = np.random.default_rng(stable_seed(CONTEXTS_VERSION, fingerprint, object_id))
    return rng.permutation(n_visible)


class ContextStore:
    """Reads and writes the per-object context order under a dataset's cache root."""

    def __init__(self, root: Path, fingerprint: str) -> None:
        self.root = Path(root) / CONTEXTS_VERSION
        self.fingerprint = fingerprint

    def path(self, data: ObjectData) -> Path:
        """Where the object's order is stored."""
        return self.root / (data.ref.id.replace("/", "__") + ".npy")

    def order(self, data: ObjectData) -> np.ndarray:
        """The object's stored order, drawn and stored on first use.

        A stored order that cannot be read, or is not a permutation of the visible points
        (truncated, garbled), is reported in one line naming the file and drawn again: the
        draw is deterministic, so the new order is the one that was lost.
        """
        path = self.path(data)
        n = len(data.surface_points)
        order = _read_order(path, n)
        if order is None:
            order = context_order(self.fingerprint, data.ref.id, n)
            _save_atomic(path, order)
        return order

    def context(self, data: ObjectData, size: int, run_seed: int, normals: bool = False) -> Context:
        """The first ``size`` points of the object's stored order; with their normals only when
        the protocol gives methods normals."""
        n = len(data.surface_points)
        if size > n:
            raise ValueError(f"context size {size} exceeds the {n} visible points")
        idx = self.order(data)[:size]
        return Context(
            ref=data.ref,
            points=data.surface_points[idx],
            normals=data.surface_normals[idx] if normals else None,
            seed=stable_seed("method", self.fingerprint, data.ref.id, size, run_seed),
        )


def order_problem(order: np.ndarray, n: int) -> str | None:
    """Why ``order`` is not a valid context order for ``n`` visible points, or None."""
    if order.ndim != 1 or not np.issubdtype(order.dtype, np.integer):
        return f"holds a {order.dtype} array of shape {order.shape}, not a list of indices"
    if len(order) != n:
        return f"holds {len(order)} indices for {n} visible points"
    # Every index exactly once: a garbled entry would repeat a point and drop another.
    if not np.array_equal(np.sort(order), np.arange(n)):
        return f"is not a permutation of the {n} visible points"
    return None


def _read_order(path: Path, n: int) -> np.ndarray | None:
    """The valid order stored at ``path``; None when there is none (a damaged file is reported
    and deleted, so the caller draws and stores the order again)."""
    try:
        order = np.load(path, allow_pickle=False)
    except FileNotFoundError:
        return None
    except Exception as exc:  # truncated: ValueError/EOFError from numpy's reader
        problem = describe(exc)
    else:
        problem = order_problem(order, n)
        if problem is None:
            return order
    warn_corrupt(path, problem, "drawing the context order again (the draw is deterministic)")
    path.unlink(missing_ok=True)
    return None


def _save_atomic(path: Path, order: np.ndarray) -> None:
    """Write ``order`` so that readers never see a partial file: a temporary file of its own
    (two processes may store the same object at once), flushed to disk, then renamed."""
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, suffix=".tmp.npy")
    try:
        with os.fdopen(fd, "wb") as f:
            np.save(f, order)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)


def contexts_digest(contexts: list[Context]) -> str:
    """SHA-256 over every context of a cell, in order: equal digests mean equal inputs."""
    return array_digest(*[c.points for c in contexts])
