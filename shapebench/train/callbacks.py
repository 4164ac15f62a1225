"""The Lightning callbacks of a training that change nothing it computes: where and when it saves,
what it says, how it stops.

:class:`EpochCheckpoints` saves ``last.ckpt`` at epoch ends, through :class:`AtomicCheckpointIO`
(a kill never leaves a truncated file); :class:`StopOnSignal` turns Ctrl-C, SIGTERM and SLURM's
pre-emption warning into a stop after the optimiser step in progress, saved where it stopped
(:func:`~shapebench.train.lightning_fit.fit_lightning` then raises :class:`TrainingInterrupted`);
:class:`TrainingPlan` prints what a training is about to cost. The draws that do change the
weights are seeded by :class:`~shapebench.train.seeding.EpochSeeds`.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path
from typing import Any

import pytorch_lightning as pl
import torch
from pytorch_lightning.plugins import TorchCheckpointIO

from shapebench.api.errors import Interrupted


class TrainingInterrupted(Interrupted):
    """Ctrl-C or SIGTERM (or SLURM's pre-emption warning) stopped a training; the checkpoint to
    resume from is kept. ``signal_name`` is the signal that asked for it (``SIGINT``...)."""

    def __init__(
        self, message: str, hint: str | None = None, signal_name: str | None = None
    ) -> None:
        super().__init__(message, hint)
        self.signal_name = signal_name


def preemption_signal() -> Any:
    """The signal SLURM sends before pre-empting or timing out this job (``--signal``), or None
    outside a SLURM job. Handled like SIGTERM: stop after the step, save, and the cluster
    launcher requeues the job (:func:`shapebench.sweeps.jobs.requeue_after`)."""
    import os
    import signal

    if not os.environ.get("SLURM_JOB_ID"):
        return None
    name = os.environ.get("SUBMITIT_PREEMPT_SIGNAL", "USR1")
    return getattr(signal, f"SIG{name}", None)


class StopRequested(Exception):
    """Raised at the end of an optimiser step after Ctrl-C or SIGTERM asked training to stop."""


class StopOnSignal(pl.Callback):
    """Ctrl-C or SIGTERM: finish the optimiser step in progress, save ``last.ckpt``, stop.

    Stopping between steps keeps the weights, the optimiser and the step count consistent (a
    ``KeyboardInterrupt`` raised inside ``optimizer.step`` would not). A single-process training
    saves where it stopped, and resumes there exactly: the next run skips the batches of the
    epoch already stepped on (:func:`~shapebench.train.data.steps_into_epoch`), and every draw is
    a function of the epoch and step (:class:`~shapebench.train.seeding.EpochSeeds`). A DDP
    training keeps its last epoch-end checkpoint. A second Ctrl-C stops at once.
    """

    def __init__(self, path: Path) -> None:
        self.path = path
        self.requested: str | None = None
        self._previous: dict[int, Any] = {}

    def _handler(self, signum: int, frame: Any) -> None:
        import signal

        if self.requested is not None:  # asked twice: stop now, without saving
            raise KeyboardInterrupt
        self.requested = signal.Signals(signum).name
        print(
            f"\n{self.requested}: stopping after the current optimiser step (Ctrl-C again to "
            "stop at once)",
            file=sys.stderr,
        )

    def on_train_start(self, trainer: pl.Trainer, pl_module: pl.LightningModule) -> None:
        import signal
        import threading

        if threading.current_thread() is not threading.main_thread():
            return  # signal handlers can only be installed from the main thread
        preempt = preemption_signal()
        for sig in (signal.SIGINT, signal.SIGTERM, *([preempt] if preempt else [])):
            self._previous[sig] = signal.signal(sig, self._handler)
        from shapebench.train.lifecycle import stop_requested

        if self.requested is None and (asked := stop_requested()) is not None:
            self.requested = asked  # asked before training started, its interrupt lost

    def teardown(self, trainer: pl.Trainer, pl_module: pl.LightningModule, stage: str) -> None:
        import signal

        for sig, handler in self._previous.items():
            signal.signal(sig, handler)
        self._previous.clear()

    def on_train_batch_end(
        self,
        trainer: pl.Trainer,
        pl_module: pl.LightningModule,
        outputs: Any,
        batch: Any,
        batch_idx: int,
    ) -> None:
        if batch_idx + 1 >= trainer.num_training_batches:
            return  # the epoch's last step: stop at its end (on_train_epoch_end), not before
        if self._asked(trainer):
            if trainer.world_size == 1:
                trainer.save_checkpoint(self.path, weights_only=False)
            raise StopRequested(self.requested or "stop requested by another rank")

    def on_train_epoch_end(self, trainer: pl.Trainer, pl_module: pl.LightningModule) -> None:
        if self._asked(trainer):
            # An epoch end: every rank saves together.
            trainer.save_checkpoint(self.path, weights_only=False)
            raise StopRequested(self.requested or "stop requested by another rank")

    def _asked(self, trainer: pl.Trainer) -> bool:
        stop = self.requested is not None
        if trainer.world_size > 1:  # a signal reaches one rank; every rank must stop together
            stop = bool(trainer.strategy.reduce_boolean_decision(stop, all=False))
        return stop


class AtomicCheckpointIO(TorchCheckpointIO):
    """Writes a checkpoint beside its destination, flushes it to disk, then renames it over the
    destination: a kill at any moment leaves either the previous checkpoint or the new one,
    never a truncated file."""

    def save_checkpoint(
        self, checkpoint: dict[str, Any], path: Any, storage_options: Any | None = None
    ) -> None:
        import os

        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
        with open(tmp, "wb") as f:
            torch.save(checkpoint, f)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)


class EpochCheckpoints(pl.Callback):
    """Saves ``last.ckpt`` at the end of every ``every_epochs``-th epoch, at the end of the first
    epoch after ``minutes`` have passed since the last save, and at the last epoch.

    What an epoch computes depends on nothing but the state it starts from
    (:class:`~shapebench.train.seeding.EpochSeeds`), so resuming from an epoch end gives exactly
    the weights of an uninterrupted training; a stop asked for by a signal is saved mid-epoch by
    :class:`StopOnSignal`. The checkpoint records its checkpoint key (the name of the training's
    folder) under ``"shapebench"``.
    """

    def __init__(self, path: Path, key: str, every_epochs: int = 1, minutes: float = 0.0) -> None:
        self.path = path
        self.key = key
        self.every_epochs = max(int(every_epochs), 0)
        self.seconds = max(float(minutes), 0.0) * 60
        self._last = time.monotonic()
        #: Epochs completed by the last save (-1: none in this process).
        self.saved_epochs = -1

    def on_train_epoch_end(self, trainer: pl.Trainer, pl_module: pl.LightningModule) -> None:
        done = trainer.current_epoch + 1
        due = (
            (self.every_epochs and done % self.every_epochs == 0)
            or (self.seconds and time.monotonic() - self._last >= self.seconds)
            or (trainer.max_epochs not in (None, -1) and done >= trainer.max_epochs)
            # A step budget ends mid-epoch; Lightning still ends that epoch (this hook runs).
            or (trainer.max_steps not in (None, -1) and trainer.global_step >= trainer.max_steps)
        )
        # Every rank must take the same decision: saving is a collective call under DDP.
        if trainer.strategy.broadcast(bool(due), src=0):
            trainer.save_checkpoint(self.path, weights_only=False)
            self._last = time.monotonic()
            self.saved_epochs = done

    def on_save_checkpoint(
        self, trainer: pl.Trainer, pl_module: pl.LightningModule, checkpoint: dict[str, Any]
    ) -> None:
        from shapebench.train.checkpoints import STAMP

        checkpoint[STAMP] = {"key": self.key}


class TrainingPlan(pl.Callback):
    """Says what a training is about to cost, so that nobody starts a 44-hour run by accident.

    When training starts: ``training plan: 66 shapes, 2700 optimiser steps (300 epochs x 9
    batches of 8 shapes per device), on cpu x1``; after ``timed`` more steps (the first is left
    out: it pays for start-up), the measured time per step and the estimated time left. Rank 0
    only; ``quiet`` silences both.
    """

    def __init__(self, quiet: bool = False, timed: int = 5) -> None:
        self.quiet = quiet
        self.timed = timed
        self._clock: float | None = None
        self._from_step = 0
        self.total = 0
        #: Seconds per optimiser step, once measured.
        self.step_seconds: float | None = None

    def on_train_start(self, trainer: pl.Trainer, pl_module: pl.LightningModule) -> None:
        batches = int(trainer.num_training_batches)
        shapes = len(trainer.train_dataloader.dataset)
        batch = min(int(trainer.train_dataloader.batch_size or 1), shapes)
        if trainer.max_steps not in (None, -1):
            self.total = int(trainer.max_steps)
            epochs = -(-self.total // max(batches, 1))
            how = f"about {epochs} epochs of {batches} batches"
        else:
            self.total = int(trainer.max_epochs) * batches
            how = f"{trainer.max_epochs} epochs x {batches} batches"
        device = trainer.strategy.root_device.type
        devices = trainer.num_devices * trainer.num_nodes
        done = int(trainer.global_step)
        resuming = f", resuming at step {done}" if done else ""
        self._say(
            f"training plan: {shapes} shapes, {self.total} optimiser steps ({how} of {batch} "
            f"shapes per device), on {device} x{devices}{resuming}",
            trainer,
        )
        # Few steps left: time them all, at least one.
        self.timed = max(1, min(self.timed, self.total - done - 2))

    def on_train_batch_end(
        self,
        trainer: pl.Trainer,
        pl_module: pl.LightningModule,
        outputs: Any,
        batch: Any,
        batch_idx: int,
    ) -> None:
        if self.step_seconds is not None:
            return
        if self._clock is None:  # the first step ends: start the clock
            self._clock, self._from_step = time.perf_counter(), int(trainer.global_step)
            return
        timed = int(trainer.global_step) - self._from_step
        if timed < self.timed:
            return
        self.step_seconds = (time.perf_counter() - self._clock) / timed
        left = max(self.total - int(trainer.global_step), 0)
        self._say(
            f"{self.step_seconds:.3g} s per optimiser step over {timed} steps; about "
            f"{_hms(self.step_seconds * left)} for the {left} step{'' if left == 1 else 's'} left",
            trainer,
        )

    def _say(self, line: str, trainer: pl.Trainer) -> None:
        if not self.quiet and trainer.is_global_zero:
            print(line, file=sys.stderr, flush=True)


def _hms(seconds: float) -> str:
    """``42 s``, ``12 min``, ``3.5 h``: an estimate's precision."""
    if seconds < 90:
        return f"{seconds:.0f} s"
    if seconds < 5400:
        return f"{seconds / 60:.0f} min"
    return f"{seconds / 3600:.1f} h"
