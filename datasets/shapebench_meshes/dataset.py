"""The ``meshes`` dataset: every mesh file below ``--data-root`` is an object.

A quick way to benchmark on one's own shapes: point ``--data-root`` at a folder of
``.obj/.off/.ply/.stl/.glb`` files. Each top-level sub-folder is a category (files directly in the
folder form the category ``misc``), an object's id is its path relative to the folder without the
extension. Objects are preprocessed like ShapeNet (the paper's §4.1) by
:class:`shapebench.api.dataset.MeshDataset` and cached.

By default there is nothing to train on: every category is *novel* and every object is a test
object of the ``novel`` split. With ``train_fraction`` > 0 the categories become *trained* and
that fraction of each category's objects forms the ``train`` split, the rest the ``trained`` test
split (deterministic, by hash of seed and object id).
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import ClassVar

from shapebench.api.dataset import MeshDataset, MeshOptions, ObjectLoadError
from shapebench.api.errors import ConfigError, DataNotFoundError
from shapebench.api.types import NOVEL, TRAIN, TRAINED, Category, ObjectRef, Supervision
from shapebench.hashing import stable_hash
from shapebench_meshes.loading import MESH_SUFFIXES, load_mesh_file
from shapebench_meshes.selection import capped, max_train_option, split_ids

ROOT_CATEGORY = "misc"


@dataclass(frozen=True)
class MeshFolderOptions(MeshOptions):
    # Not training_only although it matters most for training: it decides which objects are test
    # objects (and their split), so it must be part of the evaluation fingerprint and cell keys.
    train_fraction: float = field(
        default=0.0,
        metadata={
            "help": "fraction of each category's objects used for training (0: all are novel "
            "test objects; > 0: categories become trained, the rest is the trained test split)",
            "selection": True,
        },
    )
    max_train_per_category: int = max_train_option()


@dataclass(frozen=True)
class MeshFile:
    relpath: str  # relative to the data root, "/"-separated
    category: str
    size: int  # bytes: part of the data version, so a changed file is not served from the cache


class MeshFolderDataset(MeshDataset):
    name = "meshes"
    display_name = "Mesh folder"
    description = (
        "every .obj/.off/.ply/.stl/.glb file below --data-root is an object, sub-folders are "
        "categories"
    )
    Options: ClassVar[type] = MeshFolderOptions
    provides = frozenset(
        {Supervision.SURFACE_POINTS, Supervision.SDF_SAMPLES, Supervision.COMPLETE_POINTS}
    )
    needs_data_root = True
    obtain_hint: ClassVar[str] = (
        "pass --data-root DIR, a folder of mesh files (" + ", ".join(MESH_SUFFIXES) + "); each "
        "sub-folder of DIR is a category, files directly in DIR form the category 'misc'"
    )

    def __init__(self, options, cache_dir, data_root=None) -> None:
        super().__init__(options, cache_dir, data_root)
        if not 0.0 <= options.train_fraction < 1.0:
            raise ConfigError(
                f"train_fraction must be in [0, 1), got {options.train_fraction}",
                "e.g. -D train_fraction=0.8 keeps 20% of every category for testing",
            )
        self._files: dict[str, MeshFile] | None = None
        #: Files below the data root that are not meshes (an unknown extension), relative paths.
        self._not_meshes: list[str] = []
        self._version: str | None = None

    # ------------------------------------------------------------------ listing

    @property
    def files(self) -> dict[str, MeshFile]:
        """Object id -> file, read from the data root once per instance."""
        if self._files is None:
            self._files = scan_mesh_folder(self.data_root, self.obtain_hint, self._not_meshes)
        return self._files

    def selection_notes(self, split: str) -> list[str]:
        self.files  # noqa: B018 -- the scan fills _not_meshes
        if not self._not_meshes:
            return []
        counts: dict[str, int] = {}
        for rel in self._not_meshes:
            suffix = os.path.splitext(rel)[1].lower() or "no extension"
            counts[suffix] = counts.get(suffix, 0) + 1
        listed = ", ".join(f"{n} {s}" for s, n in sorted(counts.items()))
        return [
            f"{len(self._not_meshes)} files are not meshes and were left out ({listed}; "
            f"e.g. {self._not_meshes[0]}; mesh files are {', '.join(MESH_SUFFIXES)})"
        ]

    @property
    def version(self) -> str:
        # Which files (and their sizes) make the collection: two different folders never share
        # cached arrays, while the same folder copied to another machine keeps its fingerprint.
        if self._version is None:
            listing = sorted((k, f.relpath, f.size) for k, f in self.files.items())
            self._version = f"files-{stable_hash(listing)}-prep1"
        return self._version

    def categories(self) -> list[Category]:
        split = TRAINED if self.options.train_fraction > 0 else NOVEL
        return [Category(c, split) for c in sorted({f.category for f in self.files.values()})]

    def objects(self, split: str) -> list[ObjectRef]:
        if split not in (TRAIN, TRAINED, NOVEL):
            raise ValueError(f"unknown split {split!r}; use train, trained or novel")
        trains = self.options.train_fraction > 0
        if split == NOVEL:
            return [] if trains else self._refs(sorted(self.files))
        if not trains:
            return []
        picked: list[str] = []
        for category in sorted({f.category for f in self.files.values()}):
            ids = [k for k, f in self.files.items() if f.category == category]
            o = self.options
            train, test = split_ids(ids, o.train_fraction, o.seed, "meshes")
            if o.max_train_per_category:
                train = capped(train, o.max_train_per_category, o.seed, "meshes-train-cap")
            picked += train if split == TRAIN else test
        return self._refs(picked)

    def _refs(self, ids: list[str]) -> list[ObjectRef]:
        return [ObjectRef(i, self.files[i].category) for i in ids]

    def mesh(self, ref: ObjectRef):
        entry = self.files.get(ref.id)
        if entry is None:
            raise ObjectLoadError(f"no mesh file for object {ref.id!r} under {self.data_root}")
        return load_mesh_file(Path(self.data_root) / entry.relpath)


def scan_mesh_folder(
    root: Path | None, hint: str, not_meshes: list[str] | None = None
) -> dict[str, MeshFile]:
    """Every mesh file below ``root`` by object id, in a stable order; hidden entries skipped.

    The id is the "/"-separated relative path without the suffix; when two files differ only by
    their suffix (``a.obj`` and ``a.ply``) both keep it, so ids stay unique. Files with another
    suffix are not objects (ShapeNet keeps ``.mtl`` materials and textures beside every model,
    so a failure each would bury the real ones); their relative paths go to ``not_meshes``.
    """
    if root is None:
        raise DataNotFoundError("dataset 'meshes' needs a folder of meshes", hint)
    root = Path(root)
    if not root.is_dir():
        raise DataNotFoundError(f"mesh folder {root} does not exist or is not a folder", hint)
    found: list[tuple[str, str, int]] = []
    for dirpath, dirnames, filenames in os.walk(root, followlinks=True):
        dirnames[:] = sorted(d for d in dirnames if not d.startswith("."))
        for name in sorted(filenames):
            if name.startswith("."):
                continue
            path = Path(dirpath) / name
            if os.path.splitext(name)[1].lower() not in MESH_SUFFIXES:
                if not_meshes is not None:
                    not_meshes.append(path.relative_to(root).as_posix())
                continue
            rel = path.relative_to(root).as_posix()
            category = rel.split("/")[0] if "/" in rel else ROOT_CATEGORY
            found.append((rel, category, path.stat().st_size))
    if not found:
        raise DataNotFoundError(
            f"no mesh files ({', '.join(MESH_SUFFIXES)}) found below {root}", hint
        )
    stems: dict[str, int] = {}
    for rel, _, _ in found:
        stem = os.path.splitext(rel)[0]
        stems[stem] = stems.get(stem, 0) + 1
    out: dict[str, MeshFile] = {}
    for rel, category, size in found:
        stem = os.path.splitext(rel)[0]
        out[stem if stems[stem] == 1 else rel] = MeshFile(rel, category, size)
    return dict(sorted(out.items()))
