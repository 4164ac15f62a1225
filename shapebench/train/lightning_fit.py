"""Training with PyTorch Lightning, shared by every trainable built-in method.

:class:`ShapeDataModule` turns any dataset plugin's ``train`` split into batches of shapes (random
surface points with normals and, when asked, SDF samples, freshly drawn every step);
:func:`fit_lightning` runs one ``Trainer.fit`` with the Trainer options from the command line,
checkpoints into the training's private folder (``last.ckpt``, resumed from when present), logs
curves to the MLflow run the orchestrator created for this training (rank 0 only) and ends with a
summary (wall time, device, epochs, steps, final loss terms) on stderr and in that run. Every draw
is seeded from the trainer seed (see :func:`fit_lightning`).

shapebench uses the ``pytorch_lightning`` namespace throughout; never mix in ``lightning.pytorch``.
"""

from __future__ import annotations

import json
import re
import sys
import time
from collections.abc import Iterator, Mapping
from pathlib import Path
from typing import Any

import numpy as np
import pytorch_lightning as pl
import torch
from pytorch_lightning.plugins import TorchCheckpointIO
from pytorch_lightning.utilities.exceptions import SIGTERMException
from torch.utils.data import DataLoader, Sampler
from torch.utils.data import Dataset as TorchDataset

from shapebench.api.dataset import Dataset, ObjectLoadError
from shapebench.api.errors import Interrupted, ShapebenchError
from shapebench.api.method import TrainingContext
from shapebench.api.types import TRAIN, Supervision
from shapebench.hashing import stable_seed
from shapebench.progress import is_terminal


def device_count(device: str) -> int:
    """Devices of a ``training_device`` tag (``cpu x1``, ``cuda x4 (NVIDIA H100)``); 1 if none."""
    match = re.search(r"\bx(\d+)", device or "")
    return int(match.group(1)) if match else 1


def device_hours(wall_seconds: float, devices: int) -> float:
    """Devices held times wall time, in hours: what a cluster bills."""
    return float(wall_seconds) * max(int(devices), 1) / 3600.0


def seed_training(seed: int) -> None:
    """Seed Python's, numpy's and torch's global generators (DataLoader workers included): call
    it before building the module, whose initial weights come from them."""
    pl.seed_everything(seed, workers=True, verbose=False)


def derived_seed(seed: int, *parts: object) -> int:
    """A seed for one stream of draws of a training seeded with ``seed`` (63 bits)."""
    return stable_seed("training", seed, *parts)


def global_rank() -> int:
    """This process's rank once DDP is initialised, 0 otherwise."""
    dist = torch.distributed
    return dist.get_rank() if dist.is_available() and dist.is_initialized() else 0


def step_generator(module: pl.LightningModule) -> torch.Generator:
    """The CPU generator a training step draws its subsets and sizes from.

    :func:`fit_lightning` seeds it from the trainer seed, the rank and the step (see
    :class:`EpochSeeds`); a module stepped outside ``fit`` (tests) gets one seeded from torch's
    global seed.
    """
    gen = getattr(module, "_step_generator", None)
    if gen is None:
        gen = torch.Generator().manual_seed(derived_seed(torch.initial_seed(), "steps"))
        module._step_generator = gen
    return gen


class EpochSeeds(pl.Callback):
    """Reseeds every stream of random draws from (seed, rank, epoch or step).

    The per-step generator (:func:`step_generator`) and torch's global generator (noise a
    training step draws on the device) are seeded before every optimiser step from (seed, rank,
    global step); the data draws (:class:`ShapeSamples`) and the shuffle order before every epoch
    from (seed, rank, epoch). What an epoch computes then depends only on the weights and
    optimiser state it starts from, which the checkpoints hold: a training resumed from an
    epoch-end checkpoint gives bitwise the weights of an uninterrupted one.
    """

    def __init__(self, seed: int) -> None:
        self.seed = seed

    def on_train_epoch_start(self, trainer: pl.Trainer, pl_module: pl.LightningModule) -> None:
        data = trainer.datamodule
        if isinstance(data, ShapeDataModule):
            data.start_epoch(trainer.current_epoch)

    def on_train_batch_start(
        self, trainer: pl.Trainer, pl_module: pl.LightningModule, batch: Any, batch_idx: int
    ) -> None:
        seed = derived_seed(self.seed, "steps", trainer.global_rank, trainer.global_step)
        pl_module._step_generator = torch.Generator().manual_seed(seed)
        torch.manual_seed(
            derived_seed(self.seed, "global", trainer.global_rank, trainer.global_step)
        )


