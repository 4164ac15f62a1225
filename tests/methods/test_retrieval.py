"""The ``retrieval`` floor: the training shape nearest to the context (one-sided Chamfer), returned
whole. A training shape's own context retrieves it exactly; the pruned search is the brute-force
one, ties to the lowest index; completions repeat; the index is self-contained (a moved folder
serves without the data cache) and checked on load; its key follows the training objects and no
trainer setting; it passes ``shapebench check`` and runs end to end through the CLI, its build's
cost logged like a training's."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
from conftest import TINY

from shapebench.api.errors import ShapebenchError
from shapebench.api.method import TrainerOptions, TrainingContext
from shapebench.api.types import NOVEL, TRAIN, TRAINED, Context
from shapebench.config import make_settings
from shapebench.geometry.nearest import nearest_distances

#: conftest's TINY as dataset options: one test and one training object per category.
TINY_OPTIONS = {k: int(v) for k, _, v in (a.partition("=") for a in TINY[1::2])}
TRAINER = TrainerOptions(accelerator="cpu", seed=0)
#: The largest error of the index's 16-bit clouds on the unit frame (a box side of at most 2).
STORED_ERROR = 2.0 / 65535 / 2 * (1 + 1e-6)


def _settings(root: Path, cache: Path):
    return make_settings(f"sqlite:///{root}/m.db", cache, "quick", root)


def _dataset(settings, **changes):
    from shapebench.registry.discovery import get_registry
    from shapebench.registry.resolve import resolve_dataset

    return resolve_dataset(get_registry(), "synthetic", settings, None, {**TINY_OPTIONS, **changes})


def _method(**options):
    from shapebench_retrieval.method import Retrieval

    return Retrieval(Retrieval.Options(**options))


def _fit(dataset, folder: Path, **options) -> Path:
    return _method(**options).fit(TrainingContext(dataset, TRAINER, folder, "", None, quiet=True))


@pytest.fixture(scope="module")
def tiny(tmp_path_factory, data_cache):
    """The tiny synthetic dataset (the session's preprocessed cache), its index and a method
    that loaded it."""
    root = tmp_path_factory.mktemp("retrieval")
    dataset = _dataset(_settings(root, data_cache))
    method = _method()
    path = _fit(dataset, root / "train")
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
        # Its own ground truth, every point once, as the index stores it: each point within
        # the 16-bit storage's rounding of the dataset's.
        stored = method.index.cloud(position)
        assert np.array_equal(_rows(out.points), _rows(stored))
        assert np.abs(stored - gt).max() <= STORED_ERROR
        assert np.abs(stored - gt).max() > 0  # rounded, not copied: the test can tell
        assert nearest_distances(out.points, gt).max() <= np.sqrt(3) * STORED_ERROR


def test_a_test_object_gets_the_nearest_training_shape_whole(tiny):
    dataset, method, _ = tiny
    index = method.index
    clouds = [index.cloud(i) for i in range(len(index))]
    assert len(clouds) == len(dataset.objects(TRAIN))
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


def test_ties_go_to_the_lowest_index_and_the_search_is_exact(tmp_path):
    from shapebench_retrieval.index import RetrievalIndex, write_index

    rng = np.random.default_rng(0)
    shapes = [rng.normal(size=(300, 3)) * s for s in (0.3, 0.5, 0.4, 0.5, 0.6)]
    shapes[3] = shapes[1].copy()  # an exact duplicate: equal scores
    entries = [(f"s/{i}", "s", shape) for i, shape in enumerate(shapes)]
    index = RetrievalIndex.load(write_index(entries, 1000, tmp_path).path)
    stored = [index.cloud(i) for i in range(5)]  # the search points: every stored point here
    for k in (1, 33, 200, 1000):  # one chunk, two, several
        q = (rng.normal(size=(k, 3)) * 0.5).astype(np.float32)
        scores = [np.mean(nearest_distances(q, s) ** 2) for s in stored]
        best, score, _ = index.nearest(q)
        assert best == int(np.argmin(scores)) and score == pytest.approx(min(scores), rel=1e-12)
    best, _, _ = index.nearest(stored[1][:40])
    assert best == 1  # shape 3 scores exactly the same


def test_the_16_bit_storage_keeps_every_point_within_half_a_step(tmp_path):
    from shapebench_retrieval.index import dequantize, quantize

    rng = np.random.default_rng(1)
    for points in (rng.uniform(-1, 1, (5000, 3)), rng.normal(size=(100, 3)) * 30, np.ones((4, 3))):
        codes, low, step = quantize(points)
        assert codes.dtype == np.int16
        back = dequantize(codes, low, step)
        side = points.max(0) - points.min(0)
        # half a step of the box side, plus float32's rounding of the result
        limit = side / 65535 / 2 + np.abs(points).max(0) * 2**-23
        assert np.all(np.abs(back - points) <= limit + 1e-12)
    flat = np.zeros((3, 3))
    assert np.array_equal(dequantize(*quantize(flat)), flat)


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
    # A second indexing of the same data gives the same files, whatever the trainer's seed.
    seeded = TrainingContext(dataset, TrainerOptions(seed=5), tmp_path, "", None, quiet=True)
    rebuilt = _method().fit(seeded)
    with np.load(path) as a, np.load(rebuilt) as b:
        assert sorted(a.files) == sorted(b.files)
        assert all(np.array_equal(a[k], b[k]) for k in a.files)
    clouds = sorted(p.name for p in path.parent.glob("clouds-*.bin"))
    assert clouds == sorted(p.name for p in tmp_path.glob("clouds-*.bin")) and len(clouds) == 1
    assert (path.parent / clouds[0]).read_bytes() == (tmp_path / clouds[0]).read_bytes()


def test_a_moved_index_serves_without_the_data(tiny, data_cache, tmp_path):
    """Built from a cache that is then deleted, moved to another folder: it loads and completes
    as before (nothing in it names a path)."""
    dataset, method, _ = tiny
    cache = tmp_path / "cache"
    shutil.copytree(data_cache, cache)
    own = _dataset(_settings(tmp_path, cache))
    built = _fit(own, tmp_path / "built")
    shutil.rmtree(cache)
    moved = tmp_path / "elsewhere" / "key"
    shutil.move(tmp_path / "built", moved)
    with np.load(moved / built.name) as z:
        text = " ".join(str(z[k]) for k in z.files if z[k].dtype.kind == "U")
    assert str(tmp_path) not in text and str(data_cache) not in text
    served = _method()
    served.load_checkpoint(moved / built.name)
    for split in (TRAINED, NOVEL):
        ctx, gt = _context(dataset, dataset.objects(split)[0], 100)
        a, b = method.complete(ctx, len(gt)), served.complete(ctx, len(gt))
        assert np.array_equal(a.points, b.points) and a.info == b.info


def test_a_damaged_or_mismatched_index_is_one_error_on_load(tiny, tmp_path):
    from shapebench_retrieval.index import RetrievalIndex

    _, _, path = tiny
    folder = tmp_path / "copy"
    shutil.copytree(path.parent, folder)
    index = folder / path.name
    (clouds,) = folder.glob("clouds-*.bin")
    # The method's own option differs from the index's.
    with pytest.raises(ShapebenchError, match="built with index_points=2048.*has 512") as err:
        _method(index_points=512).load_checkpoint(index)
    assert str(folder) in err.value.hint
    # The clouds file cut short, then gone.
    data = clouds.read_bytes()
    clouds.write_bytes(data[:-6])
    with pytest.raises(ShapebenchError, match=rf"{clouds.name} beside it, which has \d+ bytes"):
        RetrievalIndex.load(index)
    clouds.unlink()
    with pytest.raises(ShapebenchError, match="which is missing"):
        RetrievalIndex.load(index)
    # Its bytes changed, at the same size: the shape read is refused (an object's failure).
    changed = bytearray(data)
    changed[7] ^= 0xFF
    clouds.write_bytes(bytes(changed))
    loaded = RetrievalIndex.load(index)
    with pytest.raises(RuntimeError, match="no longer holds training shape"):
        loaded.cloud(0)
    assert loaded.cloud(1).shape[1] == 3  # the others still serve
    # Arrays that do not match their meta, and an index of the old format.
    with np.load(index) as z:
        arrays = {k: z[k] for k in z.files}
    meta = json.loads(str(arrays["meta"]))
    np.savez(tmp_path / "short.npz", **{**arrays, "ids": arrays["ids"][:-1]})
    with pytest.raises(ShapebenchError, match=f"has {meta['shapes'] - 1} rows of 'ids'"):
        RetrievalIndex.load(tmp_path / "short.npz")
    np.savez(tmp_path / "old.npz", **{**arrays, "format": np.array("shapebench-retrieval-index-1")})
    with pytest.raises(ShapebenchError, match="not a retrieval index of format"):
        RetrievalIndex.load(tmp_path / "old.npz")
    assert meta["training_fingerprint"] and meta["dataset"] == "synthetic"


def test_the_keys_follow_the_training_objects_and_no_trainer_setting(tmp_path):
    from shapebench.evaluation.plan import RunPlan, planned_cells
    from shapebench.registry.discovery import get_registry
    from shapebench.registry.resolve import resolve_method
    from shapebench.train.ticket import training_ticket

    settings = _settings(tmp_path, tmp_path / "cache")
    method = resolve_method(get_registry(), "retrieval", settings)
    assert method.cls.trains and method.cls.fit_ignores_trainer

    def keys(trainer=TRAINER, **changes) -> tuple[str, str]:
        data = _dataset(settings, **changes)
        ticket = training_ticket(method, data, trainer, settings)
        assert ticket.identity == {}  # no trainer setting in the key or the row
        plan = RunPlan(method, data, [TRAINED], [50], [0], [], checkpoint=ticket.cell_checkpoint())
        return ticket.key, planned_cells(plan, TRAINED)[0][3]

    base = keys()
    assert keys() == base
    more_training = keys(train_per_category=2)
    assert more_training[0] != base[0] and more_training[1] != base[1]
    # More test objects: the same index (checkpoint key), other cells (another evaluated set).
    more_tests = keys(test_per_category=2)
    assert more_tests[0] == base[0] and more_tests[1] != base[1]
    # One index for every seed, budget, precision and device count.
    for trainer in (
        TrainerOptions(accelerator="cpu", seed=1),
        TrainerOptions(accelerator="cpu", max_epochs=3, max_steps=7, precision="16-mixed"),
        TrainerOptions(accelerator="cpu", devices=4, num_nodes=2),
    ):
        assert keys(trainer) == base
    # The index's own option is in the key.
    finer = resolve_method(get_registry(), "retrieval", settings, {"index_points": 512})
    assert training_ticket(finer, _dataset(settings), TRAINER, settings).key != base[0]


def test_trainer_settings_stay_in_the_key_of_a_learned_method(tmp_path):
    """The rule is the attribute's, not every method's: a trained network's key still moves
    with its seed and budget."""
    from shapebench.registry.discovery import get_registry
    from shapebench.registry.resolve import resolve_method
    from shapebench.train.ticket import training_ticket

    settings = _settings(tmp_path, tmp_path / "cache")
    igr = resolve_method(get_registry(), "igr", settings)
    assert not igr.cls.fit_ignores_trainer
    data = _dataset(settings)
    ticket = training_ticket(igr, data, TRAINER, settings)
    assert {"seed", "precision", "world_size"} <= set(ticket.identity)
    seeded = TrainerOptions(accelerator="cpu", seed=1)
    assert training_ticket(igr, data, seeded, settings).key != ticket.key


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
    res = shapebench(*args, "--seeds", "0,1", "--max-epochs", "3")
    assert res.returncode == 0, res.stdout + res.stderr
    assert res.stderr.count("retrieval: indexed 11 training shapes") == 1  # once for both seeds
    cells = shapebench.cell_runs("synthetic-trained")
    assert {int(c.data.tags["seed"]) for c in cells} == {0, 1}
    assert len({c.data.tags["checkpoint_key"] for c in cells}) == 1
    # One label: its training data (TINY's), not the trainer's settings (--max-epochs changes
    # no index).
    assert {c.data.tags["variant.label"] for c in cells} == {"retrieval[train_per_category=1]"}
    # The index build's cost, logged on its training run as a training's summary is.
    (training,) = {c.data.tags["training_run_id"] for c in cells}
    run = shapebench.client().get_run(training)
    assert run.data.metrics["summary/wall_seconds"] > 0
    assert run.data.metrics["summary/training_shapes"] == 11
    assert run.data.tags["training_device"] == "cpu x1"
    again = shapebench(*args, "--seeds", "0,1")
    assert again.returncode == 0 and "cached" in again.stdout
