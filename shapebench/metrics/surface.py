"""Metrics of a completion's surface, as ConvONet's evaluation computes them: normal consistency
and volumetric IoU.

Both need the completion's *mesh* (the implicit methods return one; PCN and Gauss return points
only, and there the metrics are recorded as not applicable) and a ground-truth array built from
the object's mesh (:class:`~shapebench.api.types.GroundTruthArray`; a dataset of bare points has
none, and there too they are not applicable). Neither depends on the frame's scale.

* ``normal-consistency``: ConvONet's ``normals correctness``. ``n`` points are sampled
  area-weighted on the completion's mesh with their faces' normals (seeded by the context), ``n``
  the ground truth's count; for each point of one set the nearest point of the other is found and
  ``|cos|`` of the angle between their normals taken (unoriented: marching cubes and scans
  disagree on which side is out); the mean of each direction, then the mean of the two.
* ``iou``: ``|A ∩ B| / |A ∪ B|`` over 100,000 points uniform in the padded box [-1.1, 1.1]^3,
  A the points inside the ground-truth mesh (built once per object), B those inside the
  completion's mesh (ConvONet's ``check_mesh_contains`` on its ``points.npz``; here the
  ray-parity vote of :func:`shapebench.geometry.containment.inside`).
"""

from __future__ import annotations

import numpy as np

from shapebench.api.metric import UNIT_SPHERE_FRAME, Metric, MetricCard, NotApplicable
from shapebench.api.types import Completion, Context, GroundTruthArray, ObjectData
from shapebench.geometry.containment import inside
from shapebench.geometry.nearest import kdtree
from shapebench.geometry.sampling import sample_surface
from shapebench.preprocess.samples import IOU_BOUND, IOU_POINTS

POINTS_ONLY = "the completion is points only, with no mesh"


def _mesh(prediction: Completion):
    mesh = prediction.mesh
    if mesh is None:
        raise NotApplicable(POINTS_ONLY)
    if len(mesh.faces) == 0:
        raise ValueError("the completion's mesh has no faces")
    return mesh


def _truth(ground_truth: ObjectData, kind: GroundTruthArray) -> np.ndarray:
    array = ground_truth.extra.get(kind.value)
    if array is None:
        raise NotApplicable(
            f"the dataset gives no {kind.value!r} ground truth (its objects are points only, "
            "with no mesh)"
        )
    return array


def _unitless_card(name: str, quantity: str, eval_points: int, **fields: str) -> MetricCard:
    """The card of a metric whose values are not distances (no power, no scale, higher better)."""
    return MetricCard(
        metric=name,
        power=0,
        quantity=quantity,
        halved=False,
        scale=1.0,
        frame=UNIT_SPHERE_FRAME,
        eval_points=eval_points,
        higher_is_better=True,
        **fields,
    )


class NormalConsistency(Metric):
    name = "normal-consistency"
    description = (
        "mean |cos| between the normals of nearest neighbours, both ways (ConvONet; needs a "
        "mesh: higher is better)"
    )
    higher_is_better = True
    by_default = False
    needs = frozenset({GroundTruthArray.ORIENTED_POINTS})

    def card(self, eval_points: int) -> MetricCard:
        return _unitless_card(
            self.name,
            "|cos| between the face normals of nearest neighbours (meshes only)",
            eval_points,
            reduction="mean",
            direction="symmetric",
            combine="mean",
        )

    def compute(self, prediction: Completion, ground_truth: ObjectData, context: Context) -> float:
        mesh = _mesh(prediction)
        truth = _truth(ground_truth, GroundTruthArray.ORIENTED_POINTS)
        rng = np.random.default_rng(context.seed)
        points, face = sample_surface(mesh.vertices, mesh.faces, len(truth), rng)
        normals = np.asarray(mesh.face_normals, dtype=np.float64)[face]
        gt_points, gt_normals = truth[:, :3].astype(np.float64), truth[:, 3:].astype(np.float64)
        tree = ground_truth.cache.get("normal-consistency.tree")
        if tree is None:
            tree = ground_truth.cache["normal-consistency.tree"] = kdtree(gt_points)
        _, to_gt = tree.query(points)
        _, to_pred = kdtree(points).query(gt_points)
        accuracy = np.abs(np.einsum("ij,ij->i", normals, gt_normals[to_gt])).mean()
        completeness = np.abs(np.einsum("ij,ij->i", gt_normals, normals[to_pred])).mean()
        return float(0.5 * (accuracy + completeness))


class IoU(Metric):
    name = "iou"
    description = (
        "volumetric IoU of the meshes' insides on 100k uniform points (ConvONet; needs a mesh: "
        "higher is better)"
    )
    higher_is_better = True
    by_default = False
    needs = frozenset({GroundTruthArray.OCCUPANCY})

    def card(self, eval_points: int) -> MetricCard:
        return _unitless_card(
            self.name,
            f"volumetric IoU of inside the meshes at points uniform in the box "
            f"[-{IOU_BOUND:g}, {IOU_BOUND:g}]^3 of the unit-radius frame (inside by ray parity)",
            IOU_POINTS,
            reduction="none",
            direction="none",
        )

    def compute(self, prediction: Completion, ground_truth: ObjectData, context: Context) -> float:
        mesh = _mesh(prediction)
        truth = _truth(ground_truth, GroundTruthArray.OCCUPANCY)
        occupied = truth[:, 3] > 0.5
        predicted = inside(mesh, truth[:, :3].astype(np.float64))
        union = np.count_nonzero(occupied | predicted)
        if union == 0:
            raise ValueError("neither mesh has any query point inside it")
        return float(np.count_nonzero(occupied & predicted) / union)
