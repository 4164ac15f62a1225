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

from pathlib import Path

import numpy as np

from shapebench.hashing import array_digest, stable_seed
from shapebench.types import Context, ObjectData

CONTEXTS_VERSION = "contexts-v1"


def context_order(fingerprint: str, object_id: str, n_visible: int) -> np.ndarray:
    rng = np.random.default_rng(stable_seed(CONTEXTS_VERSION, fingerprint, object_id))
    return rng.permutation(n_visible)


class ContextStore:
    """Reads and writes the per-object context order under a dataset's cache root."""

    def __init__(self, root: Path, fingerprint: str) -> None:
        self.root = Path(root) / CONTEXTS_VERSION
        self.fingerprint = fingerprint

    def order(self, data: ObjectData) -> np.ndarray:
        path = self.root / (data.ref.id.replace("/", "__") + ".npy")
        n = len(data.surface_points)
        if path.exists():
            order = np.load(path)
            if len(order) == n:
                return order
        order = context_order(self.fingerprint, data.ref.id, n)
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_suffix(".tmp.npy")
        np.save(tmp, order)
        tmp.replace(path)
        return order

    def context(
        self, data: ObjectData, size: int, run_seed: int, normals: bool = False
    ) -> Context:
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


def contexts_digest(contexts: list[Context]) -> str:
    """SHA-256 over every context of a cell, in order: equal digests mean equal inputs."""
    return array_digest(*[c.points for c in contexts])
