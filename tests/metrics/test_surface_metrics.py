"""Normal consistency and volumetric IoU (issue 29 §1), as ConvONet evaluates them: values by
hand on meshes whose answer is known, the ground-truth arrays a mesh dataset builds for them, and
*not applicable* (never a failure, never a zero) for completions without a mesh and for ground
truth without one, from the metric up to the leaderboard."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh
from conftest import TINY

from shapebench.api.metric import NotApplicable
from shapebench.api.types import (
    Completion,
    Context,
    GroundTruthArray,
    ObjectData,
    ObjectRef,
)
from shapebench.geometry.containment import inside
from shapebench.metrics.surface import IoU, NormalConsistency
from shapebench.preprocess.samples import IOU_BOUND, IOU_POINTS, occupancy_samples, oriented_points

REF = ObjectRef("shape/0", "shape")


def _square(angle_deg: float = 0.0) -> trimesh.Trimesh:
    """The unit square in the z = 0 plane, rotated about the x axis by ``angle_deg``."""
    v = np.array([[-0.5, -0.5, 0], [0.5, -0.5, 0], [0.5, 0.5, 0], [-0.5, 0.5, 0]], dtype=float)
    mesh = trimesh.Trimesh(v, [[0, 1, 2], [0, 2, 3]], process=False)
    mesh.apply_transform(trimesh.transformations.rotation_matrix(np.radians(angle_deg), [1, 0, 0]))
    return mesh


def _object(mesh: trimesh.Trimesh, arrays: dict[str, np.ndarray]) -> ObjectData:
    points = np.asarray(mesh.vertices, dtype=np.float32)
    return ObjectData(REF, points, points, points, arrays)


def _context() -> Context:
    return Context(REF, np.zeros((4, 3), dtype=np.float32), None, seed=7)


# -- normal consistency, by hand ------------------------------------------------------------------


@pytest.mark.parametrize(("angle", "expected"), [(0.0, 1.0), (60.0, 0.5), (90.0, 0.0)])
def test_normal_consistency_of_two_squares_is_the_cosine_of_their_angle(angle, expected) -> None:
    # Every face normal of one square makes the same angle with every face normal of the other,
    # so whichever point is nearest, |cos| is cos(angle): 1, 1/2, 0.
    truth = oriented_points(_square(), 2000, np.random.default_rng(0))
    data = _object(_square(), {GroundTruthArray.ORIENTED_POINTS.value: truth})
    prediction = Completion(points=truth[:, :3], mesh=_square(angle))
    value = NormalConsistency().compute(prediction, data, _context())
    assert value == pytest.approx(expected, abs=1e-6)


def test_normal_consistency_ignores_which_side_is_out() -> None:
    # Marching cubes and scanned meshes disagree on orientation: a flipped square is consistent.
    truth = oriented_points(_square(), 1000, np.random.default_rng(0))
    flipped = _square()
    flipped.invert()
    data = _object(_square(), {GroundTruthArray.ORIENTED_POINTS.value: truth})
    value = NormalConsistency().compute(Completion(truth[:, :3], mesh=flipped), data, _context())
    assert value == pytest.approx(1.0)


def test_oriented_points_lie_on_the_faces_with_their_normals() -> None:
    box = trimesh.creation.box(extents=(1.0, 2.0, 3.0))
    arr = oriented_points(box, 500, np.random.default_rng(1))
    assert arr.shape == (500, 6)
    np.testing.assert_allclose(np.linalg.norm(arr[:, 3:], axis=1), 1.0, atol=1e-6)
    # On an axis-aligned box a point's normal is the axis of the face it lies on.
    axis = np.argmax(np.abs(arr[:, 3:]), axis=1)
    half = np.array([0.5, 1.0, 1.5])
    np.testing.assert_allclose(np.abs(arr[np.arange(500), axis]), half[axis], atol=1e-5)


# -- IoU, by hand -----------------------------------------------------------------------------


def test_iou_of_a_cube_and_its_half_shift_is_a_third() -> None:
    # Unit cubes shifted by half a side: intersection 1/2, union 3/2, IoU 1/3, estimated on
    # 100,000 uniform points (standard error about 0.005).
    cube = trimesh.creation.box(extents=(1.0, 1.0, 1.0))
    queries = occupancy_samples(cube, IOU_POINTS, np.random.default_rng(0))
    assert np.abs(queries[:, :3]).max() <= IOU_BOUND
    data = _object(cube, {GroundTruthArray.OCCUPANCY.value: queries})
    shifted = cube.copy()
    shifted.apply_translation([0.5, 0, 0])
    assert IoU().compute(Completion(queries[:1, :3], mesh=shifted), data, _context()) == (
        pytest.approx(1 / 3, abs=0.02)
    )
    assert IoU().compute(Completion(queries[:1, :3], mesh=cube), data, _context()) == 1.0
    # The inside fraction itself: the cube fills 1 / 2.2^3 of the box.
    assert queries[:, 3].mean() == pytest.approx(1 / (2 * IOU_BOUND) ** 3, abs=0.003)


def test_inside_works_on_an_open_mesh_by_ray_votes() -> None:
    # A box without one face (holes are common in scans and ShapeNet) is still mostly "inside".
    box = trimesh.creation.box(extents=(1.0, 1.0, 1.0))
    open_box = trimesh.Trimesh(box.vertices, box.faces[2:], process=False)
    assert not open_box.is_watertight
    points = np.array([[0.0, 0.0, 0.0], [0.2, -0.1, 0.3], [2.0, 0.0, 0.0], [0.0, 0.0, -0.9]])
    assert inside(open_box, points).tolist() == [True, True, False, False]


# -- not applicable -------------------------------------------------------------------------------


@pytest.mark.parametrize("metric", [NormalConsistency(), IoU()])
def test_a_completion_without_mesh_or_truth_without_mesh_is_not_applicable(metric) -> None:
    truth = oriented_points(_square(), 100, np.random.default_rng(0))
    arrays = {
        GroundTruthArray.ORIENTED_POINTS.value: truth,
        GroundTruthArray.OCCUPANCY.value: np.zeros((10, 4), dtype=np.float32),
    }
    with pytest.raises(NotApplicable, match="points only, with no mesh"):
        metric.compute(Completion(points=truth[:, :3]), _object(_square(), arrays), _context())
    with pytest.raises(NotApplicable, match="gives no .* ground truth .*points only"):
        metric.compute(Completion(truth[:, :3], mesh=_square()), _object(_square(), {}), _context())
    assert metric.by_default is False and metric.needs


def test_the_runner_records_not_applicable_apart_from_failures() -> None:
    from shapebench.evaluation.failures import not_applicable_reasons
    from shapebench.evaluation.scoring import score, summarize

    truth = oriented_points(_square(), 500, np.random.default_rng(0))
    data = _object(_square(), {GroundTruthArray.ORIENTED_POINTS.value: truth})
    metrics = [NormalConsistency()]
    rows = []
    for mesh in (None, _square(60.0)):
        row, _ = score(Completion(points=truth[:, :3], mesh=mesh), data, _context(), metrics, 0.5)
        rows.append(row)
    assert rows[0]["status"] == "ok" and np.isnan(rows[0]["normal-consistency"])
    assert "metric_error.normal-consistency" not in rows[0]
    assert rows[1]["normal-consistency"] == pytest.approx(0.5)  # the frame's scale keeps the mesh
    import pandas as pd

    table = pd.DataFrame(rows).assign(seconds=0.0)
    summary = summarize(table, metrics)
    assert summary["normal-consistency.not_applicable"] == 1.0
    assert summary["normal-consistency.mean"] == pytest.approx(0.5)
    assert summary["failures"] == 0.0 and "normal-consistency.errors" not in summary
    reasons = not_applicable_reasons(table)
    assert reasons == [("normal-consistency", "the completion is points only, with no mesh", 1)]


# -- the arrays a mesh dataset builds, and the command line ---------------------------------------


def test_a_mesh_dataset_builds_and_caches_the_ground_truth_arrays(tmp_path) -> None:
    from shapebench.registry.discovery import get_registry

    registry = get_registry()
    cls = registry.load("dataset", "synthetic")
    dataset = cls(cls.Options(test_per_category=1, gt_points=3000), tmp_path)
    ref = dataset.objects("trained")[0]
    need = frozenset(GroundTruthArray)
    data = dataset.load(ref, need)
    oriented = data.extra[GroundTruthArray.ORIENTED_POINTS.value]
    occupancy = data.extra[GroundTruthArray.OCCUPANCY.value]
    assert oriented.shape == (3000, 6) and occupancy.shape == (IOU_POINTS, 4)
    assert 0.0 < occupancy[:, 3].mean() < 0.5  # some of the box is inside the shape
    # On the surface: every oriented point is within reach of the ground-truth points.
    from shapebench.geometry.nearest import nearest_distances

    assert np.median(nearest_distances(oriented[:, :3], data.gt_points)) < 0.05
    cached = sorted(p.name for p in (dataset.cache_root / "ground-truth").iterdir())
    assert len(cached) == 2
    again = dataset.load(ref, need)  # read back, not drawn again
    np.testing.assert_array_equal(again.extra["gt_oriented_points"], oriented)
    assert "gt_occupancy" not in dataset.load(ref).extra  # only when asked for
    # The arrays do not change the data fingerprint: no stored cell changes.
    assert (
        dataset.data_fingerprint()
        == cls(cls.Options(test_per_category=1, gt_points=3000), tmp_path).data_fingerprint()
    )


@pytest.mark.slow  # runs the CLI
def test_mesh_metrics_are_na_for_points_only_rows_in_the_cli_and_the_table(
    shapebench, tmp_path
) -> None:
    base = ("run", "-d", "synthetic", "--split", "trained", *TINY, "--contexts", "50")
    res = shapebench(*base, "-m", "gauss", "--metric", "convonet")
    assert res.returncode == 0, res.stderr
    assert "iou: not applicable to" in res.stdout and "points only, with no mesh" in res.stdout
    assert " n/a " in res.stdout
    # Depth runs that computed the default metrics only: their table is skipped, in one line.
    res = shapebench(*base, "-m", "gauss", "--protocol", "depth", "-q")
    assert res.returncode == 0, res.stderr
    out = tmp_path / "boards"
    res = shapebench(
        "leaderboard",
        "-d",
        "synthetic",
        "--metric",
        "iou",
        "--reference",
        "gauss",
        "--out",
        str(out),
    )
    assert res.returncode == 0, res.stdout + res.stderr
    assert "skipped: no run of synthetic-trained with depth contexts recorded metric 'iou'" in (
        res.stderr
    )
    page = (out / "synthetic-trained.md").read_text()
    assert "| n/a |" in page
    assert "**Choices**: options (profiles, method defaults, the ladder) are chosen on the " in page
    assert "n/a: iou does not apply to `gauss`: the completion is points only" in page
    import pandas as pd

    csv = pd.read_csv(out / "synthetic-trained.csv")
    assert csv["kind"].tolist() == ["not_applicable"]
    assert csv["not_applicable"].iloc[0].startswith("the completion is points only")


def test_the_header_says_which_split_options_are_chosen_on() -> None:
    from shapebench.boards.splits import choices_text

    assert "chosen on the `validation` split of `shapenet`" in choices_text("shapenet", "trained")
    assert "for choices, not reports" in choices_text("synthetic", "validation")
    assert "`meshes` has no validation split" in choices_text("meshes", "novel")
    assert "not installed here" in choices_text("no-such-dataset", "trained")
