"""The LightningModule base of the point-cloud methods
(:class:`~shapebench.train.point_cloud_method.PointCloudMethod`): :class:`PointCloudModule`.

Imports Lightning: only a method's ``module.py`` imports it, lazily.
"""

from __future__ import annotations

import torch

from shapebench.train.lightning_fit import step_generator
from shapebench.train.lightning_module import OptionsModule


class PointCloudModule(OptionsModule):
    """An :class:`~shapebench.train.lightning_module.OptionsModule` whose ``network`` maps
    (B, k, 3) context points to an output cloud (or to a tuple of clouds, the completion last).

    A subclass builds ``self.network`` from :attr:`options` and defines :meth:`losses`. Each
    training step feeds the network the batch's first k surface points, k drawn from the option
    ``context_sizes`` by :meth:`context_size`, and gives :meth:`losses` its output's inputs and
    the complete cloud; :meth:`combine` makes one loss of the terms (by default their sum, each
    logged as ``train/<name>``). The default optimiser is Adam at the option ``lr``, no schedule.
    """

    def context_size(self, generator: torch.Generator | None = None) -> int:
        """One batch's context size, drawn from ``context_sizes`` with ``generator`` (default:
        the training step's seeded :func:`~shapebench.train.lightning_fit.step_generator`)."""
        sizes = self.options.context_sizes
        gen = generator if generator is not None else step_generator(self)
        return sizes[int(torch.randint(len(sizes), (1,), generator=gen))]

    def losses(self, points: torch.Tensor, target: torch.Tensor) -> dict[str, torch.Tensor]:
        """The loss terms, by name, of the network on (B, k, 3) ``points`` against the (B, n, 3)
        complete clouds ``target``: each a scalar (the mean over the batch)."""
        raise NotImplementedError(f"{type(self).__name__} defines no losses()")

    def combine(
        self, terms: dict[str, torch.Tensor]
    ) -> tuple[torch.Tensor, dict[str, torch.Tensor | float]]:
        """The training loss from :meth:`losses`' terms, and what to log besides it (each value
        as ``train/<name>``): by default the sum of the terms, each logged by its name."""
        return sum(terms.values()), terms

    def training_step(self, batch: dict[str, torch.Tensor], batch_idx: int) -> torch.Tensor:
        k = self.context_size()
        loss, logged = self.combine(self.losses(batch["points"][:, :k], batch["complete"]))
        self.log_dict(
            {"train/loss": loss, **{f"train/{name}": v for name, v in logged.items()}},
            on_step=False,
            on_epoch=True,
            batch_size=len(batch["points"]),
            sync_dist=True,
        )
        return loss

    def configure_optimizers(self):
        return torch.optim.Adam(self.parameters(), lr=self.options.lr)
