"""The field's metrics (issue 29): chamfer-l1-pointr, emd and dcd against values computed by
hand in the test, and against independent computations (brute force over every permutation for
EMD, a double loop for DCD), plus what 'on request' means for the default metric set."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest
from test_metrics import make_context, make_object, random_pair, score

from shapebench.api.types import Completion
from shapebench.metrics.chamfer import ChamferL1, ChamferL1PoinTr
from shapebench.metrics.dcd import DCD, density_aware_chamfer
from shapebench.metrics.emd import EMD, assignment_distance
from shapebench.registry.discovery import get_registry
from shapebench.registry.resolve import resolve_metrics

# -- chamfer-l1-pointr ----------------------------------------------------------------------------


def test_pointr_cd_l1_of_two_points_by_hand() -> None:
    # One predicted point at 0, ground truth {0, (3, 4, 0)}: d(g -> P) = 0 and 5, mean 2.5;
    # d(P -> G) = 0; CD-L1 (PoinTr) = (2.5 + 0) / 2 = 1.25.
    pred = np.array([[0.0, 0.0, 0.0]])
    gt = np.array([[0.0, 0.0, 0.0], [3.0, 4.0, 0.0]])
    assert score(ChamferL1PoinTr(), pred, gt) == pytest.approx(1.25)


def test_pointr_cd_l1_of_a_grid_and_its_shift() -> None:
    # A grid of spacing 1 shifted by 0.1 along x: every point's nearest neighbour is its own
    # shifted copy, 0.1 away, both ways -> (0.1 + 0.1) / 2.
    g = np.stack(np.meshgrid(*[np.arange(4.0)] * 3, indexing="ij"), -1).reshape(-1, 3)
    assert score(ChamferL1PoinTr(), g + [0.1, 0, 0], g) == pytest.approx(0.1, abs=1e-6)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_pointr_cd_l1_is_half_of_chamfer_l1_on_the_same_points(seed: int) -> None:
    pred, gt = random_pair(seed)
    assert score(ChamferL1PoinTr(), pred, gt) == pytest.approx(0.5 * score(ChamferL1(), pred, gt))


def test_pointr_card_says_halved_and_keeps_chamfer_l1s_card() -> None:
    card = ChamferL1PoinTr().card(16384)
    assert card.halved and card.power == 1 and card.scale == 1000.0
    assert "halved" in card.describe()
    assert not ChamferL1().card(16384).halved  # the default metric's card (and keys) unchanged


# -- emd ------------------------------------------------------------------------------------------


def test_emd_of_identical_sets_is_zero() -> None:
    pts = np.random.default_rng(0).normal(size=(300, 3))
    assert score(EMD(), pts, pts) == pytest.approx(0.0, abs=1e-12)


def test_emd_is_not_chamfer_by_hand() -> None:
    # P = {0, 0.1}, G = {0, 1} on a line. Chamfer pairs both P points with G's 0; the one-to-one
    # matching must use G's 1: 0->0 and 0.1->1 gives (0 + 0.9) / 2 = 0.45, the other
    # pairing (1 + 0.1) / 2 = 0.55.
    pred = np.array([[0.0, 0, 0], [0.1, 0, 0]])
    gt = np.array([[0.0, 0, 0], [1.0, 0, 0]])
    assert score(EMD(), pred, gt) == pytest.approx(0.45)


def test_emd_of_a_shifted_grid_is_the_shift() -> None:
    g = np.stack(np.meshgrid(*[np.arange(5.0)] * 3, indexing="ij"), -1).reshape(-1, 3)
    assert score(EMD(), g + [0, 0.2, 0], g) == pytest.approx(0.2, abs=1e-6)  # float32 points


@pytest.mark.parametrize("seed", [0, 1, 2, 3])
def test_emd_equals_brute_force_over_every_permutation(seed: int) -> None:
    rng = np.random.default_rng(seed)
    a, b = rng.uniform(-1, 1, (7, 3)), rng.uniform(-1, 1, (7, 3))
    brute = min(
        np.mean([np.linalg.norm(a[i] - b[j]) for i, j in enumerate(perm)])
        for perm in itertools.permutations(range(7))
    )
    assert assignment_distance(a, b) == pytest.approx(brute, rel=1e-12)


def test_emd_subsets_are_seeded_equal_size_and_shared_by_methods() -> None:
    pred, gt = random_pair(0, n_gt=5000, n_pred=3000)
    a = score(EMD(), pred, gt)
    assert a == score(EMD(), pred, gt)  # same context seed: same subsets, same value
    other = EMD().compute(Completion(points=pred), make_object(gt), _context(seed=1))
    assert other != a  # another context seed draws other points
    card = EMD().card(30000)
    assert card.direction == "matched" and "2048-point subsets" in card.quantity


# -- dcd ------------------------------------------------------------------------------------------


def _context(seed: int):
    ctx = make_context()
    return type(ctx)(ref=ctx.ref, points=ctx.points, normals=ctx.normals, seed=seed)


def test_dcd_of_identical_sets_is_zero() -> None:
    pts = np.random.default_rng(0).normal(size=(400, 3))
    assert density_aware_chamfer(pts, pts) == pytest.approx(0.0, abs=1e-5)


def test_dcd_by_hand_two_points_against_one() -> None:
    # P = {0, 0} (two copies), G = {(d, 0, 0)} with d = 0.01, alpha = 1000, n_lambda = 1.
    # Term of G: its nearest P point is shared by 1 G point, size ratio |G|/|P| = 1/2:
    #   1 - exp(-1000 d^2) * 0.5 / 1.
    # Term of P: both P points have G's point as nearest, shared by 2, ratio |P|/|G| = 2:
    #   1 - exp(-1000 d^2) * 2 / 2, for each.  DCD = the mean of the two terms.
    d = 0.01
    e = math.exp(-1000 * d * d)
    expected = 0.5 * ((1 - 0.5 * e) + (1 - e))
    pred = np.zeros((2, 3))
    gt = np.array([[d, 0.0, 0.0]])
    assert density_aware_chamfer(pred, gt) == pytest.approx(expected, rel=1e-5)


@pytest.mark.parametrize("seed", [0, 1])
def test_dcd_equals_a_double_loop_of_its_definition(seed: int) -> None:
    pred, gt = random_pair(seed, n_gt=80, n_pred=60)
    pred, gt = pred.astype(np.float64), gt.astype(np.float64)

    def term(a: np.ndarray, b: np.ndarray) -> float:
        nearest = [int(np.argmin([np.sum((x - y) ** 2) for y in b])) for x in a]
        values = []
        for x, j in zip(a, nearest, strict=True):
            shared = sum(1 for k in nearest if k == j)
            d2 = float(np.sum((x - b[j]) ** 2))
            values.append(1 - math.exp(-1000 * d2) * (len(a) / len(b)) / shared)
        return float(np.mean(values))

    expected = 0.5 * (term(gt, pred) + term(pred, gt))
    assert density_aware_chamfer(pred, gt) == pytest.approx(expected, rel=1e-5)


def test_dcd_is_bounded_and_sees_density_that_chamfer_misses() -> None:
    # Two predictions with the same Chamfer-like coverage: points spread over the ground truth,
    # or piled on a tenth of it. DCD tells them apart; both values lie in [0, 1].
    gt = np.random.default_rng(0).uniform(-1, 1, (2048, 3))
    spread = gt + np.random.default_rng(1).normal(scale=0.005, size=gt.shape)
    piled = np.repeat(gt[:205], 10, axis=0)[:2048]
    a, b = density_aware_chamfer(spread, gt), density_aware_chamfer(piled, gt)
    assert 0 <= a < b <= 1
    assert DCD().card(30000).quantity.count("alpha=1000") == 1


# -- the default set ------------------------------------------------------------------------------


def test_the_field_metrics_are_computed_on_request_only() -> None:
    registry = get_registry()
    assert {"chamfer-l1-pointr", "emd", "dcd"} <= set(registry.names("metric"))
    default = {m.name for m in resolve_metrics(registry, None)}
    assert default == {"chamfer-l2", "chamfer-l1", "chamfer-l2-asym", "chamfer-l1-asym", "fscore"}
    asked = [m.name for m in resolve_metrics(registry, ["emd", "chamfer-l2"])]
    assert asked == ["emd", "chamfer-l2"]


# -- fidelity -------------------------------------------------------------------------------------


def test_fidelity_by_hand_reads_the_context_not_the_ground_truth() -> None:
    from shapebench.api.types import Context, ObjectRef
    from shapebench.metrics.fidelity import Fidelity

    # Context {0, (0, 0, 2)}, completion {0, (0, 0, 1)}: distances 0 and 1, mean 0.5, whatever
    # the ground truth (here empty: a real scan has none).
    ref = ObjectRef("scan/0", "scan")
    context = Context(ref=ref, points=np.array([[0, 0, 0], [0, 0, 2.0]]), normals=None, seed=0)
    completion = Completion(points=np.array([[0, 0, 0], [0, 0, 1.0]], dtype=np.float32))
    truthless = make_object(np.zeros((0, 3)))
    assert Fidelity().compute(completion, truthless, context) == pytest.approx(0.5)
    assert Fidelity.needs_ground_truth is False
    assert Fidelity().card(0).direction == "context->pred"


def test_presets_expand_to_the_conventions_of_a_community() -> None:
    registry = get_registry()
    assert [m.name for m in resolve_metrics(registry, ["pcn"])] == [
        "chamfer-l1-pointr",
        "chamfer-l2",
        "fscore",
    ]
    # Each metric once, in order; a preset beside a metric it holds adds it once.
    names = [m.name for m in resolve_metrics(registry, ["chamfer-l2", "mvp", "emd"])]
    assert names == ["chamfer-l2", "dcd", "fscore", "emd"]
