"""`shapebench merge`: per-job stores into one, idempotently by cell key (issue: offline nodes)."""

from __future__ import annotations

import pytest
from conftest import SMALL_IGR, TINY

pytestmark = pytest.mark.slow  # runs the CLI


def test_merge_brings_per_job_stores_together_once(shapebench, tmp_path):
    sb = shapebench
    jobs = []
    for i, contexts in enumerate(("50", "50,100")):  # the two jobs share the cell k=50
        job = type(sb)(tmp_path / f"job{i}", sb.cache)
        job.workspace.mkdir()
        res = job(
            "run",
            "-m",
            "gauss",
            "-d",
            "synthetic",
            *TINY,
            "--split",
            "novel",
            "--contexts",
            contexts,
            "-q",
        )
        assert res.returncode == 0, res.stderr[-3000:]
        jobs.append(job)

    res = sb("merge", *(str(j.workspace) for j in jobs))
    assert res.returncode == 0, res.stderr[-3000:]
    runs = sb.cell_runs("synthetic-novel")
    assert sorted(r.data.tags["context_size"] for r in runs) == ["100", "50"]  # k=50 once
    assert all("shapebench.merged_from" in r.data.tags for r in runs)
    assert all(r.data.metrics["chamfer-l2.mean"] > 0 for r in runs)

    again = sb("merge", *(str(j.workspace) for j in jobs))
    assert again.returncode == 0 and "0 cell runs added" in again.stdout
    assert len(sb.cell_runs("synthetic-novel")) == 2

    # A cell key promises scores equal to a relative SCORE_RTOL (other thread counts sum floats
    # in another order), not bitwise: a merge keeps the target's cell and reports a source whose
    # scores of that key differ by more.
    from shapebench.api.protocol import SCORE_RTOL

    (k50,) = [
        r for r in jobs[1].cell_runs("synthetic-novel") if r.data.tags["context_size"] == "50"
    ]
    mean = k50.data.metrics["chamfer-l2.mean"]
    source = jobs[1].client()
    source.log_metric(k50.info.run_id, "chamfer-l2.mean", mean * (1 + SCORE_RTOL / 10), step=50)
    close = sb("merge", str(jobs[1].workspace))
    assert close.returncode == 0 and "differ" not in close.stdout, close.stdout
    source.log_metric(k50.info.run_id, "chamfer-l2.mean", mean * (1 + SCORE_RTOL * 10), step=50)
    far = sb("merge", str(jobs[1].workspace))
    assert far.returncode == 0 and "0 cell runs added" in far.stdout
    assert "1 cells kept whose scores differ" in far.stdout, far.stdout
    assert k50.data.tags["shapebench.cell_key"] in far.stdout

    # The merged store is a store like any other: its leaderboard reads the copied artifacts,
    # and a run in it reuses the merged cells.
    board = sb(
        "leaderboard",
        "-d",
        "synthetic",
        "--split",
        "novel",
        "--reference",
        "gauss",
        "--out",
        str(tmp_path / "boards"),
    )
    assert board.returncode == 0, board.stderr[-3000:]
    rerun = sb(
        "run", "-m", "gauss", "-d", "synthetic", *TINY, "--split", "novel", "--contexts", "50,100"
    )
    assert rerun.returncode == 0 and " new " not in rerun.stdout


def test_merge_names_a_missing_store(shapebench, tmp_path):
    res = shapebench("merge", str(tmp_path / "nowhere"))
    assert res.returncode == 2 and "no MLflow store at" in res.stderr


def test_merged_cells_name_the_target_stores_training(shapebench, tmp_path):
    """A merged cell's training_run_id is the target's run of its training, whether the merge
    copied that training or found it there (run ids mean nothing across stores), so the
    leaderboard's cost column still shows it."""
    sb = shapebench

    def igr(job, contexts: str):
        res = job(
            "run",
            "-m",
            "igr",
            "-d",
            "synthetic",
            *TINY,
            *SMALL_IGR,
            "--split",
            "novel",
            "--contexts",
            contexts,
            "-q",
            "--retrain",
        )
        assert res.returncode == 0, res.stderr[-3000:]

    jobs = []
    for i in range(2):
        job = type(sb)(tmp_path / f"job{i}", sb.cache)
        job.workspace.mkdir()
        jobs.append(job)
    igr(jobs[0], "50")
    igr(jobs[1], "100")  # the same training, in a store of its own
    assert sb("merge", str(jobs[0].workspace)).returncode == 0  # copies the training
    assert sb("merge", str(jobs[1].workspace)).returncode == 0  # finds it there

    client = sb.client()
    exp = client.get_experiment_by_name("training/synthetic")
    (training,) = client.search_runs([exp.experiment_id])
    cells = sb.cell_runs("synthetic-novel")
    assert sorted(r.data.tags["context_size"] for r in cells) == ["100", "50"]
    assert {r.data.tags["training_run_id"] for r in cells} == {training.info.run_id}

    board = sb(
        "leaderboard", "-d", "synthetic", "--split", "novel", "--out", str(tmp_path / "boards")
    )
    assert board.returncode == 0, board.stderr[-3000:]
    table = (tmp_path / "boards" / "synthetic-novel.md").read_text()
    igr_row = next(line for line in table.splitlines() if line.startswith("| IGR"))
    assert "device-h" in igr_row, igr_row
