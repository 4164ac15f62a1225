"""A run's dataset input (the MLflow UI's Dataset column) when two workers log the same dataset
at once: MLflow's store looks the dataset up, finds none, and both insert it; the second insert
breaks the datasets table's unique key. Seen in a fresh clone's quickstart (two local workers):
the worker died with a traceback. The second logger must link the existing dataset instead."""

from __future__ import annotations

import pytest
from test_paging import settings_of

from shapebench.store import records as rec
from shapebench.store.tracking import Tracker

DATASET = dict(
    name="synthetic/novel",
    digest="980bb99bf0842382",
    source={"dataset": "synthetic"},
    profile={"objects": 16},
    context="sparse",
)


def _cell(tracker: Tracker, exp: str, seed: int) -> str:
    record = rec.CellRecord(f"key{seed}", "gauss", "synthetic", "novel", 50, seed)
    return tracker.start_run(exp, f"cell{seed}", record.to_tags())


def test_a_dataset_another_worker_inserted_first_is_linked_not_a_crash(tmp_path, monkeypatch):
    tracker = Tracker(settings_of(tmp_path))
    exp = tracker.experiment_id("synthetic-novel")
    other, mine = _cell(tracker, exp, 0), _cell(tracker, exp, 1)
    real = tracker.client.log_inputs
    calls = []

    def other_worker_wins_the_race(run_id, datasets=None, **kw):
        calls.append(run_id)
        if len(calls) == 1:  # the other worker inserts between our look-up and our insert
            real(other, datasets=datasets, **kw)
            # What MLflow's SQLAlchemy store raises for our insert then (its words).
            from mlflow.exceptions import MlflowException

            raise MlflowException(
                "(sqlite3.IntegrityError) UNIQUE constraint failed: datasets.experiment_id, "
                "datasets.name, datasets.digest"
            )
        return real(run_id, datasets=datasets, **kw)

    monkeypatch.setattr(tracker.client, "log_inputs", other_worker_wins_the_race)
    tracker.log_dataset(mine, **DATASET)
    assert calls == [mine, mine]
    for run in (other, mine):
        inputs = tracker.client.get_run(run).inputs.dataset_inputs
        assert [(d.dataset.name, d.dataset.digest) for d in inputs] == [
            ("synthetic/novel", "980bb99bf0842382")
        ]


def test_any_other_failure_to_log_the_dataset_is_raised(tmp_path, monkeypatch):
    from mlflow.exceptions import MlflowException

    tracker = Tracker(settings_of(tmp_path))
    mine = _cell(tracker, tracker.experiment_id("synthetic-novel"), 0)

    def broken(run_id, datasets=None, **kw):
        raise MlflowException("database is locked")

    monkeypatch.setattr(tracker.client, "log_inputs", broken)
    with pytest.raises(MlflowException, match="database is locked"):
        tracker.log_dataset(mine, **DATASET)
