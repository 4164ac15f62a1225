"""The ``shapenet55`` dataset: ShapeNet-55 and ShapeNet-34 as PoinTr ships them (Yu et al. 2021).

Read from the user's local copy (``--data-root``; never downloaded), in PoinTr's layout::

    <root>/shapenet_pc/<synset>-<model>.npy        8,192 points of each model's surface
    <root>/ShapeNet-55/train.txt, test.txt         one file name per line
    <root>/ShapeNet-34/train.txt, test.txt         34 seen categories
    <root>/ShapeNet-Unseen21/test.txt              21 unseen categories (ShapeNet-34's novel)

``benchmark=55`` (default): every category is *trained*; its test models form the ``trained``
split. ``benchmark=34``: the 34 categories of ShapeNet-34's training list are trained (its test
list is the ``trained`` split), the 21 of the unseen list are *novel* (the ``novel`` split).
Category names are the paper's (``shapebench/data/shapenet_categories.csv`` holds all 55).

Each cloud is centred on its mean and scaled to a largest distance of 1, as PoinTr's loader does
(the unit-radius frame of every other shapebench dataset, with the centroid of the points for
the centre of mass). The cloud is the ground truth and the pool sparse contexts are drawn from;
the field's protocol is ``--protocol crop`` (0.25, 0.5 and 0.75: easy, median, hard) with
``--contexts 2048``, whose partial shapes are cut from the same cloud as PoinTr cuts them. There
are no normals (``--context-normals`` is refused) and no mesh: methods that train on SDF or
occupancy samples cannot train here.

Neither list ships a validation split: ``validation`` is carved from each trained category's
training models, ``validation_per_category`` of them picked by the seed, and those models leave
the training split.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import ClassVar

import numpy as np
from shapebench_meshes.selection import (
    capped,
    carve_validation,
    hash_order,
    max_test_option,
    max_train_option,
    validation_option,
)
from shapebench_shapenet.catalog import by_synset

from shapebench.api.dataset import Dataset, ObjectLoadError
from shapebench.api.errors import ConfigError, DataNotFoundError
from shapebench.api.types import (
    NOVEL,
    TRAIN,
    TRAINED,
    VALIDATION,
    Category,
    ObjectData,
    ObjectRef,
    Supervision,
)
from shapebench.hashing import stable_hash

#: The list files of each benchmark: (training list, test list of trained categories, test list
#: of novel categories or None).
LISTS = {
    55: ("ShapeNet-55/train.txt", "ShapeNet-55/test.txt", None),
    34: ("ShapeNet-34/train.txt", "ShapeNet-34/test.txt", "ShapeNet-Unseen21/test.txt"),
}
POINTS_DIR = "shapenet_pc"
OBTAIN_HINT = (
    "pass --data-root DIR holding PoinTr's ShapeNet-55/34 layout: shapenet_pc/<synset>-<model>"
    ".npy and ShapeNet-55/{train,test}.txt (ShapeNet-34/, ShapeNet-Unseen21/ for benchmark=34); "
    "see PoinTr's DATASET.md for where to get it"
)


@dataclass(frozen=True)
class ShapeNet55Options:
    benchmark: int = field(
        default=55,
        metadata={
            "help": "55: every category trained; 34: 34 trained, 21 unseen (novel)",
            "selection": True,
        },
    )
    max_test_per_category: int = max_test_option()
    validation_per_category: int = validation_option()
    max_train_per_category: int = max_train_option()
    seed: int = field(default=0, metadata={"help": "seed of the picks (validation, caps)"})


class ShapeNet55Dataset(Dataset):
    name = "shapenet55"
    display_name = "ShapeNet-55/34 (PoinTr)"
    description = (
        "ShapeNet-55 and ShapeNet-34 point clouds in PoinTr's layout (8,192 points per model), "
        "from your local copy; the field evaluates them with --protocol crop --contexts 2048"
    )
    Options: ClassVar[type] = ShapeNet55Options
    provides = frozenset({Supervision.SURFACE_POINTS, Supervision.COMPLETE_POINTS})
    validation_splits = (VALIDATION,)
    has_normals = False
    needs_data_root = True
    obtain_hint: ClassVar[str] = OBTAIN_HINT

    def __init__(self, options, cache_dir, data_root=None) -> None:
        super().__init__(options, cache_dir, data_root)
        if options.benchmark not in LISTS:
            raise ConfigError(
                f"benchmark must be 55 or 34, got {options.benchmark!r}",
                "-D benchmark=34 for ShapeNet-34 with its 21 unseen categories",
            )
        for name in ("max_test_per_category", "validation_per_category"):
            if getattr(options, name) < 0:
                raise ConfigError(f"{name} must be >= 0")
        self._table: dict[str, list[ObjectRef]] | None = None
        self._version: str | None = None

    # ------------------------------------------------------------------ the lists

    @property
    def root(self) -> Path:
        if self.data_root is None:
            raise DataNotFoundError("dataset 'shapenet55' reads a local copy", OBTAIN_HINT)
        return Path(self.data_root)

    def _read_list(self, rel: str) -> list[tuple[str, str]]:
        """(synset, file name) of every line of a list file."""
        path = self.root / rel
        if not path.is_file():
            raise DataNotFoundError(f"split list {path} does not exist", OBTAIN_HINT)
        out = []
        for line in path.read_text().split():
            synset = line.split("-", 1)[0]
            out.append((synset, line if line.endswith(".npy") else f"{line}.npy"))
        return out

    def _ref(self, synset: str, file: str) -> ObjectRef:
        category = by_synset().get(synset)
        name = category.name if category else synset
        return ObjectRef(f"{name}/{file[: -len('.npy')]}", name)

    def _tables(self) -> dict[str, list[ObjectRef]]:
        if self._table is not None:
            return self._table
        o = self.options
        train_list, test_list, novel_list = LISTS[o.benchmark]
        by_category: dict[str, dict[str, list[ObjectRef]]] = {}
        for split, rel in ((TRAIN, train_list), (TRAINED, test_list), (NOVEL, novel_list)):
            if rel is None:
                continue
            for synset, file in self._read_list(rel):
                ref = self._ref(synset, file)
                by_category.setdefault(ref.category, {}).setdefault(split, []).append(ref)
        table: dict[str, list[ObjectRef]] = {TRAIN: [], TRAINED: [], NOVEL: [], VALIDATION: []}
        for category in sorted(by_category):
            lists = by_category[category]
            train = {r.id: r for r in lists.get(TRAIN, [])}
            kept, validation = carve_validation(
                list(train), o.validation_per_category, o.seed, "shapenet55-validation"
            )
            if o.max_train_per_category:
                kept = capped(kept, o.max_train_per_category, o.seed, "shapenet55-train-cap")
            table[TRAIN] += [train[i] for i in kept]
            table[VALIDATION] += [train[i] for i in validation]
            for split in (TRAINED, NOVEL):
                refs = {r.id: r for r in lists.get(split, [])}
                ids = sorted(refs)
                if o.max_test_per_category:
                    picked = hash_order(ids, o.seed, "shapenet55-test-cap")
                    ids = sorted(picked[: o.max_test_per_category])
                table[split] += [refs[i] for i in ids]
        self._table = table
        return table

    @property
    def version(self) -> str:
        # The list files' contents are the data: another copy with other lists is other data.
        if self._version is None:
            lists = [rel for rels in LISTS.values() for rel in rels if rel]
            listing = [
                (rel, (self.root / rel).read_text() if (self.root / rel).is_file() else "")
                for rel in lists
            ]
            self._version = f"pointr-{stable_hash(listing)}"
        return self._version

    def categories(self) -> list[Category]:
        table = self._tables()
        trained = {r.category for r in table[TRAIN] + table[TRAINED] + table[VALIDATION]}
        novel = {r.category for r in table[NOVEL]} - trained
        return [Category(c, TRAINED) for c in sorted(trained)] + [
            Category(c, NOVEL) for c in sorted(novel)
        ]

    def objects(self, split: str) -> list[ObjectRef]:
        if split not in (TRAIN, TRAINED, NOVEL, VALIDATION):
            raise ValueError(f"unknown split {split!r}; use train, trained, novel or validation")
        return list(self._tables()[split])

    def selection_notes(self, split: str) -> list[str]:
        o = self.options
        notes = [f"ShapeNet-{o.benchmark}"]
        if split in (TRAINED, NOVEL) and o.max_test_per_category:
            notes.append(f"at most {o.max_test_per_category} test models per category")
        if split == VALIDATION:
            notes.append(
                f"{o.validation_per_category} training models per category kept apart for "
                "choosing options"
            )
        return notes

    def max_context_size(self) -> int | None:
        return None  # the clouds' sizes are read per object before any cell

    # ------------------------------------------------------------------ one object

    def load(self, ref: ObjectRef, need: frozenset[Supervision] = frozenset()) -> ObjectData:
        file = ref.id.split("/", 1)[1] + ".npy"
        path = self.root / POINTS_DIR / file
        try:
            cloud = np.load(path, allow_pickle=False)
        except FileNotFoundError as exc:
            raise ObjectLoadError(f"point cloud {path} does not exist") from exc
        except Exception as exc:  # a truncated or foreign file: numpy says what it found
            raise ObjectLoadError(f"cannot read point cloud {path}: {exc}") from exc
        cloud = np.asarray(cloud, dtype=np.float64)
        if cloud.ndim != 2 or cloud.shape[1] < 3 or len(cloud) == 0:
            raise ObjectLoadError(f"point cloud {path} has shape {cloud.shape}, not (n, 3)")
        cloud = cloud[:, :3]
        if not np.isfinite(cloud).all():
            raise ObjectLoadError(f"point cloud {path} has NaN or infinite coordinates")
        cloud = cloud - cloud.mean(axis=0)
        radius = float(np.linalg.norm(cloud, axis=1).max())
        if radius <= 0:
            raise ObjectLoadError(f"point cloud {path}: every point is the same")
        points = (cloud / radius).astype(np.float32)
        extra = {"complete_points": points} if Supervision.COMPLETE_POINTS in need else {}
        return ObjectData(ref, points, np.zeros_like(points), points, extra)
