"""`sweep --launcher local -j N`: cells in worker processes, each once, same leaderboard."""

from __future__ import annotations

import os
import signal
from collections import Counter

import numpy as np
import pytest
from processes import lock_holders, processes_mentioning, wait_for
from test_soak import SWEEP, all_runs, cell_runs, leaderboard, score_columns

from shapebench.api.protocol import SCORE_RTOL
from shapebench.sweeps.launchers import worker_argv


def test_worker_command_line_replaces_the_launcher_options():
    argv = ["s.yaml", "--launcher", "local", "-j", "3", "-q", "--jobs=2", "-j4", "--seed", "1"]
    assert worker_argv(argv, 1) == [
        "s.yaml",
        "-q",
        "--seed",
        "1",
        "--launcher",
        "inline",
        "--worker",
        "1",
    ]


GAUSS_SWEEP = """
name: threads
methods: [gauss]
datasets:
  - name: synthetic
    options: {test_per_category: 1, train_per_category: 1, surface_candidates: 3000,
              gt_points: 2000}
splits: [trained]
contexts: [50]
seeds: [0]
"""


def test_a_crashed_worker_is_a_failed_worker_and_all_failed_cells_are_not(tmp_path, monkeypatch):
    """Python exits 1 on an uncaught exception; a worker whose cells all failed exits
    ALL_FAILED_STATUS (its summary names them). A quickstart's worker died of a traceback and
    the launcher, which took 1 for "all failed", said nothing: real processes, one per status."""
    import sys

    from shapebench.sweeps import launchers

    statuses = {0: 0, 1: 1, 2: launchers.ALL_FAILED_STATUS}

    def command(argv, index):
        code = f"import os, sys; assert os.environ[{launchers.WORKER_ENV!r}] == '1'; "
        return [sys.executable, "-c", code + f"sys.exit({statuses[index]})"]

    monkeypatch.setattr(launchers, "worker_command", command)
    said: list[str] = []
    failed = launchers.run_local(["sweep.yaml"], 3, tmp_path, said.append, 1)
    assert failed == 1
    assert [line for line in said if "exited" in line] == [
        f"worker exited with status 1: see {next(tmp_path.glob('*worker1.log'))}"
    ]


def test_threads_sets_the_torch_threads_of_workers_and_of_the_inline_sweep(shapebench, tmp_path):
    """``--threads 1`` with one local worker (which would get every core) and inline: the cell
    runs record the thread count they ran with; 0 is refused in one line."""
    sb = shapebench
    # Every core by default, whatever share of them the test worker's own torch has (conftest).
    cores = str(os.cpu_count() or 1)
    sb.extra_env.update(OMP_NUM_THREADS=cores, MKL_NUM_THREADS=cores)
    sweep = tmp_path / "sweep.yaml"
    sweep.write_text(GAUSS_SWEEP)
    res = sb("sweep", str(sweep), "-q", "--launcher", "local", "-j", "1", "--threads", "1")
    assert res.returncode == 0, res.stderr[-3000:]
    assert "1 workers, 1 torch threads each" in res.stdout
    [run] = sb.cell_runs("synthetic-trained")
    assert run.data.tags["host.torch_threads"] == "1"
    # The CPU kernels torch dispatched to: what tells "another machine" from "another count".
    import torch

    capability = torch.backends.cpu.get_cpu_capability()
    assert run.data.tags["host.torch_cpu_capability"] == capability
    res = sb("sweep", str(sweep), "-q", "--force", "--threads", "1")
    assert res.returncode == 0, res.stderr[-3000:]
    threads = [r.data.tags["host.torch_threads"] for r in sb.cell_runs("synthetic-trained")]
    assert threads == ["1", "1"]
    res = sb("sweep", str(sweep), "--threads", "0")
    assert res.returncode != 0
    assert "--threads must be at least 1, got 0" in res.stderr
    assert "Traceback" not in res.stderr and len(res.stderr.strip().splitlines()) <= 2


def test_workers_visit_the_methods_in_orders_that_meet_once():
    """Two workers (the default -j 2) go through the methods from opposite ends, so neither
    trails the other through every method waiting for its cells; more workers start apart."""
    from shapebench.sweeps.spec import Entry, worker_order

    methods = [Entry(name) for name in "abcde"]

    def names(worker: int) -> str:
        return "".join(e.name for e in worker_order(methods, worker))

    assert (names(0), names(1), names(2), names(7)) == ("abcde", "edcba", "cdeab", "cdeab")
    assert worker_order(methods, 0) is not methods and worker_order([], 1) == []
    # Every worker visits every method once.
    assert all(sorted(names(w)) == list("abcde") for w in range(6))


