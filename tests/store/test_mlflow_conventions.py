"""What a run leaves in MLflow beyond its numbers: the standard tags the UI shows (user, source,
commit), versions and hardware, the evaluated dataset as a run input, the parent run's metrics
with step = context size (one line per variant in the chart view), names that tell variants
and forced reruns apart, notes with the summary, and no stray "Default" experiment or ./mlruns.
"""

from __future__ import annotations

import json

import mlflow
import pytest
from conftest import TINY, Shapebench

from shapebench.config import make_settings
from shapebench.store.listing import list_runs
from shapebench.store.presentation import training_link
from shapebench.store.provenance import git_commit
from shapebench.store.records import TRAINING_KIND, VIEW_TAG_PREFIX
from shapebench.store.tracking import Tracker, training_experiment_name
from shapebench.store.urls import VIEW_KEY

SPLIT = ["--split", "novel", "--contexts", "50,100", "-q"]


@pytest.fixture(scope="module")
def store(tmp_path_factory, data_cache) -> Shapebench:
    """gauss, gauss[sigma=0.05], and a forced rerun of gauss, on the tiny novel split."""
    sb = Shapebench(tmp_path_factory.mktemp("conventions-ws"), data_cache)
    for extra in ([], ["-O", "sigma=0.05"], ["--force"]):
        res = sb("run", "-m", "gauss", "-d", "synthetic", *TINY, *SPLIT, *extra)
        assert res.returncode == 0, res.stderr
    return sb


def _runs(sb: Shapebench, kind: str):
    client = sb.client()
    exp = client.get_experiment_by_name("synthetic-novel")
    return client.search_runs(
        [exp.experiment_id],
        f"tags.`shapebench.kind` = '{kind}'",
        order_by=["attributes.start_time ASC"],
    )


@pytest.mark.slow
def test_cells_carry_standard_tags_versions_hardware_note_and_dataset_input(store):
    cell = _runs(store, "cell")[0]
    tags = cell.data.tags
    assert tags["mlflow.source.name"].startswith("shapebench run -m gauss -d synthetic")
    assert tags["mlflow.source.type"] == "LOCAL"
    assert tags["mlflow.user"]
    commit = git_commit()
    if commit != "unknown":  # a source checkout: the UI links the run to its commit
        assert tags["mlflow.source.git.commit"] == commit.removesuffix("-dirty")
    assert tags["versions.mlflow"] == mlflow.__version__
    assert int(tags["host.cpus"]) >= 1 and tags["host.platform"]
    # The note (the run page's description) is the cell's summary at the card's scale.
    note = tags["mlflow.note.content"]
    mean = cell.data.metrics["chamfer-l2.mean"] * 1000
    assert "| chamfer-l2 |" in note and f"{mean:.3f} ±" in note and "x1000" in note
    # The evaluated objects are the run's dataset input (the UI's Dataset column).
    (given,) = cell.inputs.dataset_inputs
    assert given.dataset.name == "synthetic/novel"
    assert tags["dataset.fingerprint"].startswith(given.dataset.digest)
    assert json.loads(given.dataset.profile)["objects"] == 4
    assert {t.key: t.value for t in given.tags}["mlflow.data.context"] == "novel"


@pytest.mark.slow
def test_parent_metrics_are_its_cells_with_step_context_size(store):
    client = store.client()
    parents = _runs(store, "parent")
    cells = _runs(store, "cell")
    assert len(parents) == 3 and len(cells) == 6
    for parent in parents:
        children = {
            int(c.data.tags["context_size"]): c
            for c in cells
            if c.data.tags["mlflow.parentRunId"] == parent.info.run_id
        }
        assert sorted(children) == [50, 100]
        history = client.get_metric_history(parent.info.run_id, "chamfer-l2.mean")
        assert sorted((m.step, m.value) for m in history) == [
            (k, children[k].data.metrics["chamfer-l2.mean"]) for k in (50, 100)
        ]
        note = parent.data.tags["mlflow.note.content"]
        for child in children.values():  # the summary table links every cell
            assert f"runs/{child.info.run_id})" in note
        assert parent.inputs.dataset_inputs[0].dataset.name == "synthetic/novel"
        assert parent.data.tags["card.chamfer-l2"] == cells[0].data.tags["card.chamfer-l2"]


@pytest.mark.slow
def test_run_names_tell_variants_and_forced_reruns_apart(store):
    names = [p.info.run_name for p in _runs(store, "parent")]
    assert names == [
        "gauss on synthetic/novel",
        "gauss[sigma=0.05] on synthetic/novel",
        "gauss on synthetic/novel (forced rerun)",
    ]
    # One chart color per variant (a forced rerun keeps its variant's), all distinct.
    colors = [p.data.tags["mlflow.runColor"] for p in _runs(store, "parent")]
    assert colors[0] == colors[2] != colors[1]
    cell_names = [c.info.run_name for c in _runs(store, "cell")]
    assert len(set(cell_names)) == 6, cell_names
    assert "gauss[sigma=0.05] k=100 seed=0" in cell_names
    assert "gauss k=50 seed=0 (forced rerun)" in cell_names


@pytest.mark.slow
def test_experiments_have_a_kind_a_view_and_no_default_or_mlruns(store):
    client = store.client()
    active = {e.name: e for e in client.search_experiments()}
    assert set(active) == {"synthetic-novel"}  # MLflow's empty "Default" is gone
    exp = active["synthetic-novel"]
    assert exp.tags["mlflow.experimentKind"] == "custom_model_development"
    assert "step = context size" in exp.tags["mlflow.note.content"]
    view = json.loads(exp.tags[VIEW_TAG_PREFIX + VIEW_KEY])
    assert "metrics.`chamfer-l2.mean`" in view["selectedColumns"]
    # The chart view opens on the primary metric against the step (= context size), log x.
    first = view["compareRunCharts"][0]
    assert (first["type"], first["metricKey"], first["xAxisKey"], first["xAxisScaleType"]) == (
        "LINE",
        "chamfer-l2.mean",
        "step",
        "log",
    )
    assert first["metricSectionId"] == view["compareRunSections"][0]["uuid"]
    assert not (store.workspace / "mlruns").exists()


def test_trainings_of_old_and_new_stores_list_alike(tmp_path):
    """Trainings went to ``<dataset>-train`` before; listing finds them by kind, and the new
    experiment name cannot be taken for a split's."""
    assert training_experiment_name("synthetic") == "training/synthetic"
    assert not training_experiment_name("synthetic").startswith("synthetic-")
    settings = make_settings(workspace=tmp_path / "ws", cache_dir=tmp_path / "cache")
    tracker = Tracker(settings)
    ids = []
    for name in ("synthetic-train", training_experiment_name("synthetic")):
        exp = tracker.experiment_id(name)
        tags = {"shapebench.kind": TRAINING_KIND, "method": "msc", "dataset": "synthetic"}
        ids.append(tracker.start_run(exp, f"train msc in {name}", tags))
        tracker.end(ids[-1])
    rows = list_runs(settings, kind=TRAINING_KIND)
    assert sorted(r.run_id for r in rows) == sorted(ids)
    assert {r.experiment for r in rows} == {"synthetic-train", "training/synthetic"}
    # A cell's note links its training run on the training's own experiment page.
    exp_id = tracker.client.get_run(ids[1]).info.experiment_id
    link = training_link(tracker, ids[1])
    assert link == f"[training run {ids[1][:8]}](#/experiments/{exp_id}/runs/{ids[1]})"
    missing = training_link(tracker, "f" * 32)
    assert "not in this store" in missing