class ShapeSamples(TorchDataset):
    """Item i: a fresh random subset of object i's training arrays, and i (for auto-decoders).

    Draws come from one generator per object and epoch, seeded from (``seed``, rank, i, epoch):
    an object's subsets do not depend on the order objects are visited in nor on where a
    training was resumed, so two trainings with the same seed see the same data. The DataLoader
    runs in the training process (``num_workers=0``), where these generators live;
    :meth:`ShapeDataModule.start_epoch` sets :attr:`epoch`.
    """

    def __init__(
        self,
        objects: list[dict[str, np.ndarray]],
        surface_points: int,
        sdf_points: int = 0,
        target_points: int = 0,
        query_points: int = 0,
        seed: int = 0,
    ) -> None:
        self.objects = [
            {k: torch.from_numpy(np.ascontiguousarray(v)) for k, v in o.items()} for o in objects
        ]
        self.surface_points = surface_points
        self.sdf_points = sdf_points
        self.target_points = target_points
        self.query_points = query_points
        self.seed = seed
        self.epoch = 0
        self._generators: dict[int, torch.Generator] = {}
        for o in self.objects:
            if "sdf" in o and sdf_points:  # DeepSDF draws half of its samples outside, half inside
                o["sdf_pos"] = o["sdf"][o["sdf"][:, 3] > 0]
                o["sdf_neg"] = o["sdf"][o["sdf"][:, 3] <= 0]

    def __len__(self) -> int:
        return len(self.objects)

    def set_epoch(self, epoch: int) -> None:
        if epoch != self.epoch:
            self.epoch = epoch
            self._generators.clear()

    def generator(self, i: int) -> torch.Generator:
        if i not in self._generators:  # created lazily: the rank is known once DDP is set up
            seed = derived_seed(self.seed, "samples", global_rank(), i, self.epoch)
            self._generators[i] = torch.Generator().manual_seed(seed)
        return self._generators[i]

    def __getitem__(self, i: int) -> dict[str, torch.Tensor]:
        o = self.objects[i]
        gen = self.generator(i)

        def draw(array: torch.Tensor, k: int) -> torch.Tensor:
            return array[torch.randint(len(array), (k,), generator=gen)]

        item = {"index": torch.tensor(i)}
        idx = torch.randint(len(o["points"]), (self.surface_points,), generator=gen)
        item["points"], item["normals"] = o["points"][idx], o["normals"][idx]
        if "occupancy" in o and self.query_points:
            item["occupancy"] = draw(o["occupancy"], self.query_points)
        if "complete_points" in o and self.target_points:
            item["complete"] = draw(o["complete_points"], self.target_points)
        if self.sdf_points:
            half = self.sdf_points // 2
            parts = [draw(s, half) for s in (o["sdf_pos"], o["sdf_neg"]) if len(s)]
            item["sdf"] = torch.cat(parts)[: self.sdf_points]
        return item


class EpochShuffle(Sampler[int]):
    """The objects in an order drawn from (seed, epoch) alone, when the epoch starts.

    A stateful generator would make the order depend on when Lightning creates the epoch's
    iterator relative to the epoch hooks, which differs between a fresh and a resumed training.
    """

    def __init__(self, n: int, seed: int) -> None:
        self.n = n
        self.seed = seed
        self.epoch = 0
        #: Leading items of the next epoch already trained on (a training resumed mid-epoch).
        self.skip = 0

    def set_epoch(self, epoch: int) -> None:  # Lightning calls it before every epoch too
        self.epoch = int(epoch)

    def __len__(self) -> int:
        return self.n

    def __iter__(self) -> Iterator[int]:
        gen = torch.Generator().manual_seed(derived_seed(self.seed, "order", self.epoch))
        skip, self.skip = self.skip, 0
        return iter(torch.randperm(self.n, generator=gen).tolist()[skip:])


def steps_into_epoch(trainer: pl.Trainer, batches_per_epoch: int) -> int:
    """Optimiser steps a restored training had done in the epoch it resumes (0 unless its
    checkpoint was written mid-epoch, see :class:`StopOnSignal`): one step per batch."""
    if trainer.world_size != 1:
        return 0  # mid-epoch checkpoints are written by single-process trainings only
    epoch = trainer.fit_loop.epoch_progress.current.processed
    done = trainer.global_step - epoch * batches_per_epoch
    return done if 0 < done < batches_per_epoch else 0


