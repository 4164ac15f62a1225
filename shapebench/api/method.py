"""The Method interface: complete a sparse context into a whole shape.

A method plugin subclasses :class:`Method` and registers it through the
``shapebench_register_methods`` hook (see :mod:`shapebench.api.hookspecs`). The class attributes
describe it to ``shapebench methods``; the orchestrator then:

1. builds it with its resolved options (``Method(options)``);
2. if ``trains`` is true: calls :meth:`Method.fit` on the dataset's ``train`` split, in a process of
   its own (Lightning's DDP allows one ``Trainer.fit`` per process), unless a checkpoint for the
   same (method config, dataset, seed) exists; then :meth:`Method.load_checkpoint` in the
   evaluating process;
3. calls :meth:`Method.complete` once per test object and context size, always with the same
   context points for every method.

Module-level imports of torch are not allowed in the module that *registers* the method (it is
imported by ``shapebench --help``); import torch inside ``fit``/``complete`` or in a module that
only the class imports. Trainable methods use PyTorch Lightning under the ``pytorch_lightning``
namespace (``import pytorch_lightning as pl``), never the ``lightning.pytorch`` one: objects from
the two namespaces cannot be mixed in one program.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, ClassVar

from shapebench.api.options import NoOptions
from shapebench.api.types import Completion, Context, Supervision

if TYPE_CHECKING:
    from shapebench.api.dataset import Dataset


@dataclass(frozen=True)
class TrainerOptions:
    """Lightning Trainer settings passed through from the command line or the profile."""

    accelerator: str = "auto"
    devices: str | int = "auto"
    strategy: str = "auto"
    num_nodes: int = 1
    precision: str = "32-true"
    #: ``--max-epochs``: an epoch budget; it replaces a method's step budget (see ``max_steps``).
    max_epochs: int | None = None
    #: ``--max-steps``: an optimiser-step budget, the same cost at any training-set size.
    max_steps: int | None = None
    seed: int = 0
    #: Save ``last.ckpt`` every this many epochs (0: only at the time interval and the end) ...
    checkpoint_every_epochs: int = 1
    #: ... and at the end of the first epoch after this many minutes since the last save (0:
    #: never). Neither changes the trained weights: they are not part of the checkpoint key.
    checkpoint_minutes: float = 10.0


@dataclass(frozen=True)
class TrainingContext:
    """Everything :meth:`Method.fit` needs besides the method's own options.

    ``workdir`` is private to this (method config, dataset, seed) training: save checkpoints there
    (and resume from the last one found there). ``tracking_uri``/``run_id`` name the MLflow run
    that training curves go to; log from rank 0 only.
    """

    dataset: Dataset
    trainer: TrainerOptions
    workdir: Path
    tracking_uri: str
    run_id: str | None = None
    quiet: bool = False


class Method(ABC):
    """A shape-completion method.

    Class attributes
    ----------------
    name:
        The public name used on the command line (set by the registration, repeated here for
        messages).
    display_name:
        How leaderboards print the method (the paper's row names: "Gauss densification", "IGR"...).
    description:
        One line for ``shapebench methods``.
    supervision:
        What the method needs from the training split (:class:`~shapebench.api.types.Supervision`).
        Methods that do not train need only the context, which always has points and normals.
    trains:
        Whether :meth:`fit` must run before :meth:`complete`.
    fit_ignores_trainer:
        Whether :meth:`fit` computes its checkpoint from the training data and the method's
        options alone: no trainer setting (seed, epoch or step budget, precision, devices)
        changes it. Such a "training" is a computation on the data (an index, a lookup table),
        not an optimisation: its checkpoint key and leaderboard row leave the trainer out, so
        one fit serves every seed; it is built by the first run that needs it, with no shipped
        reference expected. A method that draws random numbers in ``fit`` seeds them from the
        data, never from ``ctx.trainer.seed``.
    Options:
        A frozen dataclass of options with defaults (see :mod:`shapebench.api.options`).
    """

    name: ClassVar[str] = ""
    display_name: ClassVar[str] = ""
    description: ClassVar[str] = ""
    supervision: ClassVar[frozenset[Supervision]] = frozenset()
    trains: ClassVar[bool] = False
    fit_ignores_trainer: ClassVar[bool] = False
    Options: ClassVar[type] = NoOptions
    #: Methods with the same family share checkpoints (``msc`` and ``msc-noopt`` differ only at
    #: completion time). Options marked ``metadata={"completion_only": True}`` do not change the
    #: checkpoint either.
    checkpoint_family: ClassVar[str] = ""
    #: Option overrides that make the method tiny for ``shapebench check`` and
    #: :mod:`shapebench.conformance.testing` (a small network, one epoch): checks train and
    #: complete for real, in seconds.
    check_options: ClassVar[dict[str, Any]] = {}
    #: Non-empty for a method that cannot complete anything from the kit's tiny dataset alone
    #: because it reads a user's own input (the ``files`` method: a folder of completions). The
    #: text says what it needs; ``shapebench check`` then checks its interface and options and
    #: skips training and completion with that reason, and the method's own tests cover them.
    check_needs: ClassVar[str] = ""
    #: Modules besides the class's own package whose source changes results (shared training
    #: code the method imports); their code is hashed into cell and checkpoint keys together with
    #: the packages of the class and its bases (see :mod:`shapebench.registry.code_digest`).
    code_modules: ClassVar[tuple[str, ...]] = ()
    #: Modules that shape the completions but not the training (mesh extraction, surface
    #: sampling): hashed into cell keys only, so an edit there computes the cells again and
    #: keeps every checkpoint (:func:`shapebench.registry.code_digest.completion_digest`).
    completion_modules: ClassVar[tuple[str, ...]] = ()

    def __init__(self, options: Any | None = None) -> None:
        self.options = options if options is not None else self.Options()

    def fit(self, ctx: TrainingContext) -> Path:
        """Train on ``ctx.dataset``'s ``train`` split and return the checkpoint path.

        Called in a fresh process per training so that multi-GPU (DDP) strategies work. A fit
        that does not log its own cost (one that is not a Lightning training) may leave a
        ``summary.json`` in ``ctx.workdir`` (``wall_seconds``, ``device_hours``,
        ``training_shapes``, ``device``): the training run records it, and the leaderboard's
        cost columns show it.
        """
        raise NotImplementedError(f"method {self.name!r} declares trains=True but has no fit()")

    def load_checkpoint(self, path: Path) -> None:
        """Restore the state :meth:`fit` saved to ``path``."""
        raise NotImplementedError(f"method {self.name!r} cannot load checkpoints")

    #: How many contexts :meth:`complete_batch` receives at once (latent optimisation batches).
    batch_size: ClassVar[int] = 1

    def complete_batch(
        self, contexts: list[Context], n_points: int
    ) -> list[Completion | Exception]:
        """Complete several contexts of the same size at once.

        Override it to batch work over objects (latent optimisation on a GPU); return one
        Completion, or the Exception that made that object fail, per context, in order. The
        default calls :meth:`complete` for each.
        """
        out: list[Completion | Exception] = []
        for ctx in contexts:
            try:
                out.append(self.complete(ctx, n_points))
            except Exception as exc:  # recorded as that object's failure
                out.append(exc)
        return out

    @abstractmethod
    def complete(self, context: Context, n_points: int) -> Completion:
        """Complete one context into a shape.

        ``n_points`` is the size of the ground truth the metrics compare against (30k by
        default): return about that many points unless the method has a fixed output size (PCN's
        16384); Chamfer averages per set, so sizes may differ. Return NaNs or no points and the
        object is recorded as failed; raising an exception does the same, with its message.
        """
