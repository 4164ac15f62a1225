"""The runner's pieces one at a time: cell keys, a finished cell found again, a failed object among
scored ones, the ranking of failure reasons, and the checks of context sizes.

Everything here is the real thing: an MLflow store (sqlite) in a temporary workspace, the ``gauss``
method, and the synthetic dataset at the tiny options of the CLI tests (``conftest.TINY``). A new
store costs seconds (its schema is migrated); one is made per module and each test gets a copy.
"""

from __future__ import annotations

import math
import shutil
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from conftest import TINY

from shapebench.api.contexts import ContextStore
from shapebench.api.errors import ShapebenchError
from shapebench.api.options import parse_assignments
from shapebench.api.protocol import Protocol
from shapebench.config import Settings, make_settings
from shapebench.evaluation.failures import (
    distinct_errors,
    failure_reasons,
    metric_errors,
    not_applicable_reasons,
)
from shapebench.evaluation.objects import ObjectCache, check_context_sizes
from shapebench.evaluation.pictures import picture_arrays, picture_png
from shapebench.evaluation.plan import RunPlan, cell_config, planned_cells, validate_contexts
from shapebench.evaluation.runner import Runner
from shapebench.hashing import stable_hash
from shapebench.registry.discovery import get_registry
from shapebench.registry.resolve import resolve_dataset, resolve_method, resolve_metrics
from shapebench.registry.variant import make_variant
from shapebench.store.tracking import Tracker, experiment_name

#: ``conftest.TINY`` (``-D key=value`` pairs for the CLI) as dataset options.
TINY_OPTIONS = parse_assignments(TINY[1::2], "-D")
#: The cell key of the plan below (gauss, synthetic/novel, k=50, seed 0, chamfer-l2) with its
#: method and dataset parts replaced by placeholders: what the runner itself puts in a key. The
#: value was computed before the runner was split into modules. If it changes, every stored
#: cell is computed again: change it on purpose only.
PINNED_KEY = "e6bb8c873a85d55e"
#: The same with a checkpoint key, training settings and shipped weights.
PINNED_TRAINED_KEY = "53890b82af3865df"


def _plan(
    settings: Settings,
    method_opts: dict | None = None,
    dataset_opts: dict | None = None,
    metrics: tuple[str, ...] = ("chamfer-l2",),
    **fields,
) -> RunPlan:
    """Gauss on the tiny synthetic dataset: one cell (novel, k=50, seed 0) unless ``fields``
    say otherwise."""
    registry = get_registry()
    method = resolve_method(registry, "gauss", settings, method_opts or {})
    dataset = resolve_dataset(
        registry, "synthetic", settings, None, TINY_OPTIONS, dataset_opts or {}
    )
    fields = {"splits": ["novel"], "contexts": [50], "seeds": [0], "quiet": True} | fields
    return RunPlan(method, dataset, metrics=resolve_metrics(registry, list(metrics)), **fields)


def _keys(plan: RunPlan, split: str = "novel") -> list[str]:
    return [key for *_, key in planned_cells(plan, split)]


class Factory:
    """A method factory that counts how often the runner asked for the method."""

    def __init__(self, make) -> None:
        self.make = make
        self.calls = 0

    def __call__(self):
        self.calls += 1
        return self.make()


@pytest.fixture
def paths(tmp_path: Path, data_cache: Path) -> Settings:
    """Settings for resolving names and computing keys; nothing is written to the store."""
    return make_settings(f"sqlite:///{tmp_path / 'mlflow.db'}", data_cache, "quick", tmp_path)


@pytest.fixture(scope="module")
def empty_store(tmp_path_factory) -> Path:
    """The folder of an MLflow store whose schema is made, and which holds no run."""
    ws = tmp_path_factory.mktemp("empty-store")
    Tracker(make_settings(f"sqlite:///{ws / 'mlflow.db'}", ws / "cache", "quick", ws))
    return ws


@pytest.fixture(scope="module")
def prepared(tmp_path_factory, data_cache: Path) -> Path:
    """The session's data cache with the objects of the tiny dataset's novel split prepared, and
    matplotlib loaded by a first picture, so that the tests below time their own work, not the
    one-off preprocessing and imports."""
    ws = tmp_path_factory.mktemp("prepare")
    dataset = _plan(make_settings(f"sqlite:///{ws / 'unused.db'}", data_cache, "quick", ws)).dataset
    for ref in dataset.objects("novel"):
        points = dataset.load(ref).surface_points[:100]
    picture_png(picture_arrays(points, points, points, None), "warm-up")
    return data_cache


