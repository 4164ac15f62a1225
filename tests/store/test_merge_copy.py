"""A merged run is its source run: tags, params, every metric value with its step and timestamp,
times, status and artifacts, whichever way merge reads and writes them (a real SQLite store).

Merge reads metric histories with one query per metric key from an SQL store and copies a local
artifact folder directly; a store without the bulk query (or a query that may have been cut),
and artifacts kept elsewhere, go through MLflow's per-run calls. Both ways must copy the same."""

from __future__ import annotations

from pathlib import Path

import pytest

from shapebench.config import make_settings
from shapebench.store import merge
from shapebench.store import records as rec
from shapebench.store.tracking import Tracker

PARAMS = 130  # more than one batch's 100 params
STEPS = 950  # with the other metrics, more than one batch's 900 metric values


def _tracker(workspace: Path) -> Tracker:
    return Tracker(
        make_settings(f"sqlite:///{workspace / 'mlflow.db'}", workspace / "cache", None, workspace)
    )


def _fill(tracker: Tracker, tmp: Path) -> list[str]:
    exp = tracker.experiment_id("synthetic-novel")
    tags = {rec.KIND_TAG: rec.TRAINING_KIND, rec.CHECKPOINT_KEY_TAG: "ckpt"}
    training = tracker.start_run(exp, "training", tags)
    tracker.log_params(training, {f"option{i}": i for i in range(PARAMS)})
    for step in range(STEPS):
        tracker.log_metrics(training, {"loss": 1.0 / (step + 1)}, step=step)
    tracker.log_metrics(training, {"summary/seconds": 12.5}, step=STEPS)
    folder = tmp / "training-files"
    (folder / "curves").mkdir(parents=True)
    (folder / "curves" / "loss.csv").write_text("step,loss\n0,1.0\n")
    (folder / "summary.json").write_text('{"seconds": 12.5}')
    tracker.client.log_artifacts(training, str(folder))
    tracker.end(training)
    cells = []
    for seed in range(3):
        record = rec.CellRecord(f"key{seed}", "igr", "synthetic", "novel", 50, seed)
        cell = tracker.start_run(
            exp, f"cell{seed}", {**record.to_tags(), rec.TRAINING_RUN_TAG: training}
        )
        tracker.log_params(cell, {"method.lr": 0.001, "seed": seed})
        tracker.log_metrics(cell, {"chamfer-l2.mean": 1.5 + seed, "failures": 0.0}, step=50)
        csv = tmp / f"cell{seed}" / "per_object.csv"
        csv.parent.mkdir()
        csv.write_text(f"object,chamfer-l2\nchair/test-000,{1.5 + seed}\n")
        tracker.log_artifact(cell, csv)
        tracker.end(cell)
        cells.append(cell)
    return [training, *cells]


def _files(tracker: Tracker, run_id: str, tmp: Path) -> dict[str, bytes]:
    root = Path(tracker.client.download_artifacts(run_id, "", str(tmp)))
    return {
        str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()
    }


def _history(tracker: Tracker, run_id: str, key: str) -> list[tuple]:
    values = tracker.client.get_metric_history(run_id, key)
    return sorted((m.step, m.timestamp, m.value) for m in values)


@pytest.mark.parametrize("way", ["bulk-and-folder", "per-run-and-mlflow"])
def test_a_merged_run_is_its_source_run(tmp_path, monkeypatch, way):
    if way == "per-run-and-mlflow":
        import shapebench.store.tracking as tracking

        monkeypatch.setattr(merge, "_BULK_LIMIT", 2)  # every bulk answer may have been cut
        monkeypatch.setattr(tracking, "local_artifact_path", lambda uri, name="": None)
    source, target = _tracker(tmp_path / "source"), _tracker(tmp_path / "target")
    runs = _fill(source, tmp_path)
    target.experiment_id("synthetic-novel")  # the target store exists, empty

    report = merge.merge_stores(
        [str(tmp_path / "source")], target.settings.tracking_uri, echo=lambda _: None
    )
    assert report.added == {rec.TRAINING_KIND: 1, rec.CELL_KIND: 3}

    copies = {}
    for exp in target.client.search_experiments():
        for run in target.client.search_runs([exp.experiment_id]):
            origin = run.data.tags[merge.MERGED_FROM].rpartition("#")[2]
            copies[origin] = run
    assert sorted(copies) == sorted(runs)
    training_copy = copies[runs[0]].info.run_id
    for run_id in runs:
        was, now = source.client.get_run(run_id), copies[run_id]
        assert now.data.params == was.data.params
        assert now.data.metrics == was.data.metrics
        for key in was.data.metrics:
            assert _history(target, now.info.run_id, key) == _history(source, run_id, key), key
        tags = {k: v for k, v in now.data.tags.items() if k != merge.MERGED_FROM}
        if rec.TRAINING_RUN_TAG in was.data.tags:  # re-pointed at the target's training
            assert tags.pop(rec.TRAINING_RUN_TAG) == training_copy
            assert was.data.tags.pop(rec.TRAINING_RUN_TAG) == runs[0]
        assert tags == was.data.tags
        assert (now.info.status, now.info.start_time, now.info.end_time) == (
            was.info.status,
            was.info.start_time,
            was.info.end_time,
        )
        assert _files(target, now.info.run_id, tmp_path / f"t-{run_id}") == _files(
            source, run_id, tmp_path / f"s-{run_id}"
        )
    assert len(_history(target, training_copy, "loss")) == STEPS
    assert set(_files(target, training_copy, tmp_path / "again")) == {
        "curves/loss.csv",
        "summary.json",
    }
