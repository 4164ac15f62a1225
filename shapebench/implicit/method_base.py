"""What IGR, DeepSDF and MSC share as shapebench methods: Lightning training into a checkpoint,
batched latent inference, and meshing each latent into a completion."""

from __future__ import annotations

from abc import abstractmethod
from pathlib import Path
from typing import TYPE_CHECKING, Any, ClassVar

from shapebench.method import Method, TrainingContext
from shapebench.types import Completion, Context, Supervision

if TYPE_CHECKING:  # annotations only: the method classes are imported by `shapebench methods`,
    import torch  # which must not pay for torch (the lazy-torch rule of shapebench.method)


class LightningMethod(Method):
    """A method trained with PyTorch Lightning: subclasses set ``Module`` (a LightningModule
    class) and implement :meth:`build_module`; training data come from :meth:`data_module`."""

    trains = True
    batch_size = 8
    Module: ClassVar[type]
    #: The shared training loop changes trained weights: its source is part of the keys.
    code_modules: ClassVar[tuple[str, ...]] = ("shapebench.lightning_fit",)

    def __init__(self, options: Any | None = None) -> None:
        super().__init__(options)
        self.module = None

    def needs(self) -> frozenset[Supervision]:
        """What this configured instance needs from the training split.

        The class attribute ``supervision`` is the union over every option value (what
        ``shapebench prepare -m`` builds); an instance may need less, as OccNet, whose query
        source depends on its recipe.
        """
        return frozenset(self.supervision)

    def data_module(self, ctx: TrainingContext):
        """The training split as batches of ``batch_shapes`` objects, each with
        ``surface_points`` surface points and ``sdf_points`` SDF samples (options the method may
        have), every draw seeded from the trainer seed."""
        from shapebench.lightning_fit import ShapeDataModule

        o = self.options
        return ShapeDataModule(ctx.dataset, self.needs(), getattr(o, "surface_points", 1),
                               o.batch_shapes, sdf_points=getattr(o, "sdf_points", 0),
                               quiet=ctx.quiet,
                               target_points=getattr(o, "target_points", 0),
                               query_points=getattr(o, "query_points", 0),
                               seed=ctx.trainer.seed)  # fmt: skip

    @abstractmethod
    def build_module(self, n_shapes: int):
        """A fresh LightningModule for ``n_shapes`` training objects."""

    def fit(self, ctx: TrainingContext) -> Path:
        from shapebench.lightning_fit import fit_lightning, seed_training

        data = self.data_module(ctx)
        n_shapes = data.load_objects()
        seed_training(ctx.trainer.seed)  # the initial weights are drawn here, not in fit_lightning
        return fit_lightning(self.build_module(n_shapes), data, ctx, self.options.epochs)

    def load_checkpoint(self, path: Path) -> None:
        """Load ``Module`` from ``path``; the file may come from the user (``--checkpoint``), so
        it is read with ``weights_only=True`` after a checksum test: a damaged file or a pickled
        payload raises a :class:`~shapebench.errors.ShapebenchError` naming it."""
        from shapebench.checkpoints import load_module
        from shapebench.lightning_fit import device

        self.device = device()
        self.module = load_module(self.Module, Path(path), self.device)
        self.module.eval()
        for p in self.module.parameters():
            p.requires_grad_(False)

    def complete(self, context: Context, n_points: int) -> Completion:
        result = self.complete_batch([context], n_points)[0]
        if isinstance(result, Exception):
            raise result
        return result


class ImplicitMethod(LightningMethod):
    """A LightningMethod whose ``Module`` has a ``decoder`` of an implicit surface: latent codes
    from :meth:`infer_latents`, then marching cubes."""

    @abstractmethod
    def infer_latents(self, contexts: list[Context]) -> torch.Tensor:
        """One latent code per context, (B, d), on :attr:`device`."""

    def complete_batch(
        self, contexts: list[Context], n_points: int
    ) -> list[Completion | Exception]:
        if self.module is None:
            raise RuntimeError(f"{self.name}: load_checkpoint() was not called")
        # Test-time draws (Eikonal samples around the context, posterior samples) come from
        # torch's global generator: seed it from this batch's contexts, so that an object's
        # completion does not depend on which cells ran earlier in the process (a resumed or
        # partial run then gives exactly what a full run gives).
        import torch

        from shapebench.hashing import stable_seed

        torch.manual_seed(stable_seed("complete", *(c.seed for c in contexts)) % (2**63))
        latents = self.infer_latents(contexts)
        out: list[Completion | Exception] = []
        for i, (z, ctx) in enumerate(zip(latents, contexts, strict=True)):
            try:
                out.append(self.decode(i, z, ctx, n_points))
            except Exception as exc:  # no surface, NaN, too large: this object fails alone
                out.append(exc)
        return out

    def decode(self, i: int, z: torch.Tensor, ctx: Context, n_points: int) -> Completion:
        """The completion of the ``i``-th context of the batch from its code ``z``."""
        return self.mesh(z, ctx, n_points)

    def mesh(self, z: torch.Tensor, ctx: Context, n_points: int) -> Completion:
        from shapebench.implicit.completion import field_of, mesh_completion

        o = self.options
        field = field_of(self.module.decoder, z, self.device, bf16=o.mesh_bf16)
        return mesh_completion(field, ctx, n_points, o.mesh_resolution,
                               keep_largest=bool(o.largest_component))  # fmt: skip
