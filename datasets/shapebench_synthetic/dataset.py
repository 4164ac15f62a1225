"""The ``synthetic`` dataset: watertight procedural meshes in ShapeNet-like categories.

Nothing to download: objects are generated from (category, split, index, seed) by
:mod:`shapebench_synthetic.shapes`, then preprocessed like ShapeNet (the paper's §4.1) and cached.
Categories are split into *trained* and *novel* ones as the paper splits ShapeNet; the trained
categories have ``train_per_category`` training and ``test_per_category`` test objects, the novel
ones only test objects. The ``validation`` split holds ``test_per_category`` more objects of each
trained category, generated apart from both (ids ``<category>/val-NNN``): options are chosen on
it, never on test objects, and it is evaluated only when named (``--split validation``).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from importlib.metadata import version
from typing import ClassVar

from shapebench.api.dataset import MeshDataset, MeshOptions
from shapebench.api.types import (
    NOVEL,
    TRAIN,
    TRAINED,
    VALIDATION,
    Category,
    ObjectRef,
    Supervision,
)
from shapebench.hashing import stable_seed
from shapebench_synthetic import shapes


@dataclass(frozen=True)
class SyntheticOptions(MeshOptions):
    test_per_category: int = field(
        default=2,
        metadata={
            "help": "test objects per category (raise it for a larger benchmark)",
            "selection": True,
            # The training objects are train-000... whatever the test count: a larger test set
            # reuses every trained checkpoint.
            "evaluation_only": True,
        },
    )
    train_per_category: int = field(
        default=8,
        metadata={
            "help": "training objects per trained category",
            "training_only": True,
            "selection": True,
        },
    )


class SyntheticDataset(MeshDataset):
    name = "synthetic"
    display_name = "Synthetic ShapeNet-like"
    description = (
        f"{len(shapes.CATEGORIES)} procedural ShapeNet-like categories (trained and novel); "
        "generated locally, no download"
    )
    Options: ClassVar[type] = SyntheticOptions
    provides = frozenset({Supervision.SURFACE_POINTS})
    # Its size follows test_per_category: a new option would change every synthetic key.
    validation_splits = (VALIDATION,)

    @property
    def version(self) -> str:
        # The meshes are byte-identical only for one manifold3d release (its boolean output can
        # change between versions), so its version is part of the data version.
        return f"gen{shapes.GENERATOR_VERSION}-manifold{version('manifold3d')}"

    def categories(self) -> list[Category]:
        return [Category(name, fam.split) for name, fam in shapes.CATEGORIES.items()]

    def objects(self, split: str) -> list[ObjectRef]:
        if split == TRAIN:
            cat_split, count, prefix = TRAINED, self.options.train_per_category, "train"
        elif split in (TRAINED, NOVEL):
            cat_split, count, prefix = split, self.options.test_per_category, "test"
        elif split == VALIDATION:
            cat_split, count, prefix = TRAINED, self.options.test_per_category, "val"
        else:
            raise ValueError(f"unknown split {split!r}; use train, trained, novel or validation")
        return [
            ObjectRef(f"{cat.name}/{prefix}-{i:03d}", cat.name)
            for cat in self.categories()
            if cat.split == cat_split
            for i in range(count)
        ]

    def selection_notes(self, split: str) -> list[str]:
        if split == TRAIN:
            return []
        n = self.options.test_per_category
        if split == VALIDATION:
            return [
                f"{n} validation object{'s' if n != 1 else ''} per trained category, apart from "
                "the test objects: for choosing options, not for reporting"
            ]
        return [
            f"{n} test object{'s' if n != 1 else ''} per category; "
            "-D test_per_category=N for a larger benchmark"
        ]

    def mesh(self, ref: ObjectRef):
        seed = stable_seed("synthetic", self.options.seed, ref.id) % (2**32)
        return shapes.generate(ref.category, seed)
