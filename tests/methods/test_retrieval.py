"""The ``retrieval`` floor: the training shape nearest to the context (one-sided Chamfer), returned
whole. A training shape's own context retrieves it exactly; the pruned search is the brute-force
one, ties to the lowest index; completions repeat; the keys follow the training objects; it passes
``shapebench check`` and runs end to end through the CLI."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from conftest import TINY

from shapebench.api.method import TrainerOptions, TrainingContext
from shapebench.api.types import NOVEL, TRAIN, TRAINED, Context
from shapebench.config import make_settings
from shapebench.geometry.nearest import nearest_distances

#: conftest's TINY as dataset options: one test and one training object per category.
TINY_OPTIONS = {k: int(v) for k, _, v in (a.partition("=") for a in TINY[1::2])}
TRAINER = TrainerOptions(accelerator="cpu", seed=0)


def _settings(root: Path, cache: Path):
    return make_settings(f"sqlite:///{root}/m.db", cache, "quick", root)


def _dataset(settings, **changes):
    from shapebench.registry.discovery import get_registry
    from shapebench.registry.resolve import resolve_dataset

    return resolve_dataset(get_registry(), "synthetic", settings, None, {**TINY_OPTIONS, **changes})


def _method(**options):
    from shapebench_retrieval.method import Retrieval

    return Retrieval(Retrieval.Options(**options))


@pytest.fixture(scope="module")
def tiny(tmp_path_factory, data_cache):
    """The tiny synthetic dataset (the session's preprocessed cache), its index and a method
    that loaded it."""
    root = tmp_path_factory.mktemp("retrieval")
    dataset = _dataset(_settings(root, data_cache))
    method = _method()
    path = method.fit(TrainingContext(dataset, TRAINER, root / "train", "", None, quiet=True))
    method.load_checkpoint(path)
    return dataset, method, path


def _context(dataset, ref, size: int, seed: int = 7) -> tuple[Context, np.ndarray]:
    data = dataset.load(ref)
    rng = np.random.default_rng(seed)
    rows = rng.choice(len(data.surface_points), size=size, replace=False)
    return Context(ref, data.surface_points[rows], None, seed), data.gt_points


def _rows(points: np.ndarray) -> np.ndarray:
    return points[np.lexsort(points.T)]


def test_a_training_shape_retrieves_itself(tiny):
    dataset, method, _ = tiny
    train = dataset.objects(TRAIN)
    assert len(train) == 11  # one per trained category, every category a candidate
    for position, ref in enumerate(train):
        ctx, gt = _context(dataset, ref, 100)
        out = method.complete(ctx, len(gt))
        assert out.info["retrieved"] == position and out.info["same_category"] == 1.0
        # Its own ground truth, every point once: Chamfer 0 against that shape.
        assert np.array_equal(_rows(out.points), _rows(gt))
        assert nearest_distances(out.points, gt).max() == 0.0


def test_a_test_object_gets_the_nearest_training_shape_whole(tiny):
    dataset, method, _ = tiny
    index = method.index
    clouds = [dataset.load(ref).gt_points for ref in dataset.objects(TRAIN)]
    for split in (TRAINED, NOVEL):
        ref = dataset.objects(split)[0]
        for size in (50, 300):
            ctx, gt = _context(dataset, ref, size)
            out = method.complete(ctx, len(gt))
            assert out.points.shape == (len(gt), 3) and out.points.dtype == np.float32
            # The pruned search is the brute-force one (the index holds all 2,000 points here).
            scores = [np.mean(nearest_distances(ctx.points, c) ** 2) for c in clouds]
            best = int(np.argmin(scores))
            assert out.info["retrieved"] == best
            assert out.info["fit"] == pytest.approx(scores[best], rel=1e-12)
            assert np.array_equal(_rows(out.points), _rows(clouds[best]))
            assert index.ids[best] == dataset.objects(TRAIN)[best].id
    # Fewer points than the ground truth: a seeded subsample of it; more: all of it and repeats.
    ctx, gt = _context(dataset, dataset.objects(NOVEL)[0], 50)
    few, many = method.complete(ctx, 500), method.complete(ctx, 5000)
    whole = index.cloud(int(few.info["retrieved"]))
    assert len(few.points) == 500 and len(np.unique(few.points, axis=0)) == 500
    assert nearest_distances(few.points, whole).max() == 0.0
    assert len(many.points) == 5000
    assert np.array_equal(_rows(np.unique(many.points, axis=0)), _rows(np.unique(whole, axis=0)))


def test_ties_go_to_the_lowest_index_and_the_search_is_exact():
    from shapebench_retrieval.index import FORMAT, RetrievalIndex

    rng = np.random.default_rng(0)
    shapes = [rng.normal(size=(300, 3)) * s for s in (0.3, 0.5, 0.4, 0.5, 0.6)]
    shapes[3] = shapes[1].copy()  # an exact duplicate: equal scores
    offsets = np.concatenate([[0], np.cumsum([len(s) for s in shapes])])
    arrays = {
        "format": np.array(FORMAT),
        "ids": np.array([f"s/{i}" for i in range(5)]),
        "categories": np.array(["s"] * 5),
        "sources": np.array([""] * 5),
        "digests": np.array([""] * 5),
        "sizes": np.array([len(s) for s in shapes]),
        "search": np.concatenate(shapes).astype(np.float32),
        "search_offsets": offsets,
        "embedded": np.concatenate(shapes).astype(np.float32),
        "embedded_offsets": offsets,
    }
    index = RetrievalIndex(arrays, Path("unused"))
    for k in (1, 33, 200, 1000):  # one chunk, two, several
        q = (rng.normal(size=(k, 3)) * 0.5).astype(np.float32)
        scores = [np.mean(nearest_distances(q, s.astype(np.float32)) ** 2) for s in shapes]
        best, score, _ = index.nearest(q)
        assert best == int(np.argmin(scores)) and score == pytest.approx(min(scores), rel=1e-12)
    best, _, _ = index.nearest(shapes[1][:40].astype(np.float32))
    assert best == 1  # shape 3 scores exactly the same


def test_completions_and_indexes_repeat(tiny, tmp_path):
    dataset, method, path = tiny
    again = _method()
    again.load_checkpoint(path)
    ctx, gt = _context(dataset, dataset.objects(TRAINED)[0], 100)
    first = method.complete(ctx, len(gt))
    assert np.array_equal(first.points, again.complete(ctx, len(gt)).points)
    assert first.info == again.complete(ctx, len(gt)).info
    # Another seed draws another subsample of the same shape.
    other = method.complete(Context(ctx.ref, ctx.points, None, ctx.seed + 1), 500)
    assert not np.array_equal(method.complete(ctx, 500).points, other.points)
    # A second indexing of the same data gives the same arrays.
    rebuilt = _method().fit(TrainingContext(dataset, TRAINER, tmp_path, "", None, quiet=True))
    with np.load(path) as a, np.load(rebuilt) as b:
        assert sorted(a.files) == sorted(b.files)
        assert all(np.array_equal(a[k], b[k]) for k in a.files)


def test_the_keys_follow_the_training_objects(tmp_path):
    from shapebench.evaluation.plan import RunPlan, planned_cells
    from shapebench.registry.discovery import get_registry
    from shapebench.registry.resolve import resolve_method
    from shapebench.train.ticket import training_ticket

    settings = _settings(tmp_path, tmp_path / "cache")
    method = resolve_method(get_registry(), "retrieval", settings)

    def keys(**changes) -> tuple[str, str]:
        data = _dataset(settings, **changes)
        ticket = training_ticket(method, data, TRAINER, settings)
        plan = RunPlan(method, data, [TRAINED], [50], [0], [], checkpoint=ticket.cell_checkpoint())
        return ticket.key, planned_cells(plan, TRAINED)[0][3]

    base = keys()
    assert keys() == base
    more_training = keys(train_per_category=2)
    assert more_training[0] != base[0] and more_training[1] != base[1]
    # More test objects: the same index (checkpoint key), other cells (another evaluated set).
    more_tests = keys(test_per_category=2)
    assert more_tests[0] == base[0] and more_tests[1] != base[1]
    # The index's own option and the trainer seed are in the key too.
    trainer = TrainerOptions(accelerator="cpu", seed=1)
    assert training_ticket(method, _dataset(settings), trainer, settings).key != base[0]
    finer = resolve_method(get_registry(), "retrieval", settings, {"index_points": 512})
    assert training_ticket(finer, _dataset(settings), TRAINER, settings).key != base[0]


def test_an_index_whose_cache_files_are_gone_is_refused(tiny, tmp_path):
    from shapebench_retrieval.index import RetrievalIndex

    from shapebench.api.errors import ShapebenchError

    _, method, path = tiny
    with np.load(path) as z:
        arrays = {k: z[k] for k in z.files}
    assert all(arrays["sources"])  # the synthetic dataset's cache holds every ground truth
    assert len(arrays["embedded"]) == 0
    arrays["sources"] = np.array([str(tmp_path / "gone.npz")] * len(arrays["sources"]))
    moved = tmp_path / "index.npz"
    np.savez(moved, **arrays)
    with pytest.raises(ShapebenchError, match="1?1 of those files are gone"):
        RetrievalIndex.load(moved)


@pytest.mark.slow  # builds the check's tiny dataset and imports the plugin in a subprocess
def test_retrieval_passes_the_plugin_checks(tmp_path):
    from shapebench.conformance.framework import CheckEnv
    from shapebench.conformance.testing import check_method

    with CheckEnv(workdir=tmp_path) as env:
        report = check_method("retrieval", env=env)
    done = {r.check: r.status for r in report.results}
    assert done["train"] == done["checkpoint"] == done["deterministic"] == "pass"


@pytest.mark.slow  # runs the CLI in subprocesses
def test_a_run_through_the_cli(shapebench):
    args = ("run", "-m", "retrieval", "-d", "synthetic", *TINY, "--contexts", "50,100")
    res = shapebench(*args)
    assert res.returncode == 0, res.stdout + res.stderr
    assert "retrieval: indexed 11 training shapes" in res.stderr
    cells = shapebench.cell_runs("synthetic-trained")
    assert len(cells) >= 2  # 50 and 100 points, each seed of the profile
    assert {c.data.tags["checkpoint_key"] for c in cells} != {""}
    again = shapebench(*args)
    assert again.returncode == 0 and "cached" in again.stdout