def cell_claimed(sb) -> bool:
    """Some process holds a cell's claim: it is computing that cell (cheaper to poll than the
    store, so that short cells are not missed)."""
    return bool(lock_holders(sb.workspace / "locks" / "cells", "[!p]*.lock"))


def _sweep_file(tmp_path):
    sweep = tmp_path / "sweep.yaml"
    sweep.write_text(SWEEP.replace("epochs: 60", "epochs: 20"))
    return sweep


@pytest.fixture(scope="module")
def inline_board(tmp_path_factory, data_cache):
    """The leaderboard of the sweep run inline: what every launcher must reproduce."""
    from conftest import Shapebench

    root = tmp_path_factory.mktemp("inline")
    inline = Shapebench(root / "ws", data_cache)
    inline.workspace.mkdir()
    res = inline("sweep", str(_sweep_file(root)), "-q", timeout=900)
    assert res.returncode == 0, res.stderr[-3000:]
    return leaderboard(inline, root / "board")


def _assert_each_cell_once_and_same_board(sb, expected, out):
    runs = cell_runs(sb)
    per_cell = Counter(
        (r.data.tags["method"], r.data.tags["split"], r.data.tags["context_size"]) for r in runs
    )
    assert len(per_cell) == 8 and set(per_cell.values()) == {1}
    assert all_runs(sb, "RUNNING") == []
    training = [
        r for r in all_runs(sb, "FINISHED") if r.data.tags.get("shapebench.kind") == "training"
    ]
    assert len(training) == 1
    got = leaderboard(sb, out)
    numeric = score_columns(expected)  # timings differ between runs; the scores may not
    # Workers run with cores // N torch threads, the inline sweep with all cores: float sums
    # differ in order, so the contract is the cell key's relative tolerance, not bitwise.
    a, b = got[numeric].to_numpy(float), expected[numeric].to_numpy(float)
    close = np.isclose(a, b, rtol=SCORE_RTOL, atol=0.0, equal_nan=True)
    worst = np.nanmax(np.abs(a - b) / np.where(b == 0, 1.0, np.abs(b)))
    print(f"largest relative difference from the inline leaderboard: {worst:.3g}")
    assert close.all(), got[numeric].where(~close).dropna(how="all")


@pytest.mark.slow
def test_two_local_workers_give_the_inline_leaderboard_even_when_one_is_killed(
    shapebench, tmp_path, inline_board
):
    sb = shapebench
    sweep = _sweep_file(tmp_path)
    proc = sb.popen("sweep", str(sweep), "-q", "--launcher", "local", "-j", "2")

    # Kill worker 1 while it computes a cell (holds the cell's claim): the launcher finishes
    # its work. Waiting for "some cell RUNNING" and then killing worker 1 raced with worker 1
    # having finished its share and exited (CI, stop 65).
    def worker_1_computing() -> list[int]:
        mine = processes_mentioning("--worker 1", parent=proc.pid)  # this sweep's, not others'
        holders = lock_holders(sb.workspace / "locks" / "cells", "[!p]*.lock")  # not parent-*
        return [pid for pid in mine if pid in holders]

    def worker_logs() -> str:
        logs = sorted(sb.workspace.rglob("*worker*.log"))
        return "\n".join(f"{log.name}:\n{log.read_text()[-2000:]}" for log in logs)

    workers = wait_for(
        worker_1_computing, timeout=300, what="worker 1 computing a cell", explain=worker_logs
    )
    for pid in workers:
        os.kill(pid, signal.SIGKILL)
    out, err = proc.communicate(timeout=900)
    assert proc.returncode == 0, err[-3000:]
    assert "2 workers" in out
    _assert_each_cell_once_and_same_board(sb, inline_board, tmp_path / "board-local")


