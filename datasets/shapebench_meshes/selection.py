"""Deterministic train/test selection of objects, shared by the file-based datasets.

Objects are ranked by a hash of (seed, object id) rather than shuffled as a list, so that adding
or removing one file moves only that file: every other object stays on its side of the split.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import field
from typing import Any

from shapebench.hashing import stable_seed


def hash_order(ids: Iterable[str], seed: int, salt: str) -> list[str]:
    """``ids`` in a pseudo-random order that depends only on (salt, seed, id)."""
    return sorted(ids, key=lambda i: (stable_seed(salt, seed, i), i))


def max_train_option() -> Any:
    """The ``max_train_per_category`` field of a mesh dataset with a training split: the
    training-set size axis of a data-scaling sweep."""
    return field(
        default=0,
        metadata={
            "help": "train on at most this many objects per category (0: all), picked by the "
            "seed; a smaller cap picks a subset of a larger one",
            "training_only": True,
        },
    )


def max_test_option() -> Any:
    """The ``max_test_per_category`` field of a dataset read from a user's copy: a cap on the
    test objects of each category, picked by the seed (it chooses objects: ``selection``)."""
    return field(
        default=0,
        metadata={
            "help": "evaluate at most this many test models per category (0: all)",
            "selection": True,
            # It picks among the test models only: the training models, and so every
            # checkpoint key, do not depend on it.
            "evaluation_only": True,
        },
    )


def validation_option() -> Any:
    """The ``validation_per_category`` field of a dataset whose copy ships no validation split:
    that many training models per trained category, picked by the seed, form the ``validation``
    split (for choosing options) and leave training (it chooses objects: ``selection``)."""
    return field(
        default=2,
        metadata={
            "help": "training models per trained category kept apart as the validation split",
            "selection": True,
        },
    )


def carve_validation(ids: list[str], count: int, seed: int, salt: str) -> tuple[list, list]:
    """(training ids, validation ids): ``count`` of ``ids`` picked by hash rank, both sorted."""
    validation = sorted(hash_order(ids, seed, salt)[:count])
    return sorted(set(ids) - set(validation)), validation


def capped(ids: Iterable[str], cap: int, seed: int, salt: str) -> list[str]:
    """At most ``cap`` of ``ids``, the first by hash rank, sorted: a smaller cap picks a subset
    of a larger one, so the training sets of a data-scaling sweep are nested."""
    return sorted(hash_order(ids, seed, salt)[:cap])


def split_ids(
    ids: Iterable[str], fraction: float, seed: int, salt: str
) -> tuple[list[str], list[str]]:
    """``(picked, rest)``: ``round(fraction * n)`` ids picked by hash rank, both sorted.

    With a fraction strictly between 0 and 1 and at least two ids, both sides get one or more.
    """
    ordered = hash_order(ids, seed, salt)
    n = len(ordered)
    k = round(fraction * n)
    if 0 < fraction < 1 and n >= 2:
        k = min(max(k, 1), n - 1)
    return sorted(ordered[:k]), sorted(ordered[k:])