@pytest.fixture
def settings(tmp_path: Path, empty_store: Path, prepared: Path) -> Settings:
    """A workspace of this test's own with an empty store, and the session's data cache."""
    ws = tmp_path / "ws"
    ws.mkdir()
    for db in empty_store.glob("mlflow.db*"):
        shutil.copy(db, ws / db.name)
    return make_settings(f"sqlite:///{ws / 'mlflow.db'}", prepared, "quick", ws)


# ------------------------------------------------------------------------------------ cell keys


def test_cell_keys_are_stable(paths):
    plan = _plan(paths)
    cells = planned_cells(plan, "novel")
    assert [(seed, size) for seed, size, _, _ in cells] == [(0, 50)]
    _, _, cfg, key = cells[0]
    assert key == stable_hash(cfg) == stable_hash(cell_config(plan, "novel", 50, 0, 2000))
    assert cfg["method"] == plan.method.config() and cfg["dataset"] == plan.dataset.config()
    # What the runner adds around the method's and the dataset's own parts.
    runner_part = {**cfg, "method": "<method>", "dataset": "<dataset>"}
    assert stable_hash(runner_part) == PINNED_KEY, runner_part
    trained = _plan(paths, checkpoint={"key": "ckpt", "training": {"epochs": 3}, "weights": "w1"})
    _, _, cfg, _ = planned_cells(trained, "novel")[0]
    assert stable_hash({**cfg, "method": "<method>", "dataset": "<dataset>"}) == (
        PINNED_TRAINED_KEY
    )
    # Locally trained weights (no "weights") keep the keys they had before shipped ones existed.
    _, _, local, _ = planned_cells(_plan(paths, checkpoint={"key": "ckpt"}), "novel")[0]
    assert "weights" not in local and local["checkpoint"] == "ckpt"

    # Resolved again (another process), the keys are the same; the order and repeats of the
    # context sizes, the row's label, --force and --quiet are not part of them.
    again = _plan(paths, contexts=[100, 50, 50], seeds=[1, 0])
    again.variant = make_variant(
        "gauss", plan.method.config(), {}, plan.protocol, "quick", label="mine"
    )
    again.force, again.quiet = True, False
    cells = planned_cells(again, "novel")
    assert [(seed, size) for seed, size, _, _ in cells] == [(1, 50), (1, 100), (0, 50), (0, 100)]
    assert cells[2][3] == key


def test_every_part_of_a_cell_config_is_in_its_key(paths):
    base = _keys(_plan(paths))[0]
    changed = {
        "method option": _keys(_plan(paths, method_opts={"sigma": 0.05})),
        "dataset option": _keys(_plan(paths, dataset_opts={"viewpoints": 50})),
        "evaluation points": _keys(_plan(paths, dataset_opts={"gt_points": 1500})),
        "split": _keys(_plan(paths), "trained")[:1],
        "context size": _keys(_plan(paths, contexts=[100])),
        "seed": _keys(_plan(paths, seeds=[1])),
        "metrics": _keys(_plan(paths, metrics=("chamfer-l2", "chamfer-l1"))),
        "frame": _keys(_plan(paths, protocol=Protocol(frame="unit-diameter"))),
        "context normals": _keys(_plan(paths, protocol=Protocol(context_normals=True))),
        "crop protocol": _keys(_plan(paths, protocol=Protocol(context="crop", crop_fraction=0.5))),
        "context noise": _keys(_plan(paths, protocol=Protocol(context_noise=0.01))),
        "checkpoint": _keys(_plan(paths, checkpoint={"key": "a"})),
        "other checkpoint": _keys(_plan(paths, checkpoint={"key": "b"})),
        "training": _keys(_plan(paths, checkpoint={"key": "a", "training": {"epochs": 3}})),
        "shipped weights": _keys(_plan(paths, checkpoint={"key": "a", "weights": "w"})),
    }
    assert all(len(keys) == 1 for keys in changed.values()), changed
    keys = {part: keys[0] for part, keys in changed.items()}
    assert base not in keys.values(), [part for part, key in keys.items() if key == base]
    assert len(set(keys.values())) == len(keys), keys


# ---------------------------------------------------------------------------------- the runner


