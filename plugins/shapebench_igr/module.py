"""IGR's LightningModule: the auto-decoder and its losses."""

from __future__ import annotations

from collections.abc import Callable

import pytorch_lightning as pl
import torch
from torch import nn

from shapebench.implicit.losses import eikonal, gradient, normal_term, offsurface_samples
from shapebench.implicit.networks import IGRDecoder
from shapebench.lightning_fit import adam_halving


def surface_losses(
    decoder: nn.Module,
    z: torch.Tensor,
    points: torch.Tensor,
    normals: torch.Tensor | None,
    offsurface: str,
) -> dict[str, torch.Tensor]:
    """IGR's loss terms per object (B,): manifold |f|, Eikonal, and the normal term."""
    off = offsurface_samples(points, offsurface)
    x = torch.cat([points, off], dim=1).detach().requires_grad_(True)
    with torch.enable_grad():
        f = decoder(z, x)
        g = gradient(f, x)
    n = points.shape[1]
    terms = {"manifold": f[:, :n].abs().mean(dim=1), "eikonal": eikonal(g[:, n:])}
    if normals is not None:
        terms["normals"] = normal_term(g[:, :n], normals)
    return terms


class IGRModule(pl.LightningModule):
    def __init__(self, n_shapes: int, latent_dim: int, width: int, depth: int, lr: float,
                 lr_halve_every: int, eikonal_weight: float, normal_weight: float,
                 latent_reg: float, offsurface: str) -> None:  # fmt: skip
        super().__init__()
        self.save_hyperparameters()
        self.decoder = IGRDecoder(latent_dim, width, depth)
        self.latents = nn.Parameter(torch.zeros(n_shapes, latent_dim))  # IGR starts codes at 0

    def training_step(self, batch: dict[str, torch.Tensor], batch_idx: int) -> torch.Tensor:
        h = self.hparams
        z = self.latents[batch["index"]]
        t = surface_losses(self.decoder, z, batch["points"], batch["normals"], h.offsurface)
        latent = z.norm(dim=-1).mean()
        loss = (t["manifold"].mean() + h.eikonal_weight * t["eikonal"].mean()
                + h.normal_weight * t["normals"].mean() + h.latent_reg * latent)  # fmt: skip
        self.log_dict({"train/loss": loss, "train/manifold": t["manifold"].mean(),
                       "train/eikonal": t["eikonal"].mean(), "train/normals": t["normals"].mean()},
                      on_step=False, on_epoch=True, batch_size=len(z), sync_dist=True)  # fmt: skip
        return loss

    def configure_optimizers(self):
        return adam_halving(self.parameters(), self.hparams.lr, self.hparams.lr_halve_every)

    def completion_loss(
        self, points: torch.Tensor, normals: torch.Tensor | None
    ) -> Callable[[torch.Tensor], torch.Tensor]:
        """The per-object loss a latent code is optimised with at completion time."""
        h = self.hparams

        def loss(z: torch.Tensor) -> torch.Tensor:
            t = surface_losses(self.decoder, z, points, normals, h.offsurface)
            total = t["manifold"] + h.eikonal_weight * t["eikonal"] + h.latent_reg * z.abs().mean(1)
            if normals is not None:
                total = total + h.normal_weight * t["normals"]
            return total

        return loss
