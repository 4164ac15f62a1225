"""Exact checks of the Chamfer and F-score metrics on cases whose answer is known.

Every leaderboard number goes through these few functions, and a mistake in them (a squared
distance where a Euclidean one is meant, a mean over the wrong set, a stale cache) produces
plausible-looking numbers that nothing downstream would catch. So the tests compare against
closed forms (a cloud against itself, concentric spheres, hand-built F-score cases) and against
an independent numpy implementation from the full pairwise distance matrix, with tolerances
derived from the geometry rather than picked to pass.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from scipy.spatial import cKDTree

import shapebench.metrics.chamfer as chamfer_module
from shapebench.api.metric import Metric
from shapebench.api.types import Completion, Context, ObjectData, ObjectRef
from shapebench.geometry.nearest import PointTree, brute_force_nearest, nearest_distances
from shapebench.metrics.chamfer import (
    Chamfer,
    ChamferL1,
    ChamferL1Asym,
    ChamferL2,
    ChamferL2Asym,
)
from shapebench.metrics.fscore import FScore

CHAMFERS: list[Chamfer] = [ChamferL2(), ChamferL1(), ChamferL2Asym(), ChamferL1Asym()]
ALL_METRICS: list[Metric] = [*CHAMFERS, FScore()]
REF = ObjectRef(id="obj-0", category="test")


# --------------------------------------------------------------------------------------------
# Builders
# --------------------------------------------------------------------------------------------


def make_object(gt: np.ndarray) -> ObjectData:
    """An ObjectData whose ground truth is ``gt`` (the other arrays are irrelevant to metrics)."""
    gt = np.asarray(gt, dtype=np.float32)
    return ObjectData(
        ref=REF, surface_points=gt[:10], surface_normals=np.zeros_like(gt[:10]), gt_points=gt
    )


def make_context() -> Context:
    pts = np.zeros((1, 3), dtype=np.float32)
    return Context(ref=REF, points=pts, normals=pts, seed=0)


def score(metric: Metric, pred: np.ndarray, gt: np.ndarray) -> float:
    """One metric on fresh Completion/ObjectData objects, so no cache is shared between calls."""
    completion = Completion(points=np.asarray(pred, dtype=np.float32))
    return metric.compute(completion, make_object(gt), make_context())


def fibonacci_sphere(n: int, radius: float = 1.0) -> np.ndarray:
    """``n`` nearly uniform points on a sphere (spherical Fibonacci lattice), float32."""
    i = np.arange(n) + 0.5
    z = 1.0 - 2.0 * i / n
    rho = np.sqrt(1.0 - z * z)
    phi = math.pi * (1.0 + math.sqrt(5.0)) * i
    pts = np.stack([rho * np.cos(phi), rho * np.sin(phi), z], axis=1)
    return (radius * pts).astype(np.float32)


def pairwise(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Full Euclidean distance matrix in float64 by explicit differences (no |a|^2+|b|^2-2ab)."""
    a64 = np.asarray(a, dtype=np.float64)
    b64 = np.asarray(b, dtype=np.float64)
    return np.sqrt(((a64[:, None, :] - b64[None, :, :]) ** 2).sum(axis=-1))


def reference_metrics(pred: np.ndarray, gt: np.ndarray, tau: float) -> dict[str, float]:
    """Every metric straight from the definitions in chamfer.py / fscore.py.

    Each direction is a mean over *its own* set (the module's reading of eq. 7).
    """
    d = pairwise(gt, pred)  # rows: GT points, columns: predicted points
    g2p = d.min(axis=1)  # each GT point to the prediction
    p2g = d.min(axis=0)  # each predicted point to the GT
    precision = float((p2g < tau).mean())
    recall = float((g2p < tau).mean())
    f = 0.0 if precision + recall == 0 else 2 * precision * recall / (precision + recall)
    return {
        "chamfer-l2": float((g2p**2).mean() + (p2g**2).mean()),
        "chamfer-l1": float(g2p.mean() + p2g.mean()),
        "chamfer-l2-asym": float((g2p**2).mean()),
        "chamfer-l1-asym": float(g2p.mean()),
        "fscore": f,
    }


