"""The paper's ShapeNet categories: names, synset ids and the trained/novel split.

Read from the table shipped with shapebench (``shapebench/data/shapenet_categories.csv``, the
paper's 40 trained and 15 novel categories), so the split is the paper's and never guessed from
the data on disk.
"""

from __future__ import annotations

import csv
import io
from dataclasses import dataclass
from functools import lru_cache
from importlib import resources

from shapebench.api.errors import ConfigError


@dataclass(frozen=True)
class ShapeNetCategory:
    name: str  # the paper's name, used as the benchmark's category name ("Plane")
    synset: str  # ShapeNetCore folder name ("02691156")
    shapenet_name: str  # ShapeNet's own name ("airplane")
    split: str  # "trained" or "novel"


@lru_cache(maxsize=1)
def catalog() -> tuple[ShapeNetCategory, ...]:
    """Every category of the paper's table, in the table's order."""
    text = resources.files("shapebench").joinpath("data/shapenet_categories.csv").read_text()
    rows = csv.DictReader(io.StringIO(text))
    return tuple(
        ShapeNetCategory(r["paper_name"], r["synset_id"], r["shapenet_name"], r["split"])
        for r in rows
    )


def by_synset() -> dict[str, ShapeNetCategory]:
    return {c.synset: c for c in catalog()}


def resolve(names: list[str] | tuple[str, ...]) -> list[ShapeNetCategory]:
    """Categories named by paper name, ShapeNet name or synset id (case-insensitive), in table
    order; an empty selection means every category."""
    if not names:
        return list(catalog())
    keys: dict[str, ShapeNetCategory] = {}
    for c in catalog():
        for key in (c.name, c.synset, c.shapenet_name):
            keys[key.lower()] = c
    unknown = [n for n in names if str(n).strip().lower() not in keys]
    if unknown:
        raise ConfigError(
            f"unknown ShapeNet categor{'y' if len(unknown) == 1 else 'ies'} "
            f"{', '.join(map(repr, unknown))}",
            "use the paper's names (e.g. Chair, 'Garbage Can'), ShapeNet's names or synset ids; "
            "'shapebench datasets' lists them",
        )
    wanted = {keys[str(n).strip().lower()].synset for n in names}
    return [c for c in catalog() if c.synset in wanted]
