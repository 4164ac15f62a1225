"""Nothing lost when work is interrupted: resumable training, no orphans, concurrent runs.

Every test drives the real CLI in child processes and interrupts it the way users do (Ctrl-C,
``kill``, ``kill -9``), then checks the checkpoints, the MLflow store and the process table.
"""

from __future__ import annotations

import json
import os
import signal
import time
from pathlib import Path

import pytest
import torch
from conftest import TINY
from processes import last_ckpt, processes_mentioning, saved_epochs, wait_for

pytestmark = pytest.mark.slow  # every test here starts the CLI or trains

#: A tiny IGR trained long enough (about 0.1 s per epoch) to be interrupted mid-way.
IGR = [
    "-m",
    "igr",
    "-d",
    "synthetic",
    *TINY,
    "-O",
    "latent_dim=8",
    "-O",
    "width=32",
    "-O",
    "depth=2",
    "-O",
    "batch_shapes=4",
    "-O",
    "surface_points=64",
    "-O",
    "mesh_resolution=32",
    "-O",
    "opt_steps=5",
]


def training_runs(sb, status: str | None = None):
    client = sb.client()
    exp = client.get_experiment_by_name("training/synthetic")
    runs = client.search_runs([exp.experiment_id]) if exp else []
    return [r for r in runs if status is None or r.info.status == status]


def weights(path: Path) -> dict[str, torch.Tensor]:
    return torch.load(path, map_location="cpu", weights_only=True)["state_dict"]


def test_killed_training_resumes_from_its_saved_epoch_to_the_same_weights(shapebench, tmp_path):
    sb = shapebench
    args = ["train", *IGR, "-O", "epochs=150"]
    proc = sb.popen(*args)
    wait_for(lambda: saved_epochs(sb) >= 3, what="3 epochs saved")
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    killed_at = saved_epochs(sb)
    assert 3 <= killed_at < 150
    assert [r.info.status for r in training_runs(sb)] == ["RUNNING"]

    res = sb(*args)
    assert res.returncode == 0, res.stderr[-3000:]
    assert f"({killed_at} epochs done," in res.stderr  # resumed, not restarted from epoch 0
    path = last_ckpt(sb)
    summary = json.loads((path.parent / "summary.json").read_text())
    assert summary["resumed_from_epoch"] == killed_at
    # The killed training's run is closed; the resumed one is marked as such.
    runs = {r.info.status: r for r in training_runs(sb)}
    assert sorted(runs) == ["FINISHED", "KILLED"]
    assert runs["FINISHED"].data.tags.get("resumed") == "true"

    # An uninterrupted training in another workspace: same number of steps, same weights.
    other = type(sb)(tmp_path / "uninterrupted", sb.cache, sb.sites)
    other.workspace.mkdir()
    res = other(*args, "-q")
    assert res.returncode == 0, res.stderr[-3000:]
    straight = last_ckpt(other)
    plain = json.loads((straight.parent / "summary.json").read_text())
    assert summary["optimizer_steps"] == plain["optimizer_steps"] > 0
    a, b = weights(path), weights(straight)
    assert a.keys() == b.keys() and all(torch.equal(a[k], b[k]) for k in a)


def test_ctrl_c_during_training_says_where_it_stopped_and_how_to_resume(shapebench):
    sb = shapebench
    proc = sb.popen("train", *IGR, "-O", "epochs=150")
    wait_for(lambda: saved_epochs(sb) >= 2, what="2 epochs saved")
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 130, err[-3000:]
    assert "stopping after the current optimiser step" in err
    assert "Interrupted: training stopped in epoch" in err
    assert "is kept at" in err and "run the same command again to resume" in err
    assert "Traceback" not in err
    assert [r.info.status for r in training_runs(sb)] == ["KILLED"]


def test_sigkill_of_a_run_leaves_no_training_behind_and_the_rerun_trains_once(shapebench):
    sb = shapebench
    args = ["run", *IGR, "-O", "epochs=150", "--split", "novel", "--contexts", "50", "-q"]
    proc = sb.popen(*args)
    wait_for(lambda: saved_epochs(sb) >= 2, what="the child training to save 2 epochs")
    children = processes_mentioning(str(sb.workspace))  # the training names the workspace
    assert len(children) == 1 and children[0] != proc.pid
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    start = time.monotonic()
    wait_for(
        lambda: not processes_mentioning(str(sb.workspace)),
        timeout=10,
        what="the orphaned training to stop",
    )
    print(f"orphan gone {time.monotonic() - start:.1f} s after the parent's kill -9")

    res = sb(*args)
    assert res.returncode == 0, res.stderr[-3000:]
    finished = training_runs(sb, "FINISHED")
    assert len(finished) == 1 and finished[0].data.tags.get("resumed") == "true"
    assert not training_runs(sb, "RUNNING")
    assert len(sb.cell_runs("synthetic-novel")) == 1