def random_pair(seed: int, n_gt: int = 500, n_pred: int = 700) -> tuple[np.ndarray, np.ndarray]:
    """A GT cloud and a prediction that partly follows it, so F-score is neither 0 nor 1.

    The first 4/5 of the smaller size are GT points jittered by ~tau; the remaining predicted
    points are uniform in the box, far from most GT points.
    """
    rng = np.random.default_rng(seed)
    gt = rng.uniform(-1, 1, size=(n_gt, 3))
    n_near = min(n_gt, n_pred) * 4 // 5
    near = gt[:n_near] + rng.normal(scale=0.008, size=(n_near, 3))
    far = rng.uniform(-1, 1, size=(n_pred - len(near), 3))
    pred = np.concatenate([near, far])
    return pred.astype(np.float32), gt.astype(np.float32)


# --------------------------------------------------------------------------------------------
# A cloud against itself
# --------------------------------------------------------------------------------------------


@pytest.mark.parametrize("metric", CHAMFERS, ids=lambda m: m.name)
def test_chamfer_of_cloud_with_itself_is_exactly_zero(metric: Chamfer) -> None:
    cloud = np.random.default_rng(0).normal(size=(2000, 3)).astype(np.float32)
    assert score(metric, cloud.copy(), cloud) == 0.0


def test_fscore_of_cloud_with_itself_is_one() -> None:
    cloud = np.random.default_rng(0).normal(size=(2000, 3)).astype(np.float32)
    assert score(FScore(), cloud.copy(), cloud) == 1.0


# --------------------------------------------------------------------------------------------
# Concentric spheres
# --------------------------------------------------------------------------------------------

N_GT_SPHERE = 40_000
N_PRED_SPHERE = 30_000
#: float32 storage of unit-scale points perturbs each distance by ~1e-7; this covers it.
FLOAT32_SLACK = 1e-6


def covering_chord_bound(n: int) -> float:
    """An upper bound on the covering radius (as a chord) of an n-point Fibonacci lattice.

    Every point of the unit sphere is within chord c_max of a lattice point. The lattice gives
    each point an area 4*pi/n; a hexagonal cell of that area has circumradius ~0.62*sqrt(4*pi/n),
    and the Fibonacci lattice measures ~0.76*sqrt(4*pi/n) (probing 2M random directions at
    n = 30k and 40k). ``sqrt(4*pi/n)`` therefore bounds it with ~30% margin.
    """
    return math.sqrt(4 * math.pi / n)


@pytest.mark.parametrize("r", [0.9, 0.97, 1.2])
def test_concentric_spheres_match_closed_form(r: float) -> None:
    """Distances between spheres of radius 1 and r are |1 - r| plus a lattice-spacing term.

    For a unit-sphere point g and a point r*p of the other sphere at chord c between the unit
    directions, |g - r*p|^2 = (1 - r)^2 + r*c^2 exactly. All points of the other sphere have the
    same radius, so the nearest one has the smallest chord, at most the covering chord c_max:

        |1 - r| <= d <= sqrt((1 - r)^2 + r*c_max^2) <= |1 - r| + r*c_max^2 / (2|1 - r|)

    Summing both directions (different lattices, hence different c_max) gives one-sided bounds
    for every variant; the L1 upper slack is ~1.6% of the value at r = 0.9, far below what a
    squaring, halving or wrong-set-size mistake would change.
    """
    gt = fibonacci_sphere(N_GT_SPHERE)
    pred = fibonacci_sphere(N_PRED_SPHERE, radius=r)
    gap = abs(1.0 - r)
    c_gt = covering_chord_bound(N_GT_SPHERE)  # bounds pred->gt distances
    c_pred = covering_chord_bound(N_PRED_SPHERE)  # bounds gt->pred distances

    g2p_l2_hi = gap**2 + r * c_pred**2
    p2g_l2_hi = gap**2 + r * c_gt**2
    g2p_l1_hi = gap + r * c_pred**2 / (2 * gap)
    p2g_l1_hi = gap + r * c_gt**2 / (2 * gap)

    expected = {
        # name: (closed-form value = lower bound, upper bound)
        "chamfer-l1": (2 * gap, g2p_l1_hi + p2g_l1_hi),
        "chamfer-l2": (2 * gap**2, g2p_l2_hi + p2g_l2_hi),
        "chamfer-l1-asym": (gap, g2p_l1_hi),
        "chamfer-l2-asym": (gap**2, g2p_l2_hi),
    }
    obj = make_object(gt)
    completion = Completion(points=pred)
    for metric in CHAMFERS:
        lo, hi = expected[metric.name]
        value = metric.compute(completion, obj, make_context())
        assert lo - FLOAT32_SLACK <= value <= hi + FLOAT32_SLACK, (metric.name, lo, value, hi)


