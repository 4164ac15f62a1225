"""Training with PyTorch Lightning, shared by every trainable built-in method: one ``Trainer.fit``.

:func:`fit_lightning` runs one ``Trainer.fit`` of a method's LightningModule on its training data
(:class:`~shapebench.train.data.ShapeDataModule`) with the Trainer options from the command line,
checkpoints into the training's private folder (``last.ckpt``, resumed from when present, see
:mod:`shapebench.train.checkpoints`), logs curves to the MLflow run the orchestrator created for
this training (rank 0 only) and ends with a summary (wall time, device, epochs, steps, final loss
terms) on stderr and in that run (:mod:`shapebench.train.summary`). Every draw is seeded from the
trainer seed (:mod:`shapebench.train.seeding`); the callbacks that save, stop on a signal and
print the plan are in :mod:`shapebench.train.callbacks`.

Plugins import two helpers from here: :func:`step_generator` (the seeded generator of a training
step's draws) and :func:`adam_halving` (the halving Adam schedule).

shapebench uses the ``pytorch_lightning`` namespace throughout; never mix in ``lightning.pytorch``.
"""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path
from typing import Any

import pytorch_lightning as pl
import torch
from pytorch_lightning.utilities.exceptions import SIGTERMException

from shapebench.api.method import TrainingContext
from shapebench.progress import is_terminal
from shapebench.train.callbacks import (
    AtomicCheckpointIO,
    EpochCheckpoints,
    StopOnSignal,
    StopRequested,
    TrainingInterrupted,
    TrainingPlan,
)
from shapebench.train.checkpoints import (
    LAST,
    describe_progress,
    epochs_of,
    kept_message,
    resume_state,
)
from shapebench.train.data import ShapeDataModule
from shapebench.train.seeding import EpochSeeds, seed_training, step_generator
from shapebench.train.summary import SUMMARY_FILE, report_summary, training_summary

#: What plugins import from here (``step_generator`` lives in :mod:`shapebench.train.seeding`).
__all__ = ["adam_halving", "fit_lightning", "step_generator"]


