"""`sweep --launcher local -j N`: cells in worker processes, each once, same leaderboard."""

from __future__ import annotations

import os
import signal
from collections import Counter

import pytest
from test_interruptions import processes_mentioning, wait_for
from test_soak import SWEEP, all_runs, cell_runs, leaderboard

from shapebench.launchers import worker_argv


def test_worker_command_line_replaces_the_launcher_options():
    argv = ["s.yaml", "--launcher", "local", "-j", "3", "-q", "--jobs=2", "-j4", "--seed", "1"]
    assert worker_argv(argv, 1) == ["s.yaml", "-q", "--seed", "1", "--launcher", "inline",
                                    "--worker", "1"]  # fmt: skip


@pytest.mark.slow
def test_two_local_workers_give_the_inline_leaderboard_even_when_one_is_killed(
    shapebench, tmp_path
):
    sb = shapebench
    sweep = tmp_path / "sweep.yaml"
    sweep.write_text(SWEEP.replace("epochs: 60", "epochs: 20"))

    inline = type(sb)(tmp_path / "inline", sb.cache)
    inline.workspace.mkdir()
    res = inline("sweep", str(sweep), "-q", timeout=900)
    assert res.returncode == 0, res.stderr[-3000:]
    expected = leaderboard(inline, tmp_path / "board-inline")

    proc = sb.popen("sweep", str(sweep), "-q", "--launcher", "local", "-j", "2")
    # Kill worker 1 while some cell is being computed: the launcher finishes its work.
    wait_for(lambda: cell_runs(sb, status="RUNNING"), timeout=300, what="a cell in progress")
    workers = processes_mentioning("--worker 1")
    assert workers, "no worker 1 running"
    for pid in workers:
        os.kill(pid, signal.SIGKILL)
    out, err = proc.communicate(timeout=900)
    assert proc.returncode == 0, err[-3000:]
    assert "2 workers" in out

    runs = cell_runs(sb)
    per_cell = Counter((r.data.tags["method"], r.data.tags["split"],
                        r.data.tags["context_size"]) for r in runs)  # fmt: skip
    assert len(per_cell) == 8 and set(per_cell.values()) == {1}
    assert all_runs(sb, "RUNNING") == []
    training = [r for r in all_runs(sb, "FINISHED")
                if r.data.tags.get("shapebench.kind") == "training"]  # fmt: skip
    assert len(training) == 1
    got = leaderboard(sb, tmp_path / "board-local")
    numeric = expected.select_dtypes("number").columns
    assert ((got[numeric] - expected[numeric]).abs().max().max()) == 0