@pytest.mark.parametrize("r", [0.9, 1.2])
def test_scaled_copy_of_sphere_is_exactly_radial(r: float) -> None:
    """With the prediction = r * the same lattice, each nearest point is the radial one.

    The nearest-neighbour distance is then exactly |1 - r| for every point, so the closed forms
    hold to float32 rounding, with no lattice term at all.
    """
    gt = fibonacci_sphere(20_000)
    pred = (gt.astype(np.float64) * r).astype(np.float32)
    gap = abs(1.0 - r)
    obj, completion = make_object(gt), Completion(points=pred)
    ctx = make_context()
    assert ChamferL1().compute(completion, obj, ctx) == pytest.approx(2 * gap, abs=1e-6)
    assert ChamferL2().compute(completion, obj, ctx) == pytest.approx(2 * gap**2, abs=1e-6)
    assert ChamferL1Asym().compute(completion, obj, ctx) == pytest.approx(gap, abs=1e-6)
    assert ChamferL2Asym().compute(completion, obj, ctx) == pytest.approx(gap**2, abs=1e-6)


# --------------------------------------------------------------------------------------------
# Against a brute-force numpy implementation
# --------------------------------------------------------------------------------------------


@pytest.mark.parametrize("seed", [0, 1, 2, 3])
@pytest.mark.parametrize("sizes", [(500, 700), (700, 500), (300, 300)])
def test_metrics_equal_brute_force(seed: int, sizes: tuple[int, int]) -> None:
    n_gt, n_pred = sizes
    pred, gt = random_pair(seed, n_gt=n_gt, n_pred=n_pred)
    expected = reference_metrics(pred, gt, tau=FScore.tau)
    assert 0.0 < expected["fscore"] < 1.0  # the case exercises both counts
    obj, completion = make_object(gt), Completion(points=pred)
    for metric in ALL_METRICS:
        value = metric.compute(completion, obj, make_context())
        assert value == pytest.approx(expected[metric.name], rel=1e-9, abs=0), metric.name


def test_means_are_over_each_sets_own_size() -> None:
    """One GT point against three collinear predicted points, worked out by hand.

    gt->pred distances: [1]; pred->gt: [1, 2, 3]. Dividing each sum by the *other* set's size
    (eq. 7 as printed) would give chamfer-l1 = 1/3 + 6/1; the module's reading gives 1 + 2.
    """
    gt = np.array([[0.0, 0.0, 0.0]])
    pred = np.array([[1.0, 0.0, 0.0], [2.0, 0.0, 0.0], [3.0, 0.0, 0.0]])
    assert score(ChamferL1(), pred, gt) == pytest.approx(1.0 + 6.0 / 3.0, rel=1e-12)
    assert score(ChamferL2(), pred, gt) == pytest.approx(1.0 + 14.0 / 3.0, rel=1e-12)
    assert score(ChamferL1Asym(), pred, gt) == pytest.approx(1.0, rel=1e-12)
    assert score(ChamferL2Asym(), pred, gt) == pytest.approx(1.0, rel=1e-12)


# --------------------------------------------------------------------------------------------
# nearest_distances
# --------------------------------------------------------------------------------------------


@pytest.mark.parametrize("seed", [0, 1])
def test_nearest_distances_equals_brute_force(seed: int) -> None:
    rng = np.random.default_rng(seed)
    query = rng.normal(size=(3000, 3))
    reference = rng.normal(size=(2500, 3))
    exact = pairwise(query, reference).min(axis=1)
    kd = np.asarray(nearest_distances(query, reference))
    bf = brute_force_nearest(query, reference)
    assert kd.shape == (3000,)
    np.testing.assert_allclose(kd, exact, rtol=1e-12, atol=0)
    # torch.cdist goes through |q|^2 + |r|^2 - 2 q.r, hence the looser (still tiny) tolerance.
    np.testing.assert_allclose(bf, exact, rtol=1e-9, atol=0)
    np.testing.assert_allclose(kd, bf, rtol=1e-9, atol=0)


