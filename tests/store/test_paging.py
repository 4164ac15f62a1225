"""MLflow searches page through every run (issue 59: nothing silently dropped).

A real SQLite MLflow store in tmp_path with more runs than one page holds (the page size lowered
to 3), read in-process through each caller of :func:`shapebench.store.paging.search_all_runs`.
"""

from __future__ import annotations

import pytest

from shapebench.config import make_settings
from shapebench.store import paging
from shapebench.store import records as rec
from shapebench.store.tracking import Tracker

PAGE = 3
CELLS = 7  # more than two pages: 3 + 3 + 1
TRAININGS = 5
EXPERIMENT = "synthetic-novel"


@pytest.fixture
def small_pages(monkeypatch):
    monkeypatch.setattr(paging, "PAGE", PAGE)


def settings_of(workspace):
    """Settings of a store of its own in ``workspace`` (named explicitly: an MLflow tracking URI
    another in-process test left in the environment must not be used)."""
    return make_settings(
        f"sqlite:///{workspace / 'mlflow.db'}", workspace / "cache", None, workspace
    )


def fill(workspace) -> tuple[Tracker, str, str, list[str], list[str]]:
    """A store with a parent run, CELLS finished cells under it, one RUNNING cell and
    TRAININGS trainings: (tracker, experiment id, parent id, cell ids, training ids)."""
    tracker = Tracker(settings_of(workspace))
    exp = tracker.experiment_id(EXPERIMENT)
    parent = tracker.start_run(exp, "parent", {rec.KIND_TAG: rec.PARENT_KIND})
    cells = []
    for i in range(CELLS):
        record = rec.CellRecord(
            cell_key=f"key{i}", method="gauss", dataset="synthetic", split="novel",
            context_size=50, seed=i,
        )  # fmt: skip
        run = tracker.start_run(exp, f"cell{i}", record.to_tags(), parent_id=parent)
        tracker.log_metrics(run, {"chamfer-l2.mean": 1.0 + i})
        tracker.end(run)
        cells.append(run)
    unfinished = rec.CellRecord("running", "gauss", "synthetic", "novel", 50, CELLS)
    tracker.start_run(exp, "running", unfinished.to_tags())
    trainings = []
    for i in range(TRAININGS):
        tags = {rec.KIND_TAG: rec.TRAINING_KIND, rec.CHECKPOINT_KEY_TAG: f"ckpt{i}"}
        run = tracker.start_run(exp, f"training{i}", tags)
        tracker.end(run)
        trainings.append(run)
    tracker.end(parent)
    return tracker, exp, parent, cells, trainings


@pytest.fixture
def store(tmp_path, small_pages):
    return fill(tmp_path / "ws")


def test_a_single_page_would_drop_runs(store):
    """The premise: one page of PAGE runs holds fewer than the store has."""
    tracker, exp, *_ = store
    page = tracker.client.search_runs([exp], max_results=PAGE)
    assert len(page) == PAGE and page.token


def test_the_helper_follows_every_page_in_order(store):
    tracker, exp, parent, cells, trainings = store
    runs = paging.search_all_runs(
        tracker.client, [exp], order_by=["attributes.start_time ASC", "attributes.run_id ASC"]
    )
    ids = [r.info.run_id for r in runs]
    assert len(ids) == len(set(ids)) == 1 + CELLS + 1 + TRAININGS
    assert set(cells) | set(trainings) | {parent} <= set(ids)
    starts = [r.info.start_time for r in runs]
    assert starts == sorted(starts)
    # A limit is honoured across page boundaries, and keeps the first runs of the order.
    first = paging.search_all_runs(
        tracker.client, [exp], order_by=["attributes.start_time ASC"], limit=PAGE + 2
    )
    assert [r.info.run_id for r in first] == ids[: PAGE + 2]
    assert paging.search_all_runs(tracker.client, []) == []


def test_leaderboard_cells_and_runs_of_kind_see_every_run(store):
    from shapebench.boards.selection import load_runs

    tracker, exp, parent, cells, trainings = store
    finished = tracker.finished_cells(exp)
    assert sorted(run_id for run_id, _, _ in finished) == sorted(cells)  # not the RUNNING one
    assert [start for _, start, _ in finished] == sorted(
        (start for _, start, _ in finished), reverse=True
    )
    table = load_runs(tracker, exp)  # what the leaderboard builds its tables from
    assert sorted(table["seed"]) == list(range(CELLS))
    found = tracker.runs_of_kind(exp, rec.TRAINING_KIND)
    assert [run_id for run_id, _ in found] == trainings  # oldest first
    assert [run_id for run_id, _ in tracker.runs_of_kind(exp, rec.PARENT_KIND)] == [parent]


