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
