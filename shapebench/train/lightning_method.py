"""The base of every method trained with PyTorch Lightning (IGR, DeepSDF, MSC, OccNet, PCN).

A trained method is an options dataclass, a :class:`LightningMethod` subclass that declares what
it trains on and how it completes, and a LightningModule (an
:class:`~shapebench.train.lightning_module.OptionsModule`) in a module of its own, which this base
imports lazily so that registering the method never imports torch. The base does the rest:
the training data, ``fit``, safe checkpoint loading and the batched completion loop.
"""

from __future__ import annotations

import importlib
from abc import abstractmethod
from collections.abc import Iterable
from pathlib import Path
from typing import TYPE_CHECKING, Any, ClassVar

from shapebench.api.method import Method, TrainingContext
from shapebench.api.types import Completion, Context, Supervision

if TYPE_CHECKING:  # annotations only: the method classes are imported by `shapebench methods`,
    import torch

    from shapebench.train.data import ShapeDataModule


def completion_device() -> torch.device:
    """Where completion runs: the GPU when there is one."""
    import torch

    return torch.device("cuda" if torch.cuda.is_available() else "cpu")


def stack_contexts(
    contexts: list[Context], device: torch.device
) -> tuple[torch.Tensor, torch.Tensor | None]:
    """(B, k, 3) points, and normals or None; contexts of one cell all have the same size k.

    The benchmark's protocol gives methods points only, so normals are None unless every context
    carries them (``--context-normals``, see :mod:`shapebench.api.protocol`).
    """
    import numpy as np
    import torch

    pts = torch.from_numpy(np.stack([c.points for c in contexts])).to(device)
    normals = [getattr(c, "normals", None) for c in contexts]
    if any(n is None for n in normals):
        return pts, None
    return pts, torch.from_numpy(np.stack(normals)).to(device)


class LightningMethod(Method):
    """A method trained with PyTorch Lightning.

    A subclass sets ``Options``, ``supervision`` and :attr:`module_path`; it implements
    :meth:`sample_sizes` and :meth:`decode`, and :meth:`encode` unless the module's ``encoder``
    maps context points to codes. Its LightningModule takes the resolved options and the number
    of training objects (:class:`~shapebench.train.lightning_module.OptionsModule`).
    """

    trains = True
    batch_size = 8
    #: ``"package.module:Class"`` of the method's LightningModule, imported on first use.
    module_path: ClassVar[str] = ""
    #: The shared training loop, its data pipeline, its seeding and the modules' base change
    #: trained weights: their source is part of the keys. (The callbacks that save, stop and
    #: print, the resume helpers and the summary change no weight and are left out.)
    code_modules: ClassVar[tuple[str, ...]] = (
        "shapebench.train.lightning_fit",
        "shapebench.train.data",
        "shapebench.train.seeding",
        "shapebench.train.lightning_module",
    )

    def __init__(self, options: Any | None = None) -> None:
        super().__init__(options)
        self.module = None

    @property
    def label(self) -> str:
        """The method's name for messages (the class's when it was not registered)."""
        return self.name or self.checkpoint_family or type(self).__name__.lower()

    @property
    def Module(self) -> type:  # noqa: N802 (it names a class)
        """The LightningModule class at :attr:`module_path`."""
        if not self.module_path:
            raise TypeError(f"{type(self).__name__} sets no module_path ('package.module:Class')")
        module, _, cls = self.module_path.partition(":")
        return getattr(importlib.import_module(module), cls)

    # -- training ------------------------------------------------------------------------------

    def needs(self) -> frozenset[Supervision]:
        """What this configured instance needs from the training split.

        The class attribute ``supervision`` is the union over every option value (what
        ``shapebench prepare -m`` builds); an instance may need less, as OccNet, whose query
        source depends on its recipe.
        """
        return frozenset(self.supervision)

    @abstractmethod
    def sample_sizes(self) -> dict[Supervision, int]:
        """How many samples of each kind a batch holds per object and step (the kinds the
        module reads; surface points are always in a batch, one per object unless given)."""

    def data_module(self, ctx: TrainingContext) -> ShapeDataModule:
        """The training split as batches of ``batch_shapes`` objects holding
        :meth:`sample_sizes` samples, every draw seeded from the trainer seed."""
        from shapebench.train.data import ShapeDataModule

        return ShapeDataModule(
            ctx.dataset,
            self.needs(),
            self.sample_sizes(),
            self.options.batch_shapes,
            seed=ctx.trainer.seed,
            quiet=ctx.quiet,
        )

    def build_module(self, n_shapes: int):
        """A fresh LightningModule for ``n_shapes`` training objects (its initial weights are
        drawn from torch's global generator)."""
        return self.Module(self.options, n_shapes)

    def fit(self, ctx: TrainingContext) -> Path:
        from shapebench.train.lightning_fit import fit_lightning
        from shapebench.train.seeding import seed_training

        data = self.data_module(ctx)
        n_shapes = data.load_objects()
        seed_training(ctx.trainer.seed)  # the initial weights are drawn here, not in fit_lightning
        module = self.build_module(n_shapes)
        steps = int(getattr(self.options, "steps", 0) or 0)
        return fit_lightning(module, data, ctx, self.options.epochs, steps)

    def load_checkpoint(self, path: Path) -> None:
        """Load ``Module`` from ``path``; the file may come from the user (``--checkpoint``), so
        it is read with ``weights_only=True`` after a checksum test: a damaged file or a pickled
        payload raises a :class:`~shapebench.api.errors.ShapebenchError` naming it."""
        from shapebench.train.checkpoints import load_module

        self.device = completion_device()
        self.module = load_module(self.Module, Path(path), self.device)
        self.module.eval()
        for p in self.module.parameters():
            p.requires_grad_(False)

    # -- completion ----------------------------------------------------------------------------

    def encode(self, contexts: list[Context]) -> Iterable[Any]:
        """One code per context, in order (latent codes, posteriors, output clouds): the work
        done for the whole batch at once. The default, for a feed-forward encoder: the module's
        ``encoder`` on the context points (B, k, 3), without gradients."""
        import torch

        points, _ = stack_contexts(contexts, self.device)
        with torch.no_grad():
            return self.module.encoder(points)

    @abstractmethod
    def decode(self, code: Any, ctx: Context, n_points: int) -> Completion:
        """The completion of one context from its code; an exception fails this object alone."""

    def complete_batch(
        self, contexts: list[Context], n_points: int
    ) -> list[Completion | Exception]:
        """:meth:`encode` the batch, then :meth:`decode` each object, its failure captured."""
        if self.module is None:
            raise RuntimeError(f"{self.label}: load_checkpoint() was not called")
        # Test-time draws (Eikonal samples around the context, posterior samples) come from
        # torch's global generator: seed it from this batch's contexts, so that an object's
        # completion does not depend on which cells ran earlier in the process (a resumed or
        # partial run then gives exactly what a full run gives).
        import torch

        from shapebench.hashing import stable_seed

        torch.manual_seed(stable_seed("complete", *(c.seed for c in contexts)) % (2**63))
        codes = self.encode(contexts)
        out: list[Completion | Exception] = []
        for code, ctx in zip(codes, contexts, strict=True):
            try:
                out.append(self.decode(code, ctx, n_points))
            except Exception as exc:  # no surface, NaN, too large: this object fails alone
                out.append(exc)
        return out

    def complete(self, context: Context, n_points: int) -> Completion:
        result = self.complete_batch([context], n_points)[0]
        if isinstance(result, Exception):
            raise result
        return result