def test_the_finished_cell_index_holds_every_cell_as_find_cell_gives_it(store):
    """What a sweep's plan (and so ``sweep --status``) looks its cells up in: every finished
    cell past one page, each the run find_cell gives for its key; not the RUNNING one."""
    tracker, exp, _, cells, _ = store
    # A newer finished run of key0: the newest run of a key is its cell, as in find_cell.
    again = rec.CellRecord("key0", "gauss", "synthetic", "novel", 50, 0)
    newer = tracker.start_run(exp, "cell0-again", again.to_tags())
    tracker.end(newer)
    index = tracker.finished_cell_index(exp)
    assert sorted(index) == [f"key{i}" for i in range(CELLS)]
    for key, cell in index.items():
        assert cell.run_id == tracker.find_cell(exp, key).run_id
    assert index["key0"].run_id == newer
    assert index["key3"].metrics == {"chamfer-l2.mean": 4.0}


def test_artifacts_of_searched_cells_are_read_from_their_folder(store, tmp_path, monkeypatch):
    """A cell found by a search has a local artifact URI: its files are read from there, not
    through MLflow's download (two run lookups per file); another run's still download."""
    tracker, exp, _, cells, trainings = store
    table = tmp_path / "per_object.csv"
    table.write_text("object,value\na,1.5\n")
    tracker.log_artifact(cells[4], table)
    tracker.log_artifact(trainings[0], table)
    tracker.finished_cells(exp)
    downloads = []
    real = tracker.client.download_artifacts
    monkeypatch.setattr(
        tracker.client,
        "download_artifacts",
        lambda *a, **k: downloads.append(a[0]) or real(*a, **k),
    )
    got = tracker.download_artifact(cells[4], "per_object.csv", tmp_path / "a")
    assert got == tmp_path / "a" / "per_object.csv" and got.read_text() == table.read_text()
    other = tracker.download_artifact(trainings[0], "per_object.csv", tmp_path / "b")
    assert other.read_text() == table.read_text()
    assert downloads == [trainings[0]]


def test_listing_shows_every_child_and_run(store, tmp_path):
    from shapebench.store.listing import list_runs, show_run

    tracker, exp, parent, cells, _ = store
    details = show_run(tracker.settings, parent)
    assert details.children == sorted(cells)
    rows = list_runs(tracker.settings, kind="cell", limit=100)
    assert len(rows) == CELLS + 1  # the RUNNING cell is listed too
    assert len(list_runs(tracker.settings, kind="cell", limit=PAGE + 1)) == PAGE + 1


def test_a_listing_cut_by_its_limit_says_so(store):
    """``runs --limit N`` on a store with more matching runs names the cut (a 10k store listed
    "1000 runs" as if that were all); ``--limit 0`` lists every one."""
    from click.testing import CliRunner

    from shapebench.cli import cli

    tracker, *_ = store
    uri = ["--tracking-uri", tracker.uri]
    out = CliRunner().invoke(cli, ["runs", "--limit", "2", *uri]).output
    assert "2 runs (the newest 2; older ones match too (--limit 0 lists every one))" in out
    out = CliRunner().invoke(cli, ["runs", "--limit", "0", *uri]).output
    assert f"{CELLS + 1} runs; details" in out
    out = CliRunner().invoke(cli, ["runs", "--limit", str(CELLS + 1), *uri]).output
    assert f"{CELLS + 1} runs; details" in out  # exactly all: no note


def test_ui_counts_every_run(store):
    from shapebench.store.ui import experiment_links

    tracker, *_ = store
    (link,) = [
        link for link in experiment_links(tracker.client, "http://x") if link.name == EXPERIMENT
    ]
    assert link.runs == 1 + CELLS + 1 + TRAININGS


def test_merge_copies_every_run(store, tmp_path):
    from shapebench.store.merge import merge_stores

    tracker, exp, _, cells, trainings = store
    target = Tracker(settings_of(tmp_path / "target"))
    report = merge_stores([str(tmp_path / "ws")], target.uri, echo=lambda _: None)
    assert report.added == {rec.CELL_KIND: CELLS, rec.TRAINING_KIND: TRAININGS, rec.PARENT_KIND: 1}
    assert report.skipped_unfinished == 1  # the RUNNING cell
    target_exp = target.experiment_id(EXPERIMENT, create=False)
    assert len(target.finished_cells(target_exp)) == CELLS
    again = merge_stores([str(tmp_path / "ws")], target.uri, echo=lambda _: None)
    assert again.added == {} and again.present[rec.CELL_KIND] == CELLS


def test_a_run_logged_while_paging_is_read_once(store):
    """Page tokens are offsets: a run logged by another process between two pages (newest first)
    pushes a run already read onto the next page. It is returned once, and none is missed."""
    from mlflow.tracking import MlflowClient

    tracker, exp, parent, cells, trainings = store
    before = {r.info.run_id for r in paging.search_all_runs(tracker.client, [exp])}

    class Busy(MlflowClient):  # another process logging a run after our first page
        calls = 0

        def search_runs(self, *args, **kwargs):
            page = super().search_runs(*args, **kwargs)
            Busy.calls += 1
            if Busy.calls == 1:
                self.set_terminated(self.create_run(exp).info.run_id)
            return page

    runs = paging.search_all_runs(
        Busy(tracking_uri=tracker.uri), [exp], order_by=["attributes.start_time DESC"]
    )
    ids = [r.info.run_id for r in runs]
    assert Busy.calls > 2 and len(ids) == len(set(ids))
    assert before <= set(ids)