def test_a_finished_cell_is_found_and_not_computed_again(settings):
    plan = _plan(settings)
    first = Factory(plan.method.instantiate)
    [cell] = Runner(Tracker(settings), echo=lambda _: None).run(plan, first)
    assert first.calls == 1 and not cell.skipped
    assert cell.n_objects == 4 and cell.n_ok == 4 and cell.metrics["chamfer-l2.mean"] > 0

    # A new process (a new tracker on the same store) finds it by its key: nothing is computed,
    # the method is not even made, and the result is the stored one.
    tracker = Tracker(settings)
    again = Factory(plan.method.instantiate)
    lines: list[str] = []
    [found] = Runner(tracker, echo=lines.append).run(_plan(settings), again)
    assert again.calls == 0 and found.skipped
    assert found.run_id == cell.run_id
    assert found.metrics["chamfer-l2.mean"] == cell.metrics["chamfer-l2.mean"]
    assert found.cards == cell.cards
    assert len(lines) == 1 and "4 objects" in lines[0]  # announced, nothing else
    exp_id = tracker.experiment_id(experiment_name("synthetic", "novel"))
    [key] = _keys(plan)
    assert Runner(tracker).finished(plan, exp_id, key).run_id == cell.run_id
    plan.force = True  # --force: the finished cell does not count
    assert Runner(tracker).finished(plan, exp_id, key) is None


def test_a_failed_object_is_recorded_and_the_others_are_scored(settings):
    plan = _plan(settings)
    ids = [ref.id for ref in plan.dataset.objects("novel")]
    assert len(ids) == 4
    raising, nan = ids[1], ids[3]

    class Flaky(plan.method.cls):
        """Gauss, except that one object raises and another gets NaN points."""

        def complete(self, context, n_points):
            if context.ref.id == raising:
                raise RuntimeError(f"cannot complete {context.ref.id}")
            completion = super().complete(context, n_points)
            if context.ref.id == nan:
                completion.points[:7] = np.nan
            return completion

    tracker = Tracker(settings)
    [cell] = Runner(tracker, echo=lambda _: None).run(plan, lambda: Flaky(plan.method.options))
    assert not cell.skipped
    assert cell.metrics["n_objects"] == 4 and cell.metrics["failures"] == 2 and cell.n_ok == 2
    assert sorted(cell.reasons) == [
        (f"RuntimeError: cannot complete {raising}", 1),
        ("completion has 7 NaN/inf points", 1),
    ]
    assert "Traceback" in cell.tracebacks[f"RuntimeError: cannot complete {raising}"]

    path = tracker.client.download_artifacts(cell.run_id, "per_object.csv", str(settings.cache_dir))
    table = pd.read_csv(path, keep_default_na=False, na_values=[""]).set_index("object")
    assert list(table.index) == ids  # every object has its row, failed or not
    assert table.loc[raising, "status"] == table.loc[nan, "status"] == "failed"
    assert "cannot complete" in table.loc[raising, "traceback"]
    assert math.isnan(table.loc[raising, "chamfer-l2"]) and math.isnan(table.loc[nan, "chamfer-l2"])
    ok = table[table["status"] == "ok"]
    assert sorted(ok.index) == sorted(set(ids) - {raising, nan})
    assert (ok["chamfer-l2"] > 0).all() and (ok["n_points"] == 2000).all()
    # The cell's numbers are the scored objects', and they are stored on the run.
    assert cell.metrics["chamfer-l2.mean"] == pytest.approx(ok["chamfer-l2"].mean())
    assert cell.metrics["chamfer-l2.median"] == pytest.approx(ok["chamfer-l2"].median())
    stored = tracker.find_cell(cell.experiment_id, _keys(plan)[0])
    assert stored.run_id == cell.run_id and stored.metrics["failures"] == 2
    assert stored.metric_errors == frozenset()  # the method failed, no metric did


def test_a_cell_pictures_its_worst_success_beside_the_fixed_objects(settings):
    """The fixed objects are pictured in every cell; the worst scored object of the cell is too,
    so a report can show a row's failures (a failed object has no completion to picture)."""
    from shapebench.evaluation.pictures import file_stem, picture_objects

    plan = _plan(settings)
    ids = [ref.id for ref in plan.dataset.objects("novel")]
    fixed = set(picture_objects(ids))
    others = [i for i in ids if i not in fixed]
    assert others, "the tiny split pictures every object: nothing to test"
    bad = others[-1]

    class Scrambled(plan.method.cls):
        """Gauss, except that one unpictured object gets its points thrown far away."""

        def complete(self, context, n_points):
            completion = super().complete(context, n_points)
            if context.ref.id == bad:
                completion.points = completion.points * 5.0
            return completion

    tracker = Tracker(settings)
    [cell] = Runner(tracker, echo=lambda _: None).run(plan, lambda: Scrambled(plan.method.options))
    listed = {a.path for a in tracker.client.list_artifacts(cell.run_id, "pictures")}
    expected = {f"pictures/{file_stem(i)}.png" for i in {*fixed, bad}}
    assert expected <= listed
    assert not {f"pictures/{file_stem(i)}.png" for i in set(others) - {bad}} & listed


