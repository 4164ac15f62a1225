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
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytorch_lightning as pl
import torch
from torch.utils.data import DataLoader
from torch.utils.data import Dataset as TorchDataset

from shapebench.dataset import Dataset, ObjectLoadError
from shapebench.errors import ShapebenchError
from shapebench.hashing import stable_seed
from shapebench.method import TrainingContext
from shapebench.types import TRAIN, Supervision


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

    :func:`fit_lightning` seeds it from the trainer seed and the rank (see :class:`SeedSteps`);
    a module stepped outside ``fit`` (tests) gets one seeded from torch's global seed.
    """
    gen = getattr(module, "_step_generator", None)
    if gen is None:
        gen = torch.Generator().manual_seed(derived_seed(torch.initial_seed(), "steps"))
        module._step_generator = gen
    return gen


class SeedSteps(pl.Callback):
    """Gives the module a generator for its per-step draws, seeded from (seed, rank)."""

    def __init__(self, seed: int) -> None:
        self.seed = seed

    def on_fit_start(self, trainer: pl.Trainer, pl_module: pl.LightningModule) -> None:
        seed = derived_seed(self.seed, "steps", trainer.global_rank)
        pl_module._step_generator = torch.Generator().manual_seed(seed)


class ShapeSamples(TorchDataset):
    """Item i: a fresh random subset of object i's training arrays, and i (for auto-decoders).

    Draws come from one generator per object, seeded from (``seed``, rank, i): an object's
    sequence of subsets does not depend on the order objects are visited in, so two trainings
    with the same seed see the same data. The DataLoader runs in the training process
    (``num_workers=0``), where these generators live.
    """

    def __init__(self, objects: list[dict[str, np.ndarray]], surface_points: int,
                 sdf_points: int = 0, target_points: int = 0,
                 query_points: int = 0, seed: int = 0) -> None:  # fmt: skip
        self.objects = [{k: torch.from_numpy(np.ascontiguousarray(v)) for k, v in o.items()}
                        for o in objects]  # fmt: skip
        self.surface_points = surface_points
        self.sdf_points = sdf_points
        self.target_points = target_points
        self.query_points = query_points
        self.seed = seed
        self._generators: dict[int, torch.Generator] = {}
        for o in self.objects:
            if "sdf" in o and sdf_points:  # DeepSDF draws half of its samples outside, half inside
                o["sdf_pos"] = o["sdf"][o["sdf"][:, 3] > 0]
                o["sdf_neg"] = o["sdf"][o["sdf"][:, 3] <= 0]

    def __len__(self) -> int:
        return len(self.objects)

    def generator(self, i: int) -> torch.Generator:
        if i not in self._generators:  # created lazily: the rank is known once DDP is set up
            seed = derived_seed(self.seed, "samples", global_rank(), i)
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


class ShapeDataModule(pl.LightningDataModule):
    """The ``train`` split of a shapebench dataset, loaded once, sampled every step.

    ``queries_from_sdf``: OccNet's queries as the paper draws them, from the SDF samples labelled
    inside where sdf < 0 (:func:`shapebench.preprocess.samples.occupancy_from_sdf`), instead of
    the dataset's uniform occupancy samples; ``need`` must then ask for SDF samples.
    """

    def __init__(self, dataset: Dataset, need: frozenset[Supervision], surface_points: int,
                 batch_size: int, sdf_points: int = 0,
                 quiet: bool = False, target_points: int = 0,
                 query_points: int = 0, seed: int = 0,
                 queries_from_sdf: bool = False) -> None:  # fmt: skip
        super().__init__()
        self.quiet = quiet
        self.target_points = target_points
        self.query_points = query_points
        self.dataset = dataset
        self.need = need
        self.surface_points = surface_points
        self.sdf_points = sdf_points
        self.batch_size = batch_size
        self.seed = seed
        self.queries_from_sdf = queries_from_sdf
        self.refs = []
        self._objects: list[dict[str, np.ndarray]] = []

    def load_objects(self) -> int:
        """Load (preprocessing if needed) every training object; return how many are usable."""
        from tqdm import tqdm

        refs = self.dataset.objects(TRAIN)
        if not refs:
            raise ShapebenchError(f"dataset {self.dataset.name!r} has no training objects")
        for ref in tqdm(refs, desc="loading training objects", unit="obj", leave=False,
                        disable=self.quiet):  # fmt: skip
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
        samples = ShapeSamples(self._objects, self.surface_points, self.sdf_points,
                               self.target_points, self.query_points, self.seed)  # fmt: skip
        # The shuffle order has its own generator: it does not depend on what else drew numbers.
        order = torch.Generator().manual_seed(derived_seed(self.seed, "order"))
        return DataLoader(samples, batch_size=min(self.batch_size, len(samples)), shuffle=True,
                          num_workers=0, drop_last=False, generator=order)  # fmt: skip


def fit_lightning(module: pl.LightningModule, data: ShapeDataModule, ctx: TrainingContext,
                  max_epochs: int) -> Path:  # fmt: skip
    """One ``Trainer.fit``; resumes from ``<workdir>/last.ckpt``; returns that checkpoint.

    Reproducible: Lightning's ``seed_everything`` seeds the global generators (weight
    initialisation, noise drawn on the device), the data draws, the shuffle order and the
    per-step subsets have generators of their own seeded from the trainer seed, and torch runs
    its deterministic algorithms where it has them (``deterministic="warn"``). Two trainings
    with the same seed, data and options give bitwise-identical weights on one device; a resumed
    training restarts the generators, so it is not bitwise-identical to an uninterrupted one.
    """
    import logging
    import warnings

    from pytorch_lightning.callbacks import ModelCheckpoint
    from pytorch_lightning.loggers import MLFlowLogger

    t = ctx.trainer
    seed_training(t.seed)
    # Lightning's start-up banner (devices, tips) and a torch-internal deprecation are noise here.
    logging.getLogger("pytorch_lightning.utilities.rank_zero").setLevel(logging.WARNING)
    warnings.filterwarnings("ignore", message=r".*LeafSpec.*is deprecated")
    logger = (MLFlowLogger(tracking_uri=ctx.tracking_uri, run_id=ctx.run_id)
              if ctx.run_id else False)  # fmt: skip
    checkpoint = ModelCheckpoint(dirpath=ctx.workdir, save_last=True, save_top_k=0,
                                 every_n_epochs=1)  # fmt: skip
    trainer = pl.Trainer(
        accelerator=t.accelerator, devices=t.devices, strategy=t.strategy, num_nodes=t.num_nodes,
        precision=t.precision, max_epochs=t.max_epochs or max_epochs, logger=logger,
        callbacks=[checkpoint, SeedSteps(t.seed)], default_root_dir=ctx.workdir,
        log_every_n_steps=1, enable_model_summary=False, enable_progress_bar=not ctx.quiet,
        deterministic="warn",
    )  # fmt: skip
    last = ctx.workdir / "last.ckpt"
    start = time.perf_counter()
    trainer.fit(module, datamodule=data, ckpt_path=str(last) if last.exists() else None)
    summary = training_summary(trainer, time.perf_counter() - start)
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
    terms = {k: float(v) for k, v in sorted(trainer.callback_metrics.items())
             if k.startswith("train/")}  # fmt: skip
    return {"wall_seconds": seconds, "device": kind, "epochs": int(trainer.current_epoch),
            "optimizer_steps": int(trainer.global_step), "final": terms}  # fmt: skip


def report_summary(summary: dict[str, Any], logger: Any | None, quiet: bool = False) -> None:
    """Print the summary to stderr (unless ``quiet``) and log it to the MLflow training run."""
    if not quiet:
        terms = summary["final"].items()
        final = ", ".join(f"{k.removeprefix('train/')} {v:.4g}" for k, v in terms)
        print(f"training done in {summary['wall_seconds']:.1f} s on {summary['device']}: "
              f"{summary['epochs']} epochs, {summary['optimizer_steps']} optimiser steps; "
              f"final {final or 'no logged terms'}", file=sys.stderr)  # fmt: skip
    if logger is None:
        return
    metrics = {"summary/wall_seconds": summary["wall_seconds"],
               "summary/epochs": float(summary["epochs"]),
               "summary/optimizer_steps": float(summary["optimizer_steps"])}  # fmt: skip
    metrics.update({f"summary/final_{k.removeprefix('train/')}": v
                    for k, v in summary["final"].items()})  # fmt: skip
    logger.log_metrics(metrics, step=summary["optimizer_steps"])
    logger.experiment.set_tag(logger.run_id, "training_device", summary["device"])


def adam_halving(params, lr: float, every: int) -> dict:
    """Adam whose learning rates halve every ``every`` epochs (IGR's, DeepSDF's and the paper's
    schedule), in the form ``configure_optimizers`` returns. ``params`` may be parameter groups
    with their own ``lr``."""
    opt = torch.optim.Adam(params, lr=lr)
    sched = torch.optim.lr_scheduler.StepLR(opt, step_size=every, gamma=0.5)
    return {"optimizer": opt, "lr_scheduler": {"scheduler": sched, "interval": "epoch"}}


def device() -> torch.device:
    """Where completion runs: the GPU when there is one."""
    return torch.device("cuda" if torch.cuda.is_available() else "cpu")
