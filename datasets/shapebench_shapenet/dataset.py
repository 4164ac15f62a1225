"""The ``shapenet`` dataset: ShapeNetCore v1 or v2 from a local copy, split as in the paper.

Categories and their trained/novel split are the paper's (Tables 1 and 2, from
:mod:`shapebench_shapenet.catalog`); the models of each category are split into training and
test models either by hash of (seed, model id) with ``test_fraction`` of them for testing, or by
the user's split files (``split_dir``, see :mod:`shapebench_shapenet.splits`). Novel categories
are split the same way and only their test models are evaluated, so a category's test set does
not depend on whether it is trained or novel. ShapeNet ships no validation split: the
``validation`` split is ``validation_per_category`` training models of each trained category,
picked by the seed, which then leave training (options are chosen on them, never on test models).

Meshes are read per model from whichever layout the folder has (v1 ``model.obj`` or v2
``models/model_normalized.obj``) and preprocessed like every mesh dataset (the paper's §4.1):
normals of visible points are oriented towards the viewpoint that sees them, which repairs
ShapeNet's flipped faces, and SDF samples of non-watertight meshes take their sign from a vote of
the nearest surface normals (:mod:`shapebench.preprocess.samples`).
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import ClassVar

from shapebench_meshes.loading import load_mesh_file
from shapebench_meshes.selection import (
    capped,
    carve_validation,
    hash_order,
    max_test_option,
    max_train_option,
    split_ids,
    validation_option,
)

from shapebench.api.dataset import MeshDataset, MeshOptions, ObjectLoadError
from shapebench.api.errors import ConfigError
from shapebench.api.types import (
    NOVEL,
    TRAIN,
    TRAINED,
    VALIDATION,
    Category,
    ObjectRef,
    Supervision,
)
from shapebench.hashing import stable_hash
from shapebench_shapenet import catalog, layout
from shapebench_shapenet.splits import read_split_dir


@dataclass(frozen=True)
class ShapeNetOptions(MeshOptions):
    categories: list[str] = field(
        default_factory=list,
        metadata={
            "help": "categories to use, by paper name, ShapeNet name or synset id, e.g. "
            "-D 'categories=[Chair, Bus]' (default: every category present)",
            "selection": True,
        },
    )
    test_fraction: float = field(
        default=0.2,
        metadata={
            "help": "fraction of each category's models kept for testing",
            "selection": True,
        },
    )
    split_dir: str | None = field(
        default=None,
        metadata={
            "help": "folder with test.txt|json (and train.txt|json) listing <synset>/<model> "
            "ids, replacing the test_fraction split (DeepSDF split files work as they are)",
            "selection": True,
        },
    )
    max_test_per_category: int = max_test_option()
    max_train_per_category: int = max_train_option()
    validation_per_category: int = validation_option()


class ShapeNetDataset(MeshDataset):
    name = "shapenet"
    display_name = "ShapeNet"
    description = (
        "ShapeNetCore v1/v2 from a local copy: the paper's 40 trained and 15 novel categories"
    )
    Options: ClassVar[type] = ShapeNetOptions
    provides = frozenset(
        {Supervision.SURFACE_POINTS, Supervision.SDF_SAMPLES, Supervision.COMPLETE_POINTS}
    )
    needs_data_root = True
    obtain_hint: ClassVar[str] = layout.OBTAIN
    validation_splits = (VALIDATION,)

    def __init__(self, options, cache_dir, data_root=None) -> None:
        super().__init__(options, cache_dir, data_root)
        if not 0.0 < options.test_fraction <= 1.0:
            raise ConfigError(
                f"test_fraction must be in (0, 1], got {options.test_fraction}",
                "e.g. -D test_fraction=0.2 (the remaining 80% are training models)",
            )
        if options.max_test_per_category < 0:
            raise ConfigError("max_test_per_category must be >= 0 (0 means no limit)")
        if options.validation_per_category < 0:
            raise ConfigError(
                "validation_per_category must be >= 0",
                "e.g. -D validation_per_category=2 (0: no validation split)",
            )
        self.selected = catalog.resolve(list(options.categories))
        self._models: dict[str, list[layout.Model]] | None = None
        self._table: dict[str, list[ObjectRef]] | None = None
        self._version: str | None = None
        self._user_splits: dict[str, set[str]] | None = None

    @property
    def models(self) -> dict[str, list[layout.Model]]:
        """Synset -> models on disk, for the selected categories (scanned once)."""
        if self._models is None:
            required = bool(self.options.categories)
            self._models = layout.scan(self.data_root, self.selected, required)
        return self._models

    @property
    def version(self) -> str:
        # v1 and v2 meshes of a model differ (v2 is re-oriented and repaired): never share a cache.
        if self._version is None:
            layouts = sorted({m.layout for models in self.models.values() for m in models})
            self._version = f"shapenet-{'+'.join(layouts)}-prep1"
        return self._version

    def identity(self, training: bool, selection: bool = True) -> dict:
        out = super().identity(training, selection)
        if selection and self.user_splits is not None:  # edited split files: new test sets
            out["split_files"] = stable_hash({k: sorted(v) for k, v in self.user_splits.items()})
        return out

    @property
    def user_splits(self) -> dict[str, set[str]] | None:
        """The split files' ids (read once, so the listing and the version agree), or None."""
        if self.options.split_dir and self._user_splits is None:
            self._user_splits = read_split_dir(self.options.split_dir)
        return self._user_splits

    def categories(self) -> list[Category]:
        return [Category(c.name, c.split) for c in self.selected if c.synset in self.models]

    def objects(self, split: str) -> list[ObjectRef]:
        if split not in (TRAIN, TRAINED, NOVEL, VALIDATION):
            raise ValueError(f"unknown split {split!r}; use train, trained, novel or validation")
        if self._table is None:
            self._table = self._split_table()
        return list(self._table[split])

    def _split_table(self) -> dict[str, list[ObjectRef]]:
        o = self.options
        user = self.user_splits
        table: dict[str, list[ObjectRef]] = {TRAIN: [], TRAINED: [], NOVEL: [], VALIDATION: []}
        listed_missing = 0
        for cat in self.selected:
            ids = [m.id for m in self.models.get(cat.synset, [])]
            if user is not None:
                on_disk = set(ids)
                test = sorted(i for i in user["test"] if i.startswith(cat.synset + "/"))
                train = sorted(i for i in user["train"] if i.startswith(cat.synset + "/"))
                listed_missing += sum(i not in on_disk for i in test + train)
                test = [i for i in test if i in on_disk]
                train = [i for i in train if i in on_disk]
            else:
                test, train = split_ids(ids, o.test_fraction, o.seed, "shapenet")
            if o.max_test_per_category:
                test = sorted(hash_order(test, o.seed, "shapenet-cap")[: o.max_test_per_category])
            # Validation models leave training before the cap, so a capped training set never
            # holds them.
            train, validation = carve_validation(
                train, o.validation_per_category, o.seed, "shapenet-validation"
            )
            if o.max_train_per_category:
                train = capped(train, o.max_train_per_category, o.seed, "shapenet-train-cap")
            if cat.split == TRAINED:
                table[TRAIN] += [ObjectRef(i, cat.name) for i in train]
                table[VALIDATION] += [ObjectRef(i, cat.name) for i in validation]
                table[TRAINED] += [ObjectRef(i, cat.name) for i in test]
            else:  # training models of novel categories are never used
                table[NOVEL] += [ObjectRef(i, cat.name) for i in test]
        if listed_missing:
            warnings.warn(
                f"{listed_missing} model(s) listed in {o.split_dir} are not under "
                f"{self.data_root}; they are left out",
                stacklevel=2,
            )
        return table

    def selection_notes(self, split: str) -> list[str]:
        if split == VALIDATION:
            return [
                f"{self.options.validation_per_category} training models per category kept "
                "apart for choosing options (-D validation_per_category=N)"
            ]
        if split not in (TRAINED, NOVEL):
            return []
        if self._table is None:
            self._table = self._split_table()
        o = self.options
        notes = []
        counted = {}
        for ref in self._table[split]:
            counted[ref.category] = counted.get(ref.category, 0) + 1
        empty = [
            c.name
            for c in self.selected
            if c.split == split and c.synset in self.models and c.name not in counted
        ]
        if empty:
            notes.append(
                f"{len(empty)} categor{'y' if len(empty) == 1 else 'ies'} with no test "
                f"model (too few models for test_fraction={o.test_fraction}): " + ", ".join(empty)
            )
        if o.max_test_per_category:
            notes.append(
                f"at most {o.max_test_per_category} test models per category "
                "(-D max_test_per_category=0 evaluates all)"
            )
        return notes

    def mesh(self, ref: ObjectRef):
        synset, _, model = ref.id.partition("/")
        found = layout.model_file(Path(self.data_root), synset, model) if self.data_root else None
        if found is None:
            raise ObjectLoadError(
                f"ShapeNet model {ref.id} has neither {layout.V1_FILE} nor {layout.V2_FILE} "
                f"under {self.data_root}"
            )
        return load_mesh_file(found[0])
