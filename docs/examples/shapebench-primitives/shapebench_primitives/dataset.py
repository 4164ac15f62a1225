from dataclasses import dataclass, field
from typing import ClassVar

import trimesh

from shapebench import (
    NOVEL,
    TRAIN,
    TRAINED,
    Category,
    MeshDataset,
    MeshOptions,
    ObjectLoadError,
    ObjectRef,
    Supervision,
)

# Category -> split: the methods train on boxes and spheres and are tested on unseen
# boxes and spheres (the "trained" split) and on capsules, a category they never saw ("novel").
CATEGORIES = {"box": TRAINED, "sphere": TRAINED, "capsule": NOVEL}


@dataclass(frozen=True)
class PrimitivesOptions(MeshOptions):  # inherits surface_candidates, gt_points, seed, ...
    per_category: int = field(
        default=4,
        # "selection": the option picks which objects are evaluated, not what their arrays
        # are, so changing it never rebuilds the cache (it still changes the cell keys).
        metadata={
            "help": "objects per category (a quarter of them are test objects)",
            "selection": True,
        },
    )


class Primitives(MeshDataset):
    name = "primitives"
    display_name = "Primitives"
    description = "boxes, spheres and capsules of varying proportions, made with trimesh"
    Options: ClassVar[type] = PrimitivesOptions
    provides = frozenset(
        {Supervision.SURFACE_POINTS, Supervision.SDF_SAMPLES, Supervision.COMPLETE_POINTS}
    )

    @property
    def version(self) -> str:
        return "primitives-1"  # change it whenever mesh() changes: cached arrays are keyed by it

    def categories(self) -> list[Category]:
        return [Category(name, split) for name, split in CATEGORIES.items()]

    def objects(self, split: str) -> list[ObjectRef]:
        n = self.options.per_category
        test = max(n // 4, 1)
        refs = []
        for name, cat_split in CATEGORIES.items():
            ids = [f"{name}/{i}" for i in range(n)]
            if split == TRAIN and cat_split == TRAINED:
                refs += ids[test:]  # trained categories lend most objects to training
            elif split == cat_split:  # the test objects of "trained" and "novel" categories
                refs += ids[:test]
        return [ObjectRef(i, i.split("/")[0]) for i in refs]

    def mesh(self, ref: ObjectRef) -> trimesh.Trimesh:
        name, index = ref.id.split("/")
        k = 1.0 + 0.25 * int(index)  # each object has its own proportions
        if name == "box":
            return trimesh.creation.box(extents=(1.0, 0.6 * k, 0.4))
        if name == "sphere":
            return trimesh.creation.icosphere(subdivisions=3, radius=0.5 * k)
        if name == "capsule":
            return trimesh.creation.capsule(height=0.5 * k, radius=0.3)
        raise ObjectLoadError(f"unknown primitive {name!r} in object {ref.id!r}")