def test_two_runs_started_together_log_each_cell_once_and_train_once(shapebench):
    sb = shapebench  # a fresh workspace: both processes create the MLflow store at once
    args = ["run", *IGR, "-O", "epochs=20", "--contexts", "50,100", "-q"]
    procs = [sb.popen(*args) for _ in range(2)]
    outs = [p.communicate(timeout=600) for p in procs]
    for proc, (_, err) in zip(procs, outs, strict=True):
        assert proc.returncode == 0, err[-3000:]
        assert "Traceback" not in err
    assert len(training_runs(sb)) == 1
    keys = []
    for exp in ("synthetic-trained", "synthetic-novel"):
        runs = sb.cell_runs(exp, status=None)
        assert all(r.info.status == "FINISHED" for r in runs)
        keys += [r.data.tags["shapebench.cell_key"] for r in runs]
    assert len(keys) == len(set(keys)) == 4  # two splits x two context sizes, each once


@pytest.mark.parametrize("epoch, batch", [(1, 0), (2, 1)], ids=["mid-epoch", "last-batch"])
def test_a_signal_stops_between_steps_and_the_resume_gives_the_same_weights(
    tmp_path, monkeypatch, epoch, batch
):
    """A real SIGINT delivered during a step: the step finishes, the checkpoint is written
    where training stopped (mid-epoch, or at the end of an epoch's last step), and the resumed
    training ends bitwise where an uninterrupted one does."""
    from shapebench_msc.method import MSC
    from tiny_datasets import TINY_MSC, Shapes, meshes

    from shapebench.api.method import TrainerOptions, TrainingContext
    from shapebench.train.callbacks import TrainingInterrupted
    from shapebench.train.seeding import EpochSeeds

    def fit(name: str) -> Path:
        trainer = TrainerOptions(accelerator="cpu", devices=1, seed=3)
        ctx = TrainingContext(Shapes(meshes()), trainer, tmp_path / name, "", None, True)
        return MSC(MSC.Options(**{**TINY_MSC, "epochs": 4})).fit(ctx)

    straight = torch.load(fit("straight"), map_location="cpu", weights_only=True)
    seed_step = EpochSeeds.on_train_batch_start
    sent = []

    def signal_once(self, trainer, module, data, batch_idx):
        if (trainer.current_epoch, batch_idx) == (epoch, batch) and not sent:
            sent.append(trainer.global_step)
            os.kill(os.getpid(), signal.SIGINT)
        return seed_step(self, trainer, module, data, batch_idx)

    monkeypatch.setattr(EpochSeeds, "on_train_batch_start", signal_once)
    with pytest.raises(TrainingInterrupted, match="stopped in epoch"):
        fit("stopped")
    monkeypatch.setattr(EpochSeeds, "on_train_batch_start", seed_step)
    saved = torch.load(tmp_path / "stopped" / "last.ckpt", map_location="cpu", weights_only=True)
    assert saved["global_step"] == sent[0] + 1  # the step in progress was finished, then saved
    resumed = torch.load(fit("stopped"), map_location="cpu", weights_only=True)
    assert resumed["global_step"] == straight["global_step"]
    a, b = straight["state_dict"], resumed["state_dict"]
    assert all(torch.equal(a[k], b[k]) for k in a)


#: One cell of the tiny IGR, trained far longer than a test waits: an orphan would still train.
LONG_IGR_SWEEP = """
name: orphans
methods:
  - name: igr
    options: {latent_dim: 8, width: 32, depth: 2, batch_shapes: 4, surface_points: 64,
              mesh_resolution: 32, opt_steps: 5, epochs: 1000}
datasets:
  - name: synthetic
    options: {test_per_category: 1, train_per_category: 1, surface_candidates: 3000,
              gt_points: 2000}
splits: [trained]
contexts: [50]
seeds: [0]
"""


def training_processes(sb) -> list[int]:
    """Live ``shapebench train`` processes of this workspace (their command line names it)."""
    return [
        pid
        for pid in processes_mentioning(str(sb.workspace))
        if pid in processes_mentioning("shapebench train")
    ]


def held_training_locks(sb) -> list[Path]:
    """The checkpoint keys' locks that some process holds."""
    from shapebench.store.locks import try_lock

    held = []
    for path in (sb.workspace / "checkpoints").glob("*/*.lock"):
        lock = try_lock(path)
        if lock is None:
            held.append(path)
        else:
            lock.release()
    return held


