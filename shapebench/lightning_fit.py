"""Training with PyTorch Lightning, shared by every trainable built-in method.

:class:`ShapeDataModule` turns any dataset plugin's ``train`` split into batches of shapes (random
surface points with normals and, when asked, SDF samples, freshly drawn every step);
:func:`fit_lightning` runs one ``Trainer.fit`` with the Trainer options from the command line,
checkpoints into the training's private folder (``last.ckpt``, resumed from when present) and logs
curves to the MLflow run the orchestrator created for this training (rank 0 only).

shapebench uses the ``pytorch_lightning`` namespace throughout; never mix in ``lightning.pytorch``.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytorch_lightning as pl
import torch
from torch.utils.data import DataLoader
from torch.utils.data import Dataset as TorchDataset

from shapebench.dataset import Dataset, ObjectLoadError
from shapebench.errors import ShapebenchError
from shapebench.method import TrainingContext
from shapebench.types import TRAIN, Supervision


class ShapeSamples(TorchDataset):
    """Item i: a fresh random subset of object i's training arrays, and i (for auto-decoders)."""

    def __init__(self, objects: list[dict[str, np.ndarray]], surface_points: int,
                 sdf_points: int = 0, target_points: int = 0,
                 query_points: int = 0) -> None:  # fmt: skip
        self.objects = [{k: torch.from_numpy(np.ascontiguousarray(v)) for k, v in o.items()}
                        for o in objects]  # fmt: skip
        self.surface_points = surface_points
        self.sdf_points = sdf_points
        self.target_points = target_points
        self.query_points = query_points
        for o in self.objects:
            if "sdf" in o:  # DeepSDF draws half of its samples outside, half inside
                o["sdf_pos"] = o["sdf"][o["sdf"][:, 3] > 0]
                o["sdf_neg"] = o["sdf"][o["sdf"][:, 3] <= 0]

    def __len__(self) -> int:
        return len(self.objects)

    def __getitem__(self, i: int) -> dict[str, torch.Tensor]:
        o = self.objects[i]
        idx = torch.randint(len(o["points"]), (self.surface_points,))
        item = {"index": torch.tensor(i), "points": o["points"][idx], "normals": o["normals"][idx]}
        if "occupancy" in o and self.query_points:
            occ = o["occupancy"]
            item["occupancy"] = occ[torch.randint(len(occ), (self.query_points,))]
        if "complete_points" in o and self.target_points:
            full = o["complete_points"]
            item["complete"] = full[torch.randint(len(full), (self.target_points,))]
        if self.sdf_points:
            half = self.sdf_points // 2
            parts = [s[torch.randint(len(s), (half,))] for s in (o["sdf_pos"], o["sdf_neg"])
                     if len(s)]  # fmt: skip
            item["sdf"] = torch.cat(parts)[: self.sdf_points]
        return item


class ShapeDataModule(pl.LightningDataModule):
    """The ``train`` split of a shapebench dataset, loaded once, sampled every step."""

    def __init__(self, dataset: Dataset, need: frozenset[Supervision], surface_points: int,
                 batch_size: int, sdf_points: int = 0,
                 quiet: bool = False, target_points: int = 0,
                 query_points: int = 0) -> None:  # fmt: skip
        super().__init__()
        self.quiet = quiet
        self.target_points = target_points
        self.query_points = query_points
        self.dataset = dataset
        self.need = need
        self.surface_points = surface_points
        self.sdf_points = sdf_points
        self.batch_size = batch_size
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
            arrays = {"points": data.surface_points, "normals": data.surface_normals}
            for name in ("sdf", "occupancy", "complete_points"):
                if name in data.extra:
                    arrays[name] = data.extra[name]
            self.refs.append(ref)
            self._objects.append(arrays)
        if not self._objects:
            raise ShapebenchError(f"no training object of {self.dataset.name!r} could be loaded")
        return len(self._objects)

    def train_dataloader(self) -> DataLoader:
        samples = ShapeSamples(self._objects, self.surface_points, self.sdf_points,
                               self.target_points, self.query_points)  # fmt: skip
        return DataLoader(samples, batch_size=min(self.batch_size, len(samples)), shuffle=True,
                          num_workers=0, drop_last=False)  # fmt: skip


def fit_lightning(module: pl.LightningModule, data: ShapeDataModule, ctx: TrainingContext,
                  max_epochs: int) -> Path:  # fmt: skip
    """One ``Trainer.fit``; resumes from ``<workdir>/last.ckpt``; returns that checkpoint."""
    import logging
    import warnings

    from pytorch_lightning.callbacks import ModelCheckpoint
    from pytorch_lightning.loggers import MLFlowLogger

    t = ctx.trainer
    pl.seed_everything(t.seed, workers=True, verbose=False)
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
        callbacks=[checkpoint], default_root_dir=ctx.workdir, log_every_n_steps=1,
        enable_model_summary=False, enable_progress_bar=not ctx.quiet,
    )  # fmt: skip
    last = ctx.workdir / "last.ckpt"
    trainer.fit(module, datamodule=data, ckpt_path=str(last) if last.exists() else None)
    return last


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
