"""The metrics against an independent implementation: point-cloud-utils (a test-only dependency
that installs as a binary wheel, no compiler), as issue 29 asks. Chamfer distances and F-score
from its KD-tree correspondences, EMD against its Sinkhorn solver at a small regularisation, and
normal consistency from its nearest neighbours."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh
from test_metrics import random_pair, score

from shapebench.api.types import Completion, Context, GroundTruthArray, ObjectData, ObjectRef
from shapebench.metrics.chamfer import ChamferL1, ChamferL1PoinTr, ChamferL2
from shapebench.metrics.emd import assignment_distance
from shapebench.metrics.fscore import FScore
from shapebench.metrics.surface import NormalConsistency
from shapebench.preprocess.samples import oriented_points

pcu = pytest.importorskip(
    "point_cloud_utils", reason="point-cloud-utils is a test dependency (pip install '.[test]')"
)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_chamfer_and_fscore_agree_with_point_cloud_utils(seed: int) -> None:
    gt, pred = random_pair(seed, n_gt=800, n_pred=600)
    total, to_gt, to_pred = pcu.chamfer_distance(
        pred.astype(np.float64), gt.astype(np.float64), return_index=True
    )
    d_pred = np.linalg.norm(pred - gt[to_gt], axis=1)  # each predicted point to the GT
    d_gt = np.linalg.norm(gt - pred[to_pred], axis=1)  # each GT point to the prediction
    assert score(ChamferL1(), pred, gt) == pytest.approx(total, rel=1e-5)
    assert score(ChamferL1PoinTr(), pred, gt) == pytest.approx(total / 2, rel=1e-5)
    assert score(ChamferL2(), pred, gt) == pytest.approx(
        (d_pred**2).mean() + (d_gt**2).mean(), rel=1e-5
    )
    precision, recall = (d_pred < FScore.tau).mean(), (d_gt < FScore.tau).mean()
    expected = 2 * precision * recall / (precision + recall) if precision + recall else 0.0
    assert score(FScore(), pred, gt) == pytest.approx(expected, abs=1e-9)


def test_exact_emd_agrees_with_sinkhorn() -> None:
    rng = np.random.default_rng(3)
    a = rng.uniform(-1, 1, size=(200, 3))
    b = a + rng.normal(scale=0.1, size=a.shape) + np.array([0.2, 0.0, 0.0])
    exact = assignment_distance(a, b)
    # pcu's EMD is the entropic (Sinkhorn) transport cost with uniform weights: the mean matched
    # distance at our scale, within the smoothing of its regularisation (measured: 0.7 % above
    # the exact matching at eps = 0.01; smaller eps stops short of convergence).
    sinkhorn, _ = pcu.earth_movers_distance(a, b, eps=1e-2, max_iters=5000, stop_thresh=1e-12)
    assert sinkhorn == pytest.approx(exact, rel=0.01)


def test_normal_consistency_agrees_with_point_cloud_utils_neighbours() -> None:
    sphere = trimesh.creation.icosphere(subdivisions=2)
    box = trimesh.creation.box(extents=(1.6, 1.6, 1.6))
    truth = oriented_points(sphere, 3000, np.random.default_rng(0))
    ref = ObjectRef("s/0", "s")
    data = ObjectData(ref, truth[:, :3], truth[:, 3:], truth[:, :3], {"gt_oriented_points": truth})
    ctx = Context(ref, truth[:10, :3], None, seed=11)
    value = NormalConsistency().compute(Completion(truth[:, :3], mesh=box), data, ctx)
    # The same points the metric samples on the box (seeded by the context), by pcu's k-NN.
    pred = oriented_points(box, len(truth), np.random.default_rng(11))
    _, to_gt = pcu.k_nearest_neighbors(pred[:, :3], truth[:, :3], k=1)
    _, to_pred = pcu.k_nearest_neighbors(truth[:, :3], pred[:, :3], k=1)
    accuracy = np.abs((pred[:, 3:] * truth[to_gt, 3:]).sum(axis=1)).mean()
    completeness = np.abs((truth[:, 3:] * pred[to_pred, 3:]).sum(axis=1)).mean()
    assert value == pytest.approx(0.5 * (accuracy + completeness), rel=1e-5)
    assert 0.5 < value < 0.99
    assert GroundTruthArray.ORIENTED_POINTS.value == "gt_oriented_points"
