"""`shapebench sweep`: cells keyed by config hash, resumable after kill -9."""

from __future__ import annotations

import os
import signal
import time

import pytest
from conftest import TINY
from test_soak import SWEEP as SOAK_SWEEP

pytestmark = pytest.mark.slow  # runs and kills CLI subprocesses

SWEEP = """
name: resume-test
methods:
  - name: example-sphere
    options: {{delay: {delay}}}
  - gauss
datasets:
  - name: synthetic
    options: {{test_per_category: 1, train_per_category: 1, surface_candidates: 3000,
               gt_points: 2000}}
splits: [novel]
contexts: [50, 100]
seeds: [0]
"""


def test_sweep_resumes_after_kill_9_without_duplicates(with_example, tmp_path):
    sb = with_example
    # Build the tiny dataset first so the timing below is about the method only.
    assert (
        sb(
            "run",
            "-m",
            "gauss",
            "-d",
            "synthetic",
            *TINY,
            "--split",
            "novel",
            "--contexts",
            "50",
            "-q",
        ).returncode
        == 0
    )
    sweep = tmp_path / "sweep.yaml"
    sweep.write_text(SWEEP.format(delay=0.4))  # 4 objects x 0.4 s per cell
    proc = sb.popen("sweep", str(sweep), "-q", start_new_session=True)
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline:
        done = [
            r for r in sb.cell_runs("synthetic-novel") if r.data.tags["method"] == "example-sphere"
        ]
        if done:
            break
        time.sleep(0.2)
    assert done, "no cell finished before the deadline"
    os.killpg(proc.pid, signal.SIGKILL)
    proc.wait()

    res = sb("sweep", str(sweep), "-q")
    assert res.returncode == 0, res.stderr
    assert "cached" in res.stdout
    finished = sb.cell_runs("synthetic-novel")
    keys = [r.data.tags["shapebench.cell_key"] for r in finished]
    assert len(keys) == len(set(keys)), "a cell was run twice"
    cells = {(r.data.tags["method"], r.data.tags["context_size"]) for r in finished}
    assert cells == {
        ("example-sphere", "50"),
        ("example-sphere", "100"),
        ("gauss", "50"),
        ("gauss", "100"),
    }
    # The run that was killed mid-cell is not left looking alive.
    assert sb.cell_runs("synthetic-novel", status="RUNNING") == []
    client = sb.client()
    exp = client.get_experiment_by_name("synthetic-novel").experiment_id
    assert client.search_runs([exp], "attributes.status = 'RUNNING'") == []  # parents too

    # Everything done: a third run does nothing new; --force reruns every cell.
    again = sb("sweep", str(sweep), "-q")
    assert again.returncode == 0 and " new" not in again.stdout
    forced = sb("sweep", str(sweep), "-q", "--force")
    assert forced.returncode == 0
    assert len(sb.cell_runs("synthetic-novel")) == len(finished) + 4


def test_sweep_progress_counts_cells_and_extrapolates_from_computed_ones(monkeypatch):
    from types import SimpleNamespace

    import shapebench.sweeps.spec as sweep_mod

    clock = iter([0.0, 60.0, 120.0])
    monkeypatch.setattr("time.monotonic", lambda: next(clock))
    progress = sweep_mod.SweepProgress(total=8)
    cells = lambda skipped: [SimpleNamespace(skipped=skipped)] * 2  # noqa: E731
    outcome = lambda skipped: SimpleNamespace(cells=cells(skipped), train_seconds=0.0)  # noqa: E731
    assert progress.update(outcome(True)) == (
        "sweep progress: 2/8 cells (2 already done), 1m00s elapsed"
    )  # nothing computed yet: no estimate
    # 2 cells computed in 120 s: 60 s per cell, 4 cells left.
    assert progress.update(outcome(False)) == (
        "sweep progress: 4/8 cells (2 already done), 2m00s elapsed, about 4m00s left"
    )
    assert sweep_mod._duration(3 * 3600 + 125) == "3h02m"


def test_sweep_progress_leaves_training_time_out_of_the_estimate(monkeypatch):
    from types import SimpleNamespace

    import shapebench.sweeps.spec as sweep_mod

    clock = iter([0.0, 660.0])
    monkeypatch.setattr("time.monotonic", lambda: next(clock))
    progress = sweep_mod.SweepProgress(total=8)
    # 11 minutes, 10 of them training: 2 cells evaluated in 60 s, 6 left.
    trained = SimpleNamespace(cells=[SimpleNamespace(skipped=False)] * 2, train_seconds=600.0)
    assert progress.update(trained) == (
        "sweep progress: 2/8 cells, 11m00s elapsed (10m00s training), about 3m00s left"
    )


#: The soak test's small IGR and Gauss, trained for 2 epochs, one split and one context size.
TRAINING_SWEEP = (
    SOAK_SWEEP.replace("epochs: 60", "epochs: 2")
    .replace("[trained, novel]", "[novel]")
    .replace("[50, 100]", "[50]")
)


def test_sweep_progress_shows_a_training_apart_from_evaluation(shapebench, tmp_path):
    sweep = tmp_path / "sweep.yaml"
    sweep.write_text(TRAINING_SWEEP)
    res = shapebench("sweep", str(sweep), "-q")
    assert res.returncode == 0, res.stderr
    lines = [line for line in res.stdout.splitlines() if line.startswith("sweep progress")]
    # IGR trains before its cell: the first line counts that time as training.
    assert len(lines) == 2 and "training)" in lines[0], res.stdout