@pytest.mark.slow
def test_submitit_jobs_give_the_inline_leaderboard_and_a_resubmission_completes_a_killed_one(
    shapebench, tmp_path, inline_board
):
    """The cluster launcher's code path, with submitit's local executor running the jobs."""
    sb = shapebench
    sweep = _sweep_file(tmp_path)
    proc = sb.popen("sweep", str(sweep), "-q", "--launcher", "submitit-local", "-j", "2")
    # Kill the cell jobs while one computes a cell: their claims die with them.
    wait_for(lambda: cell_claimed(sb), timeout=600, what="a cell in progress")
    # This sweep's jobs only (their command line names its workspace's log folder): another
    # test's jobs (a SLURM test in the other xdist worker) must not be killed.
    mine = set(processes_mentioning(str(sb.workspace)))
    jobs = [pid for pid in processes_mentioning("submitit.core._submit") if pid in mine]
    assert jobs, "no submitit job running"
    for pid in jobs:
        os.kill(pid, signal.SIGKILL)
    out, err = proc.communicate(timeout=900)
    assert proc.returncode != 0, out + err  # jobs failed and cells are missing
    assert "failed" in out and "missing" in err
    res = sb("sweep", str(sweep), "--status")
    assert "failed:" in res.stdout and "log " in res.stdout, res.stdout

    res = sb("sweep", str(sweep), "-q", "--launcher", "submitit-local", "-j", "2", timeout=900)
    assert res.returncode == 0, res.stdout[-3000:] + res.stderr[-3000:]
    assert "0 trainings to submit" in res.stdout
    _assert_each_cell_once_and_same_board(sb, inline_board, tmp_path / "board-submitit")


@pytest.mark.slow
def test_sigkill_of_a_local_sweep_stops_its_workers_and_their_trainings(shapebench, tmp_path):
    """Issue 59: ``kill -9`` of ``sweep --launcher local`` as soon as a worker's training child
    appears: within 15 s no worker and no training is left, and no checkpoint key's lock is
    held. (The workers used to outlive the launcher, and their trainings with them.)"""
    import time
    from pathlib import Path

    from shapebench.store.locks import try_lock

    sb = shapebench
    sweep = tmp_path / "sweep.yaml"
    # Only the IGR, trained far longer than the test waits: a survivor would still be training.
    sweep.write_text(
        SWEEP.replace("epochs: 60", "epochs: 1000")
        .replace("  - gauss\n", "")
        .replace("[trained, novel]", "[trained]")
        .replace("[50, 100]", "[50]")
    )
    proc = sb.popen("sweep", str(sweep), "-q", "--launcher", "local", "-j", "2")
    mine = str(tmp_path)  # the workers name the sweep file, the trainings the workspace

    def trainings() -> list[int]:
        return [
            pid
            for pid in processes_mentioning(mine)
            if pid in processes_mentioning("shapebench train")
        ]

    try:
        wait_for(trainings, timeout=300, what="a worker's training to start")
        assert processes_mentioning("--worker", parent=proc.pid), "no worker running"
        proc.send_signal(signal.SIGKILL)
        proc.wait()
        killed = time.monotonic()
        wait_for(
            lambda: not processes_mentioning(mine),
            timeout=15,
            what="the workers and their trainings to stop after the sweep's kill -9",
            explain=lambda: "\n".join(
                (Path("/proc") / str(pid) / "cmdline").read_text().replace("\0", " ")[:300]
                for pid in processes_mentioning(mine)
            ),
        )
        print(f"everything gone {time.monotonic() - killed:.1f} s after the kill -9")
        for path in (sb.workspace / "checkpoints").glob("*/*.lock"):
            lock = try_lock(path)
            assert lock is not None, f"{path} is still held"
            lock.release()
    finally:
        for pid in processes_mentioning(mine):
            os.kill(pid, signal.SIGKILL)


@pytest.mark.slow
def test_run_with_local_workers_computes_each_cell_once(shapebench):
    """``run --launcher local -j 2``: ``sweep``'s workers, on the one-method sweep ``run``
    writes; each cell once, with ``run``'s own dataset options and protocol."""
    sb = shapebench
    res = sb(
        "run", "-m", "gauss", "-d", "synthetic", "--split", "trained", "--contexts", "50,100",
        "-D", "test_per_category=1", "--context-noise", "0.005", "--launcher", "local", "-j", "2",
        "-q",
    )  # fmt: skip
    assert res.returncode == 0, res.stderr[-3000:]
    assert "2 workers" in res.stdout and "as a sweep of one method" in res.stdout
    runs = sb.cell_runs("synthetic-trained")
    assert sorted(int(r.data.tags["context_size"]) for r in runs) == [50, 100]
    assert {r.data.tags["protocol.context"] for r in runs} == {"sparse+noise-0.005"}
    # The same command inline finds both cells finished.
    again = sb(
        "run", "-m", "gauss", "-d", "synthetic", "--split", "trained", "--contexts", "50,100",
        "-D", "test_per_category=1", "--context-noise", "0.005", "-q",
    )  # fmt: skip
    assert again.returncode == 0, again.stderr[-3000:]
    assert len(sb.cell_runs("synthetic-trained")) == 2
