"""The base of every method trained with PyTorch Lightning (IGR, DeepSDF, MSC, OccNet, PCN).

A trained method is an options dataclass, a :class:`LightningMethod` subclass that declares what
it trains on and how it completes, and a LightningModule (an
:class:`~shapebench.implicit.module_base.OptionsModule`) in a module of its own, which this base
imports lazily so that registering the method never imports torch. The base does the rest:
recipes, the training data, ``fit``, safe checkpoint loading and the batched completion loop.
"""

from __future__ import annotations

import importlib
from abc import abstractmethod
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import TYPE_CHECKING, Any, ClassVar

from shapebench.api.method import Method, TrainingContext
from shapebench.api.types import Completion, Context, Supervision

if TYPE_CHECKING:  # annotations only: the method classes are imported by `shapebench methods`,
    import numpy as np  # which must not pay for torch (shapebench.api.method's lazy-torch rule)
    import torch

    from shapebench.train.lightning_fit import ShapeDataModule


class LightningMethod(Method):
    """A method trained with PyTorch Lightning.

    A subclass sets ``Options``, ``supervision``, :attr:`module_path` and, when some options
    default to a recipe's value, :attr:`recipes`; it implements :meth:`sample_sizes` and
    :meth:`decode`, and :meth:`encode` unless the module's ``encoder`` maps context points to
    codes. Its LightningModule takes the resolved options and the number of training objects
    (:class:`~shapebench.implicit.module_base.OptionsModule`).
    """

    trains = True
    batch_size = 8
    #: ``"package.module:Class"`` of the method's LightningModule, imported on first use.
    module_path: ClassVar[str] = ""
    #: Recipe name -> option values that fill the options left at ``None`` (see
    #: :func:`shapebench.implicit.recipes.apply_recipe`); None: the options have no recipe.
    recipes: ClassVar[dict[str, dict[str, Any]] | None] = None
    #: The shared training loop changes trained weights: its source is part of the keys.
    code_modules: ClassVar[tuple[str, ...]] = ("shapebench.train.lightning_fit",)

    def __init__(self, options: Any | None = None) -> None:
        super().__init__(options)
        if self.recipes is not None:
            from shapebench.implicit.recipes import apply_recipe

            self.options = apply_recipe(self.options, self.recipes, self.label)
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
        from shapebench.train.lightning_fit import ShapeDataModule

        return ShapeDataModule(ctx.dataset, self.needs(), self.sample_sizes(),
                               self.options.batch_shapes, seed=ctx.trainer.seed,
                               quiet=ctx.quiet)  # fmt: skip

    def build_module(self, n_shapes: int):
        """A fresh LightningModule for ``n_shapes`` training objects (its initial weights are
        drawn from torch's global generator)."""
        return self.Module(self.options, n_shapes)

    def fit(self, ctx: TrainingContext) -> Path:
        from shapebench.train.lightning_fit import fit_lightning, seed_training

        data = self.data_module(ctx)
        n_shapes = data.load_objects()
        seed_training(ctx.trainer.seed)  # the initial weights are drawn here, not in fit_lightning
        return fit_lightning(self.build_module(n_shapes), data, ctx, self.options.epochs)

    def load_checkpoint(self, path: Path) -> None:
        """Load ``Module`` from ``path``; the file may come from the user (``--checkpoint``), so
        it is read with ``weights_only=True`` after a checksum test: a damaged file or a pickled
        payload raises a :class:`~shapebench.api.errors.ShapebenchError` naming it."""
        from shapebench.train.checkpoints import load_module
        from shapebench.train.lightning_fit import device

        self.device = device()
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

        from shapebench.implicit.completion import stack_contexts

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


class ImplicitMethod(LightningMethod):
    """A LightningMethod whose codes define an implicit surface: :meth:`decode` meshes
    :meth:`field` by marching cubes at :meth:`level` and samples the completion on the mesh
    (:meth:`mesh`).

    The default field is an SDF, ``module.decoder(z, x)``; the options hold ``mesh_resolution``
    and ``largest_component`` (and ``mesh_bf16`` for the default field).
    """

    #: Whether the field is negative inside (an SDF) rather than positive (logits).
    inside_is_negative: ClassVar[bool] = True

    def field(self, code: Any) -> Callable[[np.ndarray], np.ndarray]:
        """The field of one code as a numpy function of (N, 3) points."""
        from shapebench.implicit.completion import field_of

        return field_of(self.module.decoder, code, self.device, bf16=self.options.mesh_bf16)

    def level(self) -> float:
        """The field's value on the surface."""
        return 0.0

    def decode(self, code: Any, ctx: Context, n_points: int) -> Completion:
        return self.mesh(code, ctx, n_points)

    def mesh(self, code: Any, ctx: Context, n_points: int) -> Completion:
        """Marching cubes on the field of ``code``, ``n_points`` sampled on the mesh."""
        from shapebench.implicit.completion import mesh_completion

        o = self.options
        return mesh_completion(self.field(code), ctx, n_points, o.mesh_resolution,
                               level=self.level(), inside_is_negative=self.inside_is_negative,
                               keep_largest=bool(o.largest_component))  # fmt: skip

    def optimise_codes(self, loss: Callable[[torch.Tensor], torch.Tensor],
                       init: torch.Tensor) -> torch.Tensor:  # fmt: skip
        """Codes from ``init`` by the shared test-time optimiser (``opt_steps``, ``opt_lr``,
        ``opt_scale_by_error``), ``loss`` giving one value per object."""
        from shapebench.implicit.completion import optimise_latents

        o = self.options
        z, _ = optimise_latents(loss, init, o.opt_steps, o.opt_lr, o.opt_scale_by_error)
        return z
