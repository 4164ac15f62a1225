"""The ``pcn`` dataset: PCN's partial and complete clouds (Yuan et al. 2018) as PCN and PoinTr
ship them, read from the user's local copy (``--data-root``; never downloaded)::

    <root>/PCN.json                                   8 categories with train/val/test model ids
    <root>/<split>/complete/<synset>/<model>.pcd      16,384 points of the complete shape
    <root>/<split>/partial/<synset>/<model>/NN.pcd    back-projected partial scans (00-07 in
                                                      train, 00 in val and test)

Every category is *trained*. ``test`` models form the ``trained`` split, ``val`` models the
``validation`` split (PCN ships one), ``train`` models the training split. Category names are
PCN.json's ``taxonomy_name``.

An object's partial scan is the pool its contexts are drawn from (the sparse protocol's seeded,
nested order over the scan's points), its complete cloud the ground truth. The view is scan 00
for val and test (the only one), and for a training model one of its scans picked by the seed
(``view`` fixes one). Clouds are used as PCN ships them: centred on the complete cloud's mean and
inside the unit sphere (PCN's maintainers, pcn issue #30), so distances are in PCN's own frame,
close to shapebench's unit-radius frame but not rescaled to a largest distance of exactly 1. The
field's input is 2,048 points of the scan; a scan with fewer points limits ``--contexts`` (said
before any cell). There are no normals (``--context-normals`` is refused) and no mesh.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import ClassVar

import numpy as np
from shapebench_meshes.selection import capped, hash_order, max_test_option, max_train_option

from shapebench.api.dataset import Dataset, ObjectLoadError
from shapebench.api.errors import DataNotFoundError
from shapebench.api.types import (
    TRAIN,
    TRAINED,
    VALIDATION,
    Category,
    ObjectData,
    ObjectRef,
    Supervision,
)
from shapebench.exchange.pcd import read_pcd
from shapebench.hashing import stable_hash, stable_seed

OBTAIN_HINT = (
    "pass --data-root DIR holding the PCN dataset as PoinTr's DATASET.md lays it out: "
    "PCN.json and {train,val,test}/{partial,complete}/<synset>/..."
)
#: shapebench's split -> PCN's folder and PCN.json key.
FOLDERS = {TRAIN: "train", TRAINED: "test", VALIDATION: "val"}


@dataclass(frozen=True)
class PCNOptions:
    view: int = field(
        default=-1,
        metadata={
            "help": "which partial scan of a training model is its pool (-1: one per model, "
            "picked by the seed; val and test models have only scan 0)"
        },
    )
    max_test_per_category: int = max_test_option()
    max_train_per_category: int = max_train_option()
    seed: int = field(default=0, metadata={"help": "seed of the picks (views, caps)"})


@dataclass(frozen=True)
class _Model:
    synset: str
    model: str
    folder: str  # PCN's split folder: train, val or test


class PCNDataset(Dataset):
    name = "pcn"
    display_name = "PCN"
    description = (
        "PCN's partial scans and 16,384-point complete clouds (8 categories), from your local "
        "copy; contexts are drawn from the partial scan"
    )
    Options: ClassVar[type] = PCNOptions
    provides = frozenset({Supervision.SURFACE_POINTS, Supervision.COMPLETE_POINTS})
    eval_splits = (TRAINED,)  # every PCN category is trained: there is no novel split
    validation_splits = (VALIDATION,)
    has_normals = False
    needs_data_root = True
    obtain_hint: ClassVar[str] = OBTAIN_HINT

    def __init__(self, options, cache_dir, data_root=None) -> None:
        super().__init__(options, cache_dir, data_root)
        self._entries: list[dict] | None = None
        self._models: dict[str, _Model] = {}

    @property
    def root(self) -> Path:
        if self.data_root is None:
            raise DataNotFoundError("dataset 'pcn' reads a local copy", OBTAIN_HINT)
        return Path(self.data_root)

    def _catalog(self) -> list[dict]:
        if self._entries is None:
            path = self.root / "PCN.json"
            if not path.is_file():
                raise DataNotFoundError(f"{path} does not exist", OBTAIN_HINT)
            try:
                entries = json.loads(path.read_text())
            except ValueError as exc:
                raise DataNotFoundError(f"{path} is not JSON: {exc}", OBTAIN_HINT) from exc
            if not isinstance(entries, list) or not all(
                isinstance(e, dict) and "taxonomy_id" in e for e in entries
            ):
                raise DataNotFoundError(
                    f"{path} is not PCN's catalogue (a list of taxonomy entries)", OBTAIN_HINT
                )
            self._entries = entries
        return self._entries

    @property
    def version(self) -> str:
        return f"pcn-{stable_hash(self._catalog())}"

    def categories(self) -> list[Category]:
        return [Category(str(e["taxonomy_name"]), TRAINED) for e in self._catalog()]

    def objects(self, split: str) -> list[ObjectRef]:
        if split not in FOLDERS:
            raise ValueError(f"unknown split {split!r}; use train, trained or validation")
        folder = FOLDERS[split]
        o = self.options
        out = []
        for entry in self._catalog():
            name, synset = str(entry["taxonomy_name"]), str(entry["taxonomy_id"])
            ids = sorted(str(m) for m in entry.get(folder, []))
            if split == TRAINED and o.max_test_per_category:
                ids = sorted(hash_order(ids, o.seed, "pcn-test-cap")[: o.max_test_per_category])
            if split == TRAIN and o.max_train_per_category:
                ids = capped(ids, o.max_train_per_category, o.seed, "pcn-train-cap")
            for model in ids:
                ref = ObjectRef(f"{name}/{model}", name)
                self._models[ref.id] = _Model(synset, model, folder)
                out.append(ref)
        return out

    def selection_notes(self, split: str) -> list[str]:
        if split == TRAINED and self.options.max_test_per_category:
            return [f"at most {self.options.max_test_per_category} test models per category"]
        return []

    def max_context_size(self) -> int | None:
        return None  # scans differ in size: read per object before any cell

    def _model(self, ref: ObjectRef) -> _Model:
        if ref.id not in self._models:
            for split in FOLDERS:
                self.objects(split)
        if ref.id not in self._models:
            raise ObjectLoadError(f"object {ref.id!r} is not in {self.root / 'PCN.json'}")
        return self._models[ref.id]

    def scan_path(self, ref: ObjectRef) -> Path:
        """The partial scan that is ``ref``'s pool of context points."""
        m = self._model(ref)
        folder = self.root / m.folder / "partial" / m.synset / m.model
        scans = sorted(folder.glob("*.pcd"))
        if not scans:
            raise ObjectLoadError(f"no partial scan (*.pcd) in {folder}")
        view = self.options.view
        if view < 0:
            view = stable_seed("pcn-view", self.options.seed, ref.id) % len(scans)
        if view >= len(scans):
            raise ObjectLoadError(f"{folder} has {len(scans)} scans; view {view} asked for")
        return scans[view]

    def load(self, ref: ObjectRef, need: frozenset[Supervision] = frozenset()) -> ObjectData:
        m = self._model(ref)
        complete = read_pcd(self.root / m.folder / "complete" / m.synset / f"{m.model}.pcd")
        partial = read_pcd(self.scan_path(ref))
        extra = {"complete_points": complete} if Supervision.COMPLETE_POINTS in need else {}
        return ObjectData(ref, partial, np.zeros_like(partial), complete, extra)
