"""Stable hashes and seeds: the same inputs give the same value on every machine and run.

Python's ``hash()`` is salted per process, so everything that must repeat (cache keys, cell keys,
context seeds) goes through SHA-256 of a canonical JSON form instead.
"""

from __future__ import annotations

import hashlib
import json
from typing import Any

import numpy as np


def _default(obj: Any) -> Any:
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, (set, frozenset)):
        return sorted(obj)
    return str(obj)


def canonical_json(obj: Any) -> str:
    return json.dumps(obj, sort_keys=True, separators=(",", ":"), default=_default)


def stable_hash(obj: Any, length: int = 16) -> str:
    """Hex digest of the canonical JSON of ``obj``."""
    return hashlib.sha256(canonical_json(obj).encode()).hexdigest()[:length]


def stable_seed(*parts: Any) -> int:
    """A 63-bit seed derived from ``parts`` (strings, numbers, tuples...)."""
    return int(hashlib.sha256(canonical_json(list(parts)).encode()).hexdigest()[:16], 16) >> 1


def array_digest(*arrays: np.ndarray) -> str:
    h = hashlib.sha256()
    for a in arrays:
        h.update(np.ascontiguousarray(a).tobytes())
    return h.hexdigest()
