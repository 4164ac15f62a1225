"""`shapebench run` end to end: real synthetic data, real MLflow store, real subprocesses."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
from conftest import TINY, TINY_CONTEXTS

pytestmark = pytest.mark.slow  # every test runs the CLI in a subprocess


def _tags_by_cell(runs):
    return {(r.data.tags["split"], int(r.data.tags["context_size"])): r for r in runs}


def test_run_gauss_logs_every_cell_and_prints_summary(shapebench):
    res = shapebench("run", "--method", "gauss", "--dataset", "synthetic", *TINY, *TINY_CONTEXTS)
    assert res.returncode == 0, res.stderr
    assert "gauss on synthetic/trained: chamfer-l2 x1000" in res.stdout
    assert "gauss on synthetic/novel: chamfer-l2 x1000" in res.stdout
    assert "shapebench ui" in res.stdout and shapebench.tracking_uri in res.stdout

    for split, n_objects in (("trained", 11), ("novel", 4)):
        runs = _tags_by_cell(shapebench.cell_runs(f"synthetic-{split}"))
        assert sorted(k for _, k in runs) == [50, 100]
        run = runs[(split, 50)]
        tags, metrics, params = run.data.tags, run.data.metrics, run.data.params
        assert tags["method"] == "gauss" and tags["dataset"] == "synthetic"
        assert tags["plugin.distribution"] == "shapebench"
        assert "squared" not in tags["card.chamfer-l2"]  # the tag is the machine form
        assert (
            "power=2" in tags["card.chamfer-l2"] and "eval_points=2000" in tags["card.chamfer-l2"]
        )
        assert len(tags["contexts.sha256"]) == 64 and tags["git_commit"]
        assert tags["mlflow.parentRunId"]
        assert params["method.options.sigma"] == "0.01"
        assert metrics["n_objects"] == n_objects and metrics["failures"] == 0
        # The logged mean is the mean of the per-object artifact, read back from MLflow.
        client = shapebench.client()
        path = client.download_artifacts(
            run.info.run_id, "per_object.csv", str(shapebench.workspace)
        )
        table = pd.read_csv(path)
        assert len(table) == n_objects and set(table.status) == {"ok"}
        assert np.isclose(table["chamfer-l2"].mean(), metrics["chamfer-l2.mean"])
        assert (table["n_points"] == 2000).all()  # Gauss fills up to the ground truth's size
        names = {a.path for a in client.list_artifacts(run.info.run_id)}
        assert {"per_object.csv", "contexts.npz", "completions"} <= names
        plys = client.list_artifacts(run.info.run_id, "completions")
        assert plys and all(a.path.endswith(".ply") for a in plys)
    # More context points, closer to the truth (Gauss densification must improve with k).
    trained = _tags_by_cell(shapebench.cell_runs("synthetic-trained"))
    assert (
        trained[("trained", 100)].data.metrics["chamfer-l2.mean"]
        < trained[("trained", 50)].data.metrics["chamfer-l2.mean"]
    )


def test_rerun_skips_finished_cells_and_force_recomputes(shapebench):
    args = ("run", "-m", "gauss", "-d", "synthetic", "--split", "novel", *TINY, "--contexts", "50")
    assert shapebench(*args, "-q").returncode == 0
    again = shapebench(*args, "-q")
    assert again.returncode == 0 and "cached" in again.stdout
    assert len(shapebench.cell_runs("synthetic-novel")) == 1
    forced = shapebench(*args, "-q", "--force")
    assert forced.returncode == 0 and "new" in forced.stdout
    assert len(shapebench.cell_runs("synthetic-novel")) == 2
    # A changed option is a different cell: it runs, it is not taken from the cache.
    other = shapebench(*args, "-q", "-O", "sigma=0.02")
    assert other.returncode == 0 and "new" in other.stdout


def test_every_method_sees_the_same_context_points(with_example):
    sb = with_example
    for method in ("gauss", "example-sphere"):
        res = sb("run", "-m", method, "-d", "synthetic", *TINY, *TINY_CONTEXTS, "-q")
        assert res.returncode == 0, res.stderr
    runs = sb.cell_runs("synthetic-trained")
    digests: dict[int, set[str]] = {}
    for r in runs:
        digests.setdefault(int(r.data.tags["context_size"]), set()).add(
            r.data.tags["contexts.sha256"]
        )
    assert set(digests) == {50, 100}
    assert all(len(d) == 1 for d in digests.values()), digests
    # And the stored contexts are nested: the 50 points are the first 50 of the 100.
    client = sb.client()
    by_k = {
        int(r.data.tags["context_size"]): r.info.run_id
        for r in runs
        if r.data.tags["method"] == "gauss"
    }
    arrays = {}
    for k, run_id in by_k.items():
        path = client.download_artifacts(run_id, "contexts.npz", str(sb.workspace / str(k)))
        arrays[k] = np.load(path)
    np.testing.assert_array_equal(arrays[100]["points"][:, :50], arrays[50]["points"])


def test_method_failures_are_recorded_per_object(with_example):
    res = with_example("run", "-m", "example-flaky", "-d", "synthetic", *TINY, "--contexts", "50")
    assert res.returncode == 0, res.stderr
    assert "failed" in res.stdout
    runs = with_example.cell_runs("synthetic-trained")
    assert len(runs) == 1
    run = runs[0]
    client = with_example.client()
    table = pd.read_csv(
        client.download_artifacts(run.info.run_id, "per_object.csv", str(with_example.workspace))
    )
    failed = table[table.status == "failed"]
    assert run.data.metrics["failures"] == len(failed) > 0
    assert run.data.metrics["n_objects"] == len(table) == 11
    assert (table.status == "ok").any()  # the other objects went on
    errors = " ".join(failed.error)
    assert "NaN" in errors and "flaky method gave up" in errors


def test_trainable_method_trains_once_in_its_own_process(with_example):
    sb = with_example
    args = ("run", "-m", "example-template", "-d", "synthetic", *TINY, "--contexts", "50", "-q")
    res = sb(*args)
    assert res.returncode == 0, res.stderr
    client = sb.client()
    train_exp = client.get_experiment_by_name("training/synthetic")
    trainings = client.search_runs([train_exp.experiment_id])
    assert len(trainings) == 1 and trainings[0].info.status == "FINISHED"
    assert trainings[0].data.metrics["train_objects"] == 11  # one per trained category
    cells = sb.cell_runs("synthetic-novel")
    assert cells[0].data.tags["training_run_id"] == trainings[0].info.run_id
    assert list((sb.workspace / "checkpoints" / "example-template").glob("*/done.json"))
    # A new evaluation (other context size) reuses the checkpoint: no second training.
    res = sb("run", "-m", "example-template", "-d", "synthetic", *TINY, "--contexts", "100", "-q")
    assert res.returncode == 0, res.stderr
    assert len(client.search_runs([train_exp.experiment_id])) == 1