class ShapeDataModule(pl.LightningDataModule):
    """The ``train`` split of a shapebench dataset, loaded once, sampled every step.

    ``samples``: how many samples of each kind a batch holds per object (the method's
    ``sample_sizes()``): surface points with normals (``points``, ``normals``; every batch has
    them, one per object when not given), SDF samples (``sdf``), occupancy queries
    (``occupancy``) and complete-surface points (``complete``). ``need`` is what to load.

    ``queries_from_sdf``: OccNet's queries as the paper draws them, from the SDF samples labelled
    inside where sdf < 0 (:func:`shapebench.preprocess.samples.occupancy_from_sdf`), instead of
    the dataset's uniform occupancy samples; ``need`` must then ask for SDF samples.
    """

    def __init__(
        self,
        dataset: Dataset,
        need: frozenset[Supervision],
        samples: Mapping[Supervision, int],
        batch_size: int,
        seed: int = 0,
        quiet: bool = False,
        queries_from_sdf: bool = False,
    ) -> None:
        super().__init__()
        self.quiet = quiet
        self.dataset = dataset
        self.need = need
        # One surface point when none is asked for: what was always drawn, so that every
        # object's stream of draws stays as it was.
        self.surface_points = samples.get(Supervision.SURFACE_POINTS, 1)
        self.sdf_points = samples.get(Supervision.SDF_SAMPLES, 0)
        self.query_points = samples.get(Supervision.OCCUPANCY_SAMPLES, 0)
        self.target_points = samples.get(Supervision.COMPLETE_POINTS, 0)
        self.batch_size = batch_size
        self.seed = seed
        self.queries_from_sdf = queries_from_sdf
        self.refs = []
        self._objects: list[dict[str, np.ndarray]] = []
        self._samples: ShapeSamples | None = None
        self._order: EpochShuffle | None = None

    def load_objects(self) -> int:
        """Load (preprocessing if needed) every training object; return how many are usable."""
        from shapebench.progress import progress_bar

        refs = self.dataset.objects(TRAIN)
        if not refs:
            raise ShapebenchError(f"dataset {self.dataset.name!r} has no training objects")
        for ref in progress_bar(desc="loading training objects", quiet=self.quiet, iterable=refs):
            try:
                data = self.dataset.load(ref, need=self.need)
            except ObjectLoadError:
                continue  # a broken training object is skipped, not fatal
            self.refs.append(ref)
            self._objects.append(self._arrays(data))
        if not self._objects:
            raise ShapebenchError(f"no training object of {self.dataset.name!r} could be loaded")
        return len(self._objects)

    def _arrays(self, data) -> dict[str, np.ndarray]:
        arrays = {"points": data.surface_points, "normals": data.surface_normals}
        for name in ("sdf", "occupancy", "complete_points"):
            if name in data.extra:
                arrays[name] = data.extra[name]
        if self.queries_from_sdf:
            from shapebench.preprocess.samples import occupancy_from_sdf

            arrays["occupancy"] = occupancy_from_sdf(arrays.pop("sdf"))
        return arrays

    def train_dataloader(self) -> DataLoader:
        samples = ShapeSamples(
            self._objects,
            self.surface_points,
            self.sdf_points,
            self.target_points,
            self.query_points,
            self.seed,
        )
        self._samples = samples
        self._order = EpochShuffle(len(samples), self.seed)
        batch = min(self.batch_size, len(samples))
        # Lightning draws the first batch of the first epoch it runs before any epoch hook: seed
        # that epoch here (a resumed training has restored its epoch count by now), and skip
        # the batches a training stopped mid-epoch had already stepped on.
        trainer = getattr(self, "trainer", None)
        self.start_epoch(trainer.fit_loop.epoch_progress.current.processed if trainer else 0)
        if trainer is not None:
            self._order.skip = batch * steps_into_epoch(trainer, -(-len(samples) // batch))
        return DataLoader(
            samples, batch_size=batch, sampler=self._order, num_workers=0, drop_last=False
        )

    def start_epoch(self, epoch: int) -> None:
        """Seed the shuffle order and the data draws of ``epoch`` (see :class:`EpochSeeds`)."""
        if self._order is not None:
            self._order.set_epoch(epoch)
        if self._samples is not None:
            self._samples.set_epoch(epoch)


#: The checkpoint a training resumes from, in its private folder.
LAST = "last.ckpt"


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
    launcher requeues the job (:func:`shapebench.sweeps.cluster.requeue_after`)."""
    import os
    import signal

    if not os.environ.get("SLURM_JOB_ID"):
        return None
    name = os.environ.get("SUBMITIT_PREEMPT_SIGNAL", "USR1")
    return getattr(signal, f"SIG{name}", None)


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

    What an epoch computes depends on nothing but the state it starts from (:class:`EpochSeeds`),
    so resuming from an epoch end gives exactly the weights of an uninterrupted training; a stop
    asked for by a signal is saved mid-epoch by :class:`StopOnSignal`. The checkpoint records its
    checkpoint key (the name of the training's folder) under ``"shapebench"``.
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


class StopRequested(Exception):
    """Raised at the end of an optimiser step after Ctrl-C or SIGTERM asked training to stop."""


class StopOnSignal(pl.Callback):
    """Ctrl-C or SIGTERM: finish the optimiser step in progress, save ``last.ckpt``, stop.

    Stopping between steps keeps the weights, the optimiser and the step count consistent (a
    ``KeyboardInterrupt`` raised inside ``optimizer.step`` would not). A single-process training
    saves where it stopped, and resumes there exactly: the next run skips the batches of the
    epoch already stepped on (:func:`steps_into_epoch`), and every draw is a function of the
    epoch and step (:class:`EpochSeeds`). A DDP training keeps its last epoch-end checkpoint. A
    second Ctrl-C stops at once.
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


def _cluster_environment() -> list[Any]:
    """Inside a SLURM job: Lightning's SLURM environment (ranks and world size from ``srun``)
    without its auto-requeue. Its handler writes an ``hpc_ckpt`` from inside the signal handler,
    in the middle of a step; :class:`StopOnSignal` stops after the step instead, writes the
    ``last.ckpt`` an exact resume needs, and the launcher requeues the job."""
    from lightning_fabric.plugins.environments import SLURMEnvironment

    if not SLURMEnvironment.detect():
        return []
    return [SLURMEnvironment(auto_requeue=False)]


def checkpoint_epochs(path: Path) -> int | None:
    """How many whole epochs the checkpoint at ``path`` holds (a mid-epoch one: those before
    its epoch), or None if it cannot be read."""
    try:
        return _epochs_of(torch.load(path, map_location="cpu", weights_only=True))
    except Exception:
        return None


def _epochs_of(state: dict[str, Any]) -> int:
    try:
        return int(state["loops"]["fit_loop"]["epoch_progress"]["current"]["processed"])
    except (KeyError, TypeError):
        return int(state.get("epoch", -1)) + 1


def _describe(state: dict[str, Any]) -> str:
    """How far a loaded checkpoint got, for messages."""
    return f"{_epochs_of(state)} epochs done, optimiser step {int(state['global_step'])}"


def _resume_state(last: Path, key: str) -> dict[str, Any] | None:
    """The checkpoint to resume from, read once, or None when there is none. A damaged one is
    reported and deleted (training restarts from epoch 0); one stamped with another key is
    refused, naming both."""
    import warnings

    from shapebench.train.checkpoints import (
        CorruptFileWarning,
        key_of,
        load_safely,
        verify_checkpoint,
    )

    if not last.exists():
        return None
    try:
        state = load_safely(last)
    except ShapebenchError as exc:
        warnings.warn(f"{exc.message}; training from epoch 0", CorruptFileWarning, stacklevel=2)
        last.unlink(missing_ok=True)
        return None
    if key_of(last, state) not in (None, key):
        verify_checkpoint(last, key, state)  # raises, naming both keys
    return state


def _kept(last: Path) -> str:
    """What an interrupted training leaves to resume from, for its message."""
    if not last.exists():
        return "nothing was saved yet"
    try:
        state = torch.load(last, map_location="cpu", weights_only=True)
    except Exception:
        return f"{last} is unreadable"
    return f"its checkpoint ({_describe(state)}) is kept at {last}"


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
    (:class:`TrainingPlan`), and after a few steps an estimate of its time.

    Reproducible: Lightning's ``seed_everything`` seeds the global generators (weight
    initialisation), and every later draw (data subsets, shuffle order, per-step subsets, noise
    drawn on the device) is reseeded per epoch or per step from the trainer seed
    (:class:`EpochSeeds`); torch runs its deterministic algorithms where it has them
    (``deterministic="warn"``). Two trainings with the same seed, data and options give
    bitwise-identical weights on one device, and so does a training interrupted and resumed
    from its last checkpoint (:class:`EpochCheckpoints`, :class:`StopOnSignal`).

    Ctrl-C and SIGTERM (a parent that died, a scheduler's pre-emption) stop it at the end of the
    current optimiser step, save where it stopped (:class:`StopOnSignal`) and raise
    :class:`TrainingInterrupted`, saying where the rerun resumes from.
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
    state = _resume_state(last, ctx.workdir.name)
    resumed = _epochs_of(state) if state is not None else None
    if state is not None and trainer.is_global_zero:  # one line, worth it even when quiet
        print(f"resuming from {last} ({_describe(state)})", file=sys.stderr)
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
            f"{trainer.global_step}; {_kept(last)}",
            "run the same command again to resume",
            signal_name=stopper.requested,
        ) from exc
    summary = training_summary(trainer, time.perf_counter() - start)
    summary["resumed_from_epoch"] = resumed or 0
    if trainer.is_global_zero:
        report_summary(summary, logger or None, quiet=ctx.quiet)
        (ctx.workdir / SUMMARY_FILE).write_text(json.dumps(summary, indent=1))
    return last


#: The last training summary, next to the checkpoint (benchmarks/ladder.py reads it).
SUMMARY_FILE = "summary.json"


def training_summary(trainer: pl.Trainer, seconds: float) -> dict[str, Any]:
    """Wall time, device, epochs, optimiser steps and the last value of every logged term."""
    device = trainer.strategy.root_device
    kind = f"{device.type} x{trainer.num_devices * trainer.num_nodes}"
    if device.type == "cuda":
        kind += f" ({torch.cuda.get_device_name(device)})"
    terms = {
        k: float(v) for k, v in sorted(trainer.callback_metrics.items()) if k.startswith("train/")
    }

    # Device-hours: every device is held for the whole wall time (what a cluster bills).
    devices = int(trainer.num_devices * trainer.num_nodes)
    data = trainer.datamodule
    return {
        "wall_seconds": seconds,
        "device": kind,
        "devices": devices,
        "device_hours": device_hours(seconds, devices),
        # The training-set size: the x axis of a data-scaling figure.
        "training_shapes": len(data.refs) if isinstance(data, ShapeDataModule) else None,
        "epochs": int(trainer.current_epoch),
        "optimizer_steps": int(trainer.global_step),
        "final": terms,
    }


def report_summary(summary: dict[str, Any], logger: Any | None, quiet: bool = False) -> None:
    """Print the summary to stderr (unless ``quiet``) and log it to the MLflow training run."""
    if not quiet:
        terms = summary["final"].items()
        final = ", ".join(f"{k.removeprefix('train/')} {v:.4g}" for k, v in terms)
        hours = summary.get("device_hours")
        spent = f" ({hours:.3g} device-hours)" if hours is not None else ""
        shapes = summary.get("training_shapes")
        print(
            f"training done in {summary['wall_seconds']:.1f} s on {summary['device']}{spent}: "
            + (f"{shapes} shapes, " if shapes else "")
            + f"{summary['epochs']} epochs, {summary['optimizer_steps']} optimiser steps; "
            f"final {final or 'no logged terms'}",
            file=sys.stderr,
        )
    if logger is None:
        return
    metrics = {
        "summary/wall_seconds": summary["wall_seconds"],
        **({"summary/device_hours": summary["device_hours"]} if "device_hours" in summary else {}),
        "summary/epochs": float(summary["epochs"]),
        "summary/optimizer_steps": float(summary["optimizer_steps"]),
    }
    if summary.get("training_shapes"):
        metrics["summary/training_shapes"] = float(summary["training_shapes"])
    metrics.update(
        {f"summary/final_{k.removeprefix('train/')}": v for k, v in summary["final"].items()}
    )
    from shapebench.store.tracking import log_training_summary

    log_training_summary(logger, metrics, summary["optimizer_steps"], summary["device"])


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


def device() -> torch.device:
    """Where completion runs: the GPU when there is one."""
    return torch.device("cuda" if torch.cuda.is_available() else "cpu")
