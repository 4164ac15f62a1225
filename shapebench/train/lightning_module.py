"""The LightningModule base of the trained methods: built from the method's options dataclass.

Imports Lightning: only a method's ``module.py`` imports it, lazily (see
:class:`~shapebench.train.lightning_method.LightningMethod`).
"""

from __future__ import annotations

import dataclasses
from typing import Any, ClassVar

import pytorch_lightning as pl


class OptionsModule(pl.LightningModule):
    """A LightningModule configured by its method's resolved options (``Options``, a frozen
    dataclass) and the number of training objects.

    The hyper-parameters it saves are the options as a flat dict of plain values plus
    ``n_shapes``, so that a checkpoint loads with ``torch.load(weights_only=True)``
    (:func:`shapebench.train.checkpoints.load_module`) and Lightning's ``load_from_checkpoint``;
    both
    call ``Module(**hyper_parameters)``, from which the dataclass is rebuilt. Keys that are not
    options are ignored (a checkpoint written before a module took its options has hyper-
    parameters named as the options, and a few others).

    Subclasses set ``Options`` and build their networks from :attr:`options` after
    ``super().__init__``. Completion-only options (``metadata={"completion_only": True}``) are
    saved too but are the training's values: read those from the method's options instead.
    """

    Options: ClassVar[type]

    def __init__(self, options: Any = None, n_shapes: int = 0, **saved: Any) -> None:
        super().__init__()
        if options is None:  # rebuilt from saved hyper-parameters
            names = {f.name for f in dataclasses.fields(self.Options)}
            options = self.Options(**{k: v for k, v in saved.items() if k in names})
        elif saved:
            raise TypeError(f"{type(self).__name__}: pass options or saved values, not both")
        #: The options the module was built (or trained) with.
        self.options = options
        self.n_shapes = n_shapes
        self.save_hyperparameters({**dataclasses.asdict(options), "n_shapes": n_shapes})