def test_nearest_distances_uses_given_tree() -> None:
    rng = np.random.default_rng(5)
    query, reference = rng.normal(size=(400, 3)), rng.normal(size=(300, 3))
    without = nearest_distances(query, reference)
    with_tree = nearest_distances(query, reference, tree=cKDTree(reference))
    np.testing.assert_array_equal(with_tree, without)


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_nearest_distances_accepts_cpu_tensors(dtype: torch.dtype) -> None:
    rng = np.random.default_rng(7)
    query = torch.tensor(rng.normal(size=(1000, 3)), dtype=dtype, requires_grad=True)
    reference = torch.tensor(rng.normal(size=(800, 3)), dtype=dtype)
    out = nearest_distances(query, reference)
    assert isinstance(out, np.ndarray) and out.shape == (1000,)
    exact = pairwise(query.detach().numpy(), reference.numpy()).min(axis=1)
    np.testing.assert_allclose(out, exact, rtol=1e-12, atol=0)


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA device")
def test_nearest_distances_on_cuda_matches_kdtree() -> None:
    """The CUDA path works in float32 via matrix products: agree to ~1e-3 absolute, not exactly."""
    rng = np.random.default_rng(11)
    query, reference = rng.normal(size=(5000, 3)), rng.normal(size=(4000, 3))
    out = nearest_distances(torch.tensor(query).cuda(), torch.tensor(reference).cuda())
    assert out.is_cuda and out.shape == (5000,)
    np.testing.assert_allclose(
        out.cpu().numpy(), pairwise(query, reference).min(axis=1), rtol=1e-4, atol=1e-3
    )


# --------------------------------------------------------------------------------------------
# F-score by hand
# --------------------------------------------------------------------------------------------


def grid(n_side: int, spacing: float = 0.1) -> np.ndarray:
    """A cubic grid whose points are 10*tau apart, so no two GT points match the same way."""
    ax = np.arange(n_side) * spacing
    return np.stack(np.meshgrid(ax, ax, ax, indexing="ij"), axis=-1).reshape(-1, 3)


def test_fscore_known_precision_and_recall() -> None:
    """GT: 125 grid points. Prediction: 75 of them (half nudged by 0.4*tau) plus 25 far points.

    Precision = 75/100, recall = 75/125 = 3/5, F = 2*(3/4)(3/5) / (3/4 + 3/5) = 2/3.
    """
    gt = grid(5)  # 125 points, 0.1 apart
    kept = gt[:75].copy()
    kept[::2] += np.array([0.004, 0.0, 0.0])  # within tau = 0.01, still a match
    far = np.full((25, 3), 10.0) + np.arange(25)[:, None] * 0.5
    pred = np.concatenate([kept, far])
    assert score(FScore(), pred, gt) == pytest.approx(2.0 / 3.0, rel=1e-12)


def test_fscore_shifted_points_count_as_misses_both_ways() -> None:
    """Prediction = GT with 20 of 100 points moved far: precision = recall = 4/5, so F = 4/5."""
    gt = grid(5)[:100]
    pred = gt.copy()
    pred[-20:] += 5.0
    assert score(FScore(), pred, gt) == pytest.approx(0.8, rel=1e-12)


def test_fscore_zero_when_nothing_within_tau() -> None:
    gt = grid(3)
    assert score(FScore(), gt + 1.0, gt) == 0.0


def test_fscore_threshold_is_tau() -> None:
    """tau = 0.01, the PoinTr/GRNet default the card advertises: 0.009 matches, 0.011 does not."""
    gt = grid(3)
    assert FScore.tau == 0.01 and "threshold=0.01" in FScore().card(30000).as_tag()
    assert score(FScore(), gt + np.array([0.009, 0, 0]), gt) == 1.0
    assert score(FScore(), gt + np.array([0.011, 0, 0]), gt) == 0.0


# --------------------------------------------------------------------------------------------
# Metric cards
# --------------------------------------------------------------------------------------------


def test_card_tags_distinguish_conventions() -> None:
    tags = {m.name: m.card(30000).as_tag() for m in ALL_METRICS}
    assert len(set(tags.values())) == len(tags), "two metrics share a card"
    assert ChamferL1().card(30000).as_tag() != ChamferL2().card(30000).as_tag()
    assert ChamferL2().card(30000).as_tag() != ChamferL2().card(16384).as_tag()
    assert ChamferL2().card(30000).as_tag() == ChamferL2().card(30000).as_tag()  # stable