def fit_lightning(
    module: pl.LightningModule,
    data: ShapeDataModule,
    ctx: TrainingContext,
    max_epochs: int,
    max_steps: int = 0,
) -> Path:
    """One ``Trainer.fit``; resumes from ``<workdir>/last.ckpt``; returns that checkpoint.

    The budget is ``max_steps`` optimiser steps when given (> 0), else ``max_epochs`` epochs;
    ``--max-steps`` and ``--max-epochs`` (``ctx.trainer``) override them, ``--max-epochs``
    alone ending a step budget. Before the first step the training prints its plan
    (:class:`~shapebench.train.callbacks.TrainingPlan`), and after a few steps an estimate of its
    time.

    Reproducible: Lightning's ``seed_everything`` seeds the global generators (weight
    initialisation), and every later draw (data subsets, shuffle order, per-step subsets, noise
    drawn on the device) is reseeded per epoch or per step from the trainer seed
    (:class:`~shapebench.train.seeding.EpochSeeds`); torch runs its deterministic algorithms
    where it has them (``deterministic="warn"``). Two trainings with the same seed, data and
    options give bitwise-identical weights on one device, and so does a training interrupted and
    resumed from its last checkpoint (:class:`~shapebench.train.callbacks.EpochCheckpoints`,
    :class:`~shapebench.train.callbacks.StopOnSignal`).

    Ctrl-C and SIGTERM (a parent that died, a scheduler's pre-emption) stop it at the end of the
    current optimiser step, save where it stopped
    (:class:`~shapebench.train.callbacks.StopOnSignal`) and raise
    :class:`~shapebench.train.callbacks.TrainingInterrupted`, saying where the rerun resumes from.
    """
    import logging
    import warnings

    from shapebench.store.tracking import lightning_logger

    t = ctx.trainer
    seed_training(t.seed)
    # Lightning's start-up banner (devices, tips) and a torch-internal deprecation are noise here.
    logging.getLogger("pytorch_lightning.utilities.rank_zero").setLevel(logging.WARNING)
    warnings.filterwarnings("ignore", message=r".*LeafSpec.*is deprecated")
    # Where SLURM is installed, Lightning suggests srun for any training outside a job; the
    # cluster launcher starts trainings with srun itself (shapebench.sweeps.cluster).
    warnings.filterwarnings("ignore", message=r".*The `srun` command is available")
    # Lightning cannot know that our sampler skips the batches a mid-epoch checkpoint had done.
    warnings.filterwarnings("ignore", message=r".*resuming from a checkpoint that ended before")
    logger = lightning_logger(ctx.tracking_uri, ctx.run_id) if ctx.run_id else False
    last = ctx.workdir / LAST
    saver = EpochCheckpoints(
        last, ctx.workdir.name, t.checkpoint_every_epochs, t.checkpoint_minutes
    )
    stopper = StopOnSignal(last)
    steps = t.max_steps or (0 if t.max_epochs else max_steps)
    epochs = -1 if steps else (t.max_epochs or max_epochs)
    trainer = pl.Trainer(
        accelerator=t.accelerator,
        devices=t.devices,
        strategy=t.strategy,
        num_nodes=t.num_nodes,
        precision=t.precision,
        max_epochs=epochs,
        max_steps=steps or -1,
        logger=logger,
        callbacks=[saver, EpochSeeds(t.seed), stopper, TrainingPlan(quiet=ctx.quiet)],
        default_root_dir=ctx.workdir,
        enable_checkpointing=False,
        plugins=[AtomicCheckpointIO(), *_cluster_environment()],
        log_every_n_steps=1,
        enable_model_summary=False,
        deterministic="warn",
        enable_progress_bar=not ctx.quiet and is_terminal(),  # no bar in logs
    )
    state = resume_state(last, ctx.workdir.name)
    resumed = epochs_of(state) if state is not None else None
    if state is not None and trainer.is_global_zero:  # one line, worth it even when quiet
        print(f"resuming from {last} ({describe_progress(state)})", file=sys.stderr)
    start = time.perf_counter()
    try:
        # weights_only: resuming reads tensors and plain values only, never pickled objects.
        trainer.fit(
            module,
            datamodule=data,
            ckpt_path=str(last) if last.exists() else None,
            weights_only=True,
        )
    except (StopRequested, SystemExit, KeyboardInterrupt, SIGTERMException) as exc:
        # Lightning turns a KeyboardInterrupt into SystemExit(1) after its own clean-up.
        raise TrainingInterrupted(
            f"training stopped in epoch {trainer.current_epoch + 1} at optimiser step "
            f"{trainer.global_step}; {kept_message(last)}",
            "run the same command again to resume",
            signal_name=stopper.requested,
        ) from exc
    summary = training_summary(trainer, time.perf_counter() - start)
    summary["resumed_from_epoch"] = resumed or 0
    if trainer.is_global_zero:
        report_summary(summary, logger or None, quiet=ctx.quiet)
        (ctx.workdir / SUMMARY_FILE).write_text(json.dumps(summary, indent=1))
    return last


def adam_halving(params, lr: float, every: int, every_steps: int | None = None) -> dict:
    """Adam whose learning rates halve every ``every`` epochs (IGR's, DeepSDF's and the paper's
    schedule), or every ``every_steps`` optimiser steps when that is given (0: never; a step
    schedule does not stretch with the training-set size), in the form
    ``configure_optimizers`` returns. ``params`` may be parameter groups with their own ``lr``."""
    opt = torch.optim.Adam(params, lr=lr)
    if every_steps is not None:
        if every_steps <= 0:
            return {"optimizer": opt}
        sched = torch.optim.lr_scheduler.StepLR(opt, step_size=every_steps, gamma=0.5)
        return {"optimizer": opt, "lr_scheduler": {"scheduler": sched, "interval": "step"}}
    sched = torch.optim.lr_scheduler.StepLR(opt, step_size=every, gamma=0.5)
    return {"optimizer": opt, "lr_scheduler": {"scheduler": sched, "interval": "epoch"}}


def _cluster_environment() -> list[Any]:
    """Inside a SLURM job: Lightning's SLURM environment (ranks and world size from ``srun``)
    without its auto-requeue. Its handler writes an ``hpc_ckpt`` from inside the signal handler,
    in the middle of a step; :class:`~shapebench.train.callbacks.StopOnSignal` stops after the
    step instead, writes the ``last.ckpt`` an exact resume needs, and the launcher requeues the
    job."""
    from lightning_fabric.plugins.environments import SLURMEnvironment

    if not SLURMEnvironment.detect():
        return []
    return [SLURMEnvironment(auto_requeue=False)]
