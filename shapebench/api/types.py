"""Plain data passed between datasets, methods and metrics.

Arrays are numpy, float32, shaped ``(n, 3)`` for points and normals, in the dataset's normalised
frame (centre of mass at the origin, largest vertex distance 1; see :mod:`shapebench.preprocess`).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from enum import Enum
from typing import Any

import numpy as np

#: Evaluation and training splits, named as in the paper: ``trained`` is the test objects of the
#: categories used for training (Table 1), ``novel`` the test objects of categories never seen in
#: training (Table 2); ``train`` holds the training objects of the trained categories.
TRAIN = "train"
TRAINED = "trained"
NOVEL = "novel"
EVAL_SPLITS = (TRAINED, NOVEL)
#: Objects kept apart from the test objects for choosing options (profiles, the ladder, method
#: defaults): evaluated only when asked for by name (``--split validation``), never reported.
VALIDATION = "validation"
ALL_SPLITS = (TRAIN, TRAINED, NOVEL)


class Supervision(str, Enum):
    """What a method needs from a dataset at training time."""

    SURFACE_POINTS = "surface_points"  # visible ("disemboweled") surface points with normals
    SDF_SAMPLES = "sdf_samples"  # signed distances at points near the surface (DeepSDF)
    OCCUPANCY_SAMPLES = "occupancy_samples"  # inside/outside labels in the bounding box (OccNet)
    COMPLETE_POINTS = "complete_points"  # dense points over the whole surface (PCN targets)

    def __str__(self) -> str:
        return self.value


class GroundTruthArray(str, Enum):
    """Ground-truth arrays beyond ``gt_points`` that some metrics read (``Metric.needs``), built
    on first use from the object's mesh and cached. A dataset lists those it can build in
    ``Dataset.provides_ground_truth``; a dataset of bare points builds none, and metrics that
    need them are recorded as not applicable there."""

    #: ``(n, 6)``: points over the whole surface and the unit normals of their faces (normal
    #: consistency; ConvONet's ``pointcloud.npz``).
    ORIENTED_POINTS = "gt_oriented_points"
    #: ``(n, 4)``: points uniform in the padded box [-1.1, 1.1]^3 and 1 where inside the mesh
    #: (volumetric IoU; ConvONet's ``points.npz``).
    OCCUPANCY = "gt_occupancy"

    def __str__(self) -> str:
        return self.value


@dataclass(frozen=True)
class Category:
    name: str
    split: str  # TRAINED or NOVEL: whether methods may train on this category


@dataclass(frozen=True)
class ObjectRef:
    """One object of a dataset; ``id`` is unique within the dataset."""

    #: Unique within the dataset; may contain ``/`` (cache file names replace it).
    id: str
    #: The category's name (see :class:`Category`).
    category: str


@dataclass
class ObjectData:
    """The preprocessed arrays of one object.

    ``surface_points``/``surface_normals`` are the points visible from the viewpoints around the
    object (the pool contexts are drawn from); ``gt_points`` is the ground truth metrics compare
    against. Datasets may add more arrays (SDF samples, occupancy, ...) under ``extra``.
    """

    #: Which object this is.
    ref: ObjectRef
    #: ``(n, 3)`` points visible from the viewpoints: the pool contexts are drawn from.
    surface_points: np.ndarray
    #: ``(n, 3)`` unit normals of ``surface_points``.
    surface_normals: np.ndarray
    #: ``(m, 3)`` ground-truth points over the whole surface: what metrics compare against.
    gt_points: np.ndarray
    #: Training arrays by name (``"sdf"``, ``"occupancy"``, ``"complete_points"``) and
    #: ground-truth arrays (:class:`GroundTruthArray` values), when asked for.
    extra: dict[str, np.ndarray] = field(default_factory=dict)
    #: Scratch space for metrics (the ground truth's KD-tree is built once per object).
    cache: dict[str, Any] = field(default_factory=dict, repr=False, compare=False)


@dataclass(frozen=True)
class Context:
    """The sparse observation a method completes.

    ``normals`` is None under the default protocol: the paper gives methods the context points
    only, and so does shapebench unless a run asks for ``--context-normals`` (see
    :mod:`shapebench.api.protocol`). A method that can use normals must check for None. ``seed`` is
    derived from (dataset, object, context size, run seed): a method that draws random numbers
    should seed from it so that runs repeat exactly.
    """

    #: The object the context was drawn from.
    ref: ObjectRef
    #: ``(k, 3)`` float32 context points.
    points: np.ndarray
    #: ``(k, 3)`` normals of ``points``, or None (the default protocol).
    normals: np.ndarray | None
    #: Seed for any randomness of the method (runs repeat exactly).
    seed: int
    #: Whether this object's completion is pictured (the report's grids, the cell's MLflow
    #: artifacts): a method may spend work there that the scores do not need, such as drawing
    #: posterior samples for the report's uncertainty pictures. Never changes the completion.
    pictured: bool = False

    @property
    def size(self) -> int:
        return int(self.points.shape[0])


@dataclass
class Completion:
    """What a method returns for one context.

    ``points`` is always required: the completed shape as a point cloud (metrics use it). A method
    may also return the ``mesh`` it extracted, its implicit function ``sdf`` (callable on an
    ``(n, 3)`` array), and ``samples``: several completions drawn from a posterior, as point clouds.
    ``info`` holds scalars worth logging (timings, iterations, ...).
    """

    #: ``(n, 3)`` points of the completed shape; the metrics score these.
    points: np.ndarray
    #: The mesh the method extracted (a ``trimesh.Trimesh``), if any.
    mesh: Any | None = None
    #: The implicit function: signed distances of an ``(n, 3)`` array of points.
    sdf: Callable[[np.ndarray], np.ndarray] | None = None
    #: Several completions drawn from a posterior, as ``(n, 3)`` point clouds.
    samples: list[np.ndarray] | None = None
    #: Scalars worth logging (timings, iterations, ...).
    info: dict[str, float] = field(default_factory=dict)
    #: Scratch space shared by metrics scoring this completion (nearest-neighbour distances).
    cache: dict[str, Any] = field(default_factory=dict, repr=False, compare=False)