def test_card_fields_match_the_definition() -> None:
    l2, l1a = ChamferL2().card(30000), ChamferL1Asym().card(30000)
    assert (l2.power, l2.reduction, l2.direction, l2.halved, l2.scale) == (
        2,
        "mean",
        "symmetric",
        False,
        1000.0,
    )
    assert (l1a.power, l1a.direction) == (1, "gt->pred")
    assert l2.eval_points == 30000


@pytest.mark.parametrize("metric", ALL_METRICS, ids=lambda m: m.name)
def test_describe_says_squared_only_for_l2(metric: Metric) -> None:
    text = metric.card(30000).describe()
    assert ("squared" in text) == metric.name.startswith("chamfer-l2")
    assert "30000" in text


# --------------------------------------------------------------------------------------------
# Caching
# --------------------------------------------------------------------------------------------


def test_l1_reuses_distances_cached_by_l2(monkeypatch: pytest.MonkeyPatch) -> None:
    pred, gt = random_pair(0)
    obj, completion = make_object(gt), Completion(points=pred)
    ctx = make_context()
    l2 = ChamferL2().compute(completion, obj, ctx)
    assert set(completion.cache) == {"gt_to_pred", "pred_to_gt"}
    g2p, p2g = completion.cache["gt_to_pred"], completion.cache["pred_to_gt"]
    assert g2p.shape == (len(gt),) and p2g.shape == (len(pred),)
    assert l2 == pytest.approx(float((g2p**2).mean() + (p2g**2).mean()), rel=1e-12)

    def fail(*args: object, **kwargs: object) -> None:
        raise AssertionError("nearest_distances called again: cache not reused")

    monkeypatch.setattr(chamfer_module, "nearest_distances", fail)
    l1 = ChamferL1().compute(completion, obj, ctx)
    fscore = FScore().compute(completion, obj, ctx)
    assert l1 == pytest.approx(float(g2p.mean() + p2g.mean()), rel=1e-12)
    assert 0.0 < fscore < 1.0
    assert completion.cache["gt_to_pred"] is g2p and completion.cache["pred_to_gt"] is p2g


def test_asymmetric_variant_only_computes_gt_to_pred() -> None:
    """The asymmetric Chamfer needs one direction; it must not pay for (or cache) the other."""
    pred, gt = random_pair(1)
    obj, completion = make_object(gt), Completion(points=pred)
    ChamferL2Asym().compute(completion, obj, make_context())
    assert set(completion.cache) == {"gt_to_pred"}
    assert "gt_tree" not in obj.cache


def test_gt_tree_is_built_once_per_object(monkeypatch: pytest.MonkeyPatch) -> None:
    """The runner scores many completions (context sizes) of one object: one GT tree for all."""
    pred, gt = random_pair(2)
    obj = make_object(gt)
    builds: list[int] = []
    trees_passed: list[object] = []
    real_kdtree, real_nearest = chamfer_module.kdtree, chamfer_module.nearest_distances

    def counting_kdtree(points: np.ndarray) -> PointTree:
        builds.append(len(points))
        return real_kdtree(points)

    def recording_nearest(query: object, reference: object, tree: object = None) -> object:
        trees_passed.append(tree)
        return real_nearest(query, reference, tree=tree)

    monkeypatch.setattr(chamfer_module, "kdtree", counting_kdtree)
    monkeypatch.setattr(chamfer_module, "nearest_distances", recording_nearest)

    first, second = Completion(points=pred), Completion(points=pred[::-1].copy())
    v1 = ChamferL2().compute(first, obj, make_context())
    tree = obj.cache["gt_tree"]
    assert isinstance(tree, PointTree)
    np.testing.assert_array_equal(tree.data, gt.astype(np.float64))
    v2 = ChamferL2().compute(second, obj, make_context())

    assert builds == [len(gt)]  # built for the first completion only
    assert obj.cache["gt_tree"] is tree
    assert sum(t is tree for t in trees_passed) == 2  # pred->gt used it both times
    assert v1 == pytest.approx(v2, rel=1e-12)  # same points, other order: same value
