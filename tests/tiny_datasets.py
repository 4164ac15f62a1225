"""Tiny datasets held in memory, for tests that train or complete without the synthetic
benchmark on disk: a handful of meshes with their surface samples (and, for ``Blobs``, every kind
of training data a method may ask for)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import trimesh

from shapebench.api.dataset import Dataset
from shapebench.api.types import TRAIN, TRAINED, Category, ObjectData, ObjectRef, Supervision
from shapebench.preprocess.samples import occupancy_samples, sdf_samples

#: A tiny MSC: its training step draws context and target subsets, the reparameterised code and
#: Eikonal samples, and its data module draws surface points and the shuffle order.
TINY_MSC = dict(
    latent_dim=8,
    width=32,
    depth=2,
    encoder_width=16,
    encoder_layers=1,
    epochs=2,
    batch_shapes=2,
    surface_points=64,
    max_target=32,
    lr=1e-3,
)


class Shapes(Dataset):
    """A handful of small training meshes held in memory."""

    name = "shapes"

    def __init__(self, meshes: list[trimesh.Trimesh]) -> None:
        super().__init__(None, Path("."))
        self.meshes = meshes

    def categories(self) -> list[Category]:
        return [Category("blob", TRAINED)]

    def objects(self, split: str) -> list[ObjectRef]:
        if split != TRAIN:
            return []
        return [ObjectRef(f"blob/{i}", "blob") for i in range(len(self.meshes))]

    def load(self, ref: ObjectRef, need: frozenset[Supervision] = frozenset()) -> ObjectData:
        mesh = self.meshes[int(ref.id.split("/")[1])]
        pts, faces = trimesh.sample.sample_surface(mesh, 500, seed=0)
        normals = mesh.face_normals[faces]
        return ObjectData(
            ref, pts.astype(np.float32), normals.astype(np.float32), pts.astype(np.float32)
        )


def meshes() -> list[trimesh.Trimesh]:
    return [
        trimesh.creation.icosphere(2, radius=0.5),
        trimesh.creation.box((0.8, 0.5, 0.3)),
        trimesh.creation.capsule(0.6, 0.2),
        trimesh.creation.box((0.3, 0.3, 1.0)),
    ]


class Blobs(Dataset):
    """Three small training meshes in memory, with every kind of training data."""

    name = "blobs"

    def __init__(self) -> None:
        super().__init__(None, Path("."))
        self.meshes = [
            trimesh.creation.icosphere(2, radius=0.5),
            trimesh.creation.box((0.8, 0.5, 0.3)),
            trimesh.creation.capsule(0.6, 0.2),
        ]

    def categories(self) -> list[Category]:
        return [Category("blob", TRAINED)]

    def objects(self, split: str) -> list[ObjectRef]:
        ids = range(len(self.meshes)) if split == TRAIN else []
        return [ObjectRef(f"blob/{i}", "blob") for i in ids]

    def load(self, ref: ObjectRef, need: frozenset[Supervision] = frozenset()) -> ObjectData:
        mesh = self.meshes[int(ref.id.split("/")[1])]
        pts, faces = trimesh.sample.sample_surface(mesh, 500, seed=0)
        rng = np.random.default_rng(0)
        extra = {}
        if Supervision.SDF_SAMPLES in need:
            extra["sdf"] = sdf_samples(mesh, 2000, rng)
        if Supervision.OCCUPANCY_SAMPLES in need:
            extra["occupancy"] = occupancy_samples(mesh, 2000, rng)
        if Supervision.COMPLETE_POINTS in need:
            extra["complete_points"] = mesh.sample(800).astype(np.float32)
        return ObjectData(
            ref,
            pts.astype(np.float32),
            mesh.face_normals[faces].astype(np.float32),
            pts.astype(np.float32),
            extra,
        )
