"""The training data of a Lightning-trained method: a dataset's ``train`` split as seeded batches.

:class:`ShapeDataModule` loads every training object once (its surface points with normals and
the supervision the method needs) and turns them into batches of shapes: random subsets of each
object's arrays, freshly drawn every step (:class:`ShapeSamples`), in an order drawn per epoch
(:class:`EpochShuffle`). Every draw is seeded from the trainer seed, the rank, the object and the
epoch (:func:`shapebench.train.seeding.derived_seed`), so that a training resumed from a
checkpoint sees the data an uninterrupted one sees.

This module changes what a training computes: it is part of the keys of every Lightning-trained
method (``LightningMethod.code_modules``).
"""

from __future__ import annotations

from collections.abc import Iterator, Mapping

import numpy as np
import pytorch_lightning as pl
import torch
from torch.utils.data import DataLoader, Sampler
from torch.utils.data import Dataset as TorchDataset

from shapebench.api.dataset import Dataset, ObjectLoadError
from shapebench.api.errors import ShapebenchError
from shapebench.api.types import TRAIN, Supervision
from shapebench.train.seeding import derived_seed, global_rank


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
    checkpoint was written mid-epoch, see :class:`~shapebench.train.callbacks.StopOnSignal`):
    one step per batch."""
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
        """Seed the shuffle order and the data draws of ``epoch`` (see
        :class:`~shapebench.train.seeding.EpochSeeds`)."""
        if self._order is not None:
            self._order.set_epoch(epoch)
        if self._samples is not None:
            self._samples.set_epoch(epoch)
