"""IGR's LightningModule: the auto-decoder and its losses."""

from __future__ import annotations

from collections.abc import Callable

import torch
from torch import nn

from shapebench.implicit.losses import eikonal, gradient, normal_term, offsurface_samples
from shapebench.implicit.networks import IGRDecoder
from shapebench.train.lightning_fit import adam_halving
from shapebench.train.lightning_module import OptionsModule
from shapebench_igr.method import IGROptions


def surface_losses(
    decoder: nn.Module,
    z: torch.Tensor,
    points: torch.Tensor,
    normals: torch.Tensor | None,
    offsurface: str,
    eikonal_samples: int = 0,
) -> dict[str, torch.Tensor]:
    """IGR's loss terms per object (B,): manifold |f|, Eikonal, and the normal term.

    The Eikonal samples are drawn around ``points`` by ``offsurface``'s rule, or, with
    ``eikonal_samples`` > 0, around that many points drawn from them with replacement: the same
    distribution, estimated with a sample count that does not shrink with the context.
    """
    off = offsurface_samples(points, offsurface, count=eikonal_samples)
    x = torch.cat([points, off], dim=1).detach().requires_grad_(True)
    with torch.enable_grad():
        f = decoder(z, x)
        g = gradient(f, x)
    n = points.shape[1]
    terms = {"manifold": f[:, :n].abs().mean(dim=1), "eikonal": eikonal(g[:, n:])}
    if normals is not None:
        terms["normals"] = normal_term(g[:, :n], normals)
    return terms


class IGRModule(OptionsModule):
    Options = IGROptions
    options: IGROptions

    def __init__(self, options: IGROptions | None = None, n_shapes: int = 0, **saved) -> None:
        super().__init__(options, n_shapes, **saved)
        o = self.options
        self.decoder = IGRDecoder(o.latent_dim, o.width, o.depth)
        self.latents = nn.Parameter(torch.zeros(n_shapes, o.latent_dim))  # IGR starts codes at 0

    def training_step(self, batch: dict[str, torch.Tensor], batch_idx: int) -> torch.Tensor:
        o = self.options
        z = self.latents[batch["index"]]
        t = surface_losses(self.decoder, z, batch["points"], batch["normals"], o.offsurface)
        latent = z.norm(dim=-1).mean()
        loss = (
            t["manifold"].mean()
            + o.eikonal_weight * t["eikonal"].mean()
            + o.normal_weight * t["normals"].mean()
            + o.latent_reg * latent
        )
        self.log_dict(
            {
                "train/loss": loss,
                "train/manifold": t["manifold"].mean(),
                "train/eikonal": t["eikonal"].mean(),
                "train/normals": t["normals"].mean(),
            },
            on_step=False,
            on_epoch=True,
            batch_size=len(z),
            sync_dist=True,
        )
        return loss

    def configure_optimizers(self):
        o = self.options
        return adam_halving(self.parameters(), o.lr, o.lr_halve_every, o.lr_halve_steps)

    def completion_loss(
        self, points: torch.Tensor, normals: torch.Tensor | None, eikonal_samples: int = 0
    ) -> Callable[[torch.Tensor], torch.Tensor]:
        """The per-object loss a latent code is optimised with at completion time
        (``eikonal_samples``: the method's ``opt_eikonal_samples``, see :func:`surface_losses`)."""
        o = self.options

        def loss(z: torch.Tensor) -> torch.Tensor:
            t = surface_losses(self.decoder, z, points, normals, o.offsurface, eikonal_samples)
            total = t["manifold"] + o.eikonal_weight * t["eikonal"] + o.latent_reg * z.abs().mean(1)
            if normals is not None:
                total = total + o.normal_weight * t["normals"]
            return total

        return loss