def assert_nothing_left_after_killing(sb, proc, leftovers: str, delay: float = 0.0) -> None:
    """SIGKILL ``proc`` ``delay`` seconds from now; within 15 s no process of this test
    (a command line mentioning ``leftovers``) may live, and no checkpoint key's lock be held.
    Whatever is left is killed afterwards, so that a failure leaves no orphan either."""
    time.sleep(delay)
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    killed = time.monotonic()
    try:
        wait_for(
            lambda: not processes_mentioning(leftovers),
            timeout=15,
            what=f"the processes of {leftovers} to stop after their parent's kill -9",
            explain=lambda: "\n".join(
                (Path("/proc") / str(pid) / "cmdline").read_text().replace("\0", " ")[:300]
                for pid in processes_mentioning(leftovers)
            ),
        )
        print(f"everything gone {time.monotonic() - killed:.1f} s after the kill -9")
        assert held_training_locks(sb) == []
    finally:
        for pid in processes_mentioning(leftovers):
            os.kill(pid, signal.SIGKILL)


@pytest.mark.parametrize("command", ["run", "sweep", "train"])
def test_sigkill_as_soon_as_a_training_starts_leaves_no_training_behind(
    shapebench, tmp_path, command
):
    """Issue 59: a ``run`` (or inline ``sweep``) killed while its training child still imports
    torch or prepares data, before any Python-level watchdog could start, left that child
    training for minutes. The child must die with its parent at any moment, and release the
    key's lock; a killed ``train`` is the training itself, and leaves no lock held either."""
    sb = shapebench
    if command == "sweep":
        sweep = tmp_path / "sweep.yaml"
        sweep.write_text(LONG_IGR_SWEEP)
        proc = sb.popen("sweep", str(sweep), "-q")
    else:
        extra = ["--split", "trained", "--contexts", "50"] if command == "run" else []
        proc = sb.popen(command, *IGR, "-O", "epochs=1000", *extra, "-q")
    if command == "train":
        # Killed while it trains and holds the key's lock.
        wait_for(lambda: saved_epochs(sb) >= 1, what="the training to save an epoch")
        assert held_training_locks(sb)
    else:
        # Killed as soon as the child appears: it is still importing (the case of the issue).
        wait_for(
            lambda: processes_mentioning("shapebench train", parent=proc.pid),
            timeout=180,
            what="the child training to start",
        )
    assert_nothing_left_after_killing(sb, proc, str(sb.workspace))


def test_the_fallback_watchdog_stops_a_training_whose_parent_is_already_gone(tmp_path):
    """Where the kernel does not stop the child (no prctl, or the parent died before the child
    was armed), :func:`watch_parent` does, even when it starts after its parent died: it used
    to take a parent that was not (or no longer) its parent for a Lightning rank's, and watch
    nothing."""
    import subprocess
    import sys

    from shapebench.train.lifecycle import PARENT_ENV

    gone = subprocess.Popen(["true"])
    gone.wait()  # a pid no process has now, as a dead parent's
    code = (
        "import time; from shapebench.train.lifecycle import watch_parent; watch_parent(); "
        "time.sleep(30); print('still running')"
    )
    env = {**os.environ, PARENT_ENV: str(gone.pid)}
    child = subprocess.run(
        [sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=60
    )
    assert child.returncode == -signal.SIGTERM, child.stdout + child.stderr
    assert f"(pid {gone.pid}) is gone: stopping" in child.stderr
    # A parent alive, but not this process's parent (a grandchild inherited the variable, as
    # the ranks Lightning launches do): neither stopped nor watched.
    env = {**os.environ, PARENT_ENV: str(os.getpid())}
    code = "from shapebench.train.lifecycle import watch_parent; watch_parent(); print('kept')"
    shell = f'{sys.executable} -c "{code}"; true'  # `; true`: sh forks, no exec
    child = subprocess.run(["sh", "-c", shell], env=env, capture_output=True, text=True, timeout=60)
    assert child.returncode == 0 and "kept" in child.stdout, child.stderr


def test_a_stop_asked_before_training_started_is_kept_when_its_interrupt_was_lost(
    monkeypatch, tmp_path
):
    """SIGTERM while a library is imported can land in code that swallows its interrupt: the
    signal is remembered, and the training stops after its first step (StopOnSignal) or before
    it starts (train_here)."""
    from shapebench.train import lifecycle
    from shapebench.train.callbacks import StopOnSignal

    monkeypatch.setattr(lifecycle, "_stop_signal", None)
    stop = StopOnSignal(tmp_path / "last.ckpt")
    stop.on_train_start(None, None)
    stop.teardown(None, None, "fit")
    assert stop.requested is None
    lifecycle.note_stop_signal(signal.SIGTERM)
    assert lifecycle.stop_requested() == "SIGTERM"
    stop.on_train_start(None, None)
    stop.teardown(None, None, "fit")
    assert stop.requested == "SIGTERM"
    from shapebench.train.training import train_here

    with pytest.raises(KeyboardInterrupt):
        train_here(None, None)  # type: ignore[arg-type]  # stops before reading the ticket