def test_failure_reasons_are_ranked_by_how_many_objects_share_them():
    table = pd.DataFrame(
        {
            "object": [f"o{i}" for i in range(9)],
            "status": ["failed"] * 6 + ["ok"] * 3,
            "error": [
                "ValueError: empty mesh",
                "OSError: unreadable\nsecond line",
                "ValueError: empty mesh",
                "OSError: unreadable\nanother second line",
                "ValueError: empty mesh",
                float("nan"),  # no message (an empty cell read back from the CSV)
                "",
                "",
                "",
            ],
            "traceback": ["tb-empty-1", "tb-unreadable", "tb-empty-2", *[""] * 4, "tb-iou", ""],
            "metric_error.iou": [""] * 7 + ["RuntimeError: no mesh", "RuntimeError: no mesh"],
            "not_applicable.normal-consistency": [""] * 6 + ["points only"] * 2 + [""],
        }
    )
    ranked = distinct_errors(table)
    assert [(reason, n) for reason, n, _ in ranked] == [
        ("ValueError: empty mesh", 3),
        ("OSError: unreadable", 2),  # the first line only: the rest is the traceback's
        ("metric iou: RuntimeError: no mesh", 2),
        ("unknown", 1),
    ]
    # Each reason keeps the traceback of its first object; ties keep the order they came in.
    assert [t for _, _, t in ranked] == ["tb-empty-1", "tb-unreadable", "tb-iou", ""]
    assert failure_reasons(table) == [(reason, n) for reason, n, _ in ranked]
    assert failure_reasons(table, top=2) == [
        ("ValueError: empty mesh", 3),
        ("OSError: unreadable", 2),
    ]
    assert metric_errors(table) == ["iou"]
    # Not applying is no failure: it is counted apart, with its reason.
    assert not_applicable_reasons(table) == [("normal-consistency", "points only", 2)]
    # A long message is cut; a table of successes has no reason.
    table.loc[0, "error"] = "E: " + "x" * 500
    assert max(len(reason) for reason, _ in failure_reasons(table)) == 200
    ok = pd.DataFrame({"object": ["a"], "status": ["ok"], "error": [""]})
    assert failure_reasons(ok) == [] and metric_errors(ok) == []


# ------------------------------------------------------------------------------- context sizes


def test_context_sizes_are_positive_integers_sorted_once():
    assert validate_contexts([300, 50, 100, 50]) == [50, 100, 300]
    with pytest.raises(ShapebenchError, match="no context sizes given") as caught:
        validate_contexts([])
    assert "--contexts" in caught.value.hint
    with pytest.raises(ShapebenchError, match=r"positive integers, got \[0, -5, 2.5\]"):
        validate_contexts([50, 0, -5, 2.5])


def test_a_context_size_no_object_can_give_is_refused_before_any_cell(settings):
    plan = _plan(settings, contexts=[50, 100_000])
    factory = Factory(plan.method.instantiate)
    tracker = Tracker(settings)
    with pytest.raises(ShapebenchError) as caught:
        Runner(tracker, echo=lambda _: None).run(plan, factory)
    # Refused before any work: no method, and not even the cell that fits was computed.
    assert factory.calls == 0
    exp_id = tracker.experiment_id(experiment_name("synthetic", "novel"))
    assert all(tracker.find_cell(exp_id, key) is None for key in _keys(plan))
    message = caught.value.message
    assert message.startswith("context size 100000 is larger than the ")
    assert message.endswith("(synthetic/novel)")
    # The object named is the one with the fewest points, and the hint says how many.
    visible = {
        r.id: len(plan.dataset.load(r).surface_points) for r in plan.dataset.objects("novel")
    }
    fewest = min(visible.values())
    assert f"the {fewest} visible surface points of object" in message
    assert any(f"object {obj!r}" in message for obj, n in visible.items() if n == fewest)
    assert caught.value.hint.startswith(f"use context sizes up to {fewest},")
    # Exactly as many points as the poorest object has is allowed; one more is not.
    refs, protocol = plan.dataset.objects("novel"), plan.protocol
    store = ContextStore(plan.dataset.cache_root, plan.dataset.data_fingerprint())
    cache = ObjectCache(plan.dataset)
    check_context_sizes(refs, cache, [50, fewest], True, "novel", protocol, store)
    with pytest.raises(ShapebenchError, match=f"context size {fewest + 1} is larger"):
        check_context_sizes(refs, cache, [fewest + 1], True, "novel", protocol, store)
    # Under the crop protocol the limit is what the crop leaves of the ground truth.
    crop = _plan(settings, contexts=[1999], protocol=Protocol(context="crop", crop_fraction=0.5))
    with pytest.raises(ShapebenchError, match="ground-truth points a crop of 0.5 leaves of object"):
        Runner(tracker, echo=lambda _: None).run(crop, factory)
    assert factory.calls == 0
