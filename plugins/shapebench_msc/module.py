"""MSC's LightningModule: encoder, IGR decoder, ELBO + Eikonal (+ normals)."""

from __future__ import annotations

import math
from collections.abc import Callable

import torch
from torch import nn

from shapebench.implicit.losses import (
    eikonal,
    gaussian_kl,
    gradient,
    normal_term,
    offsurface_samples,
)
from shapebench.implicit.networks import IGRDecoder, MSCEncoder
from shapebench.train.lightning_fit import adam_halving, step_generator
from shapebench.train.lightning_module import OptionsModule
from shapebench_msc.method import MSCOptions


class MSCModule(OptionsModule):
    Options = MSCOptions
    options: MSCOptions

    def __init__(self, options: MSCOptions | None = None, n_shapes: int = 0, **saved) -> None:
        super().__init__(options, n_shapes, **saved)
        o = self.options
        self.encoder = MSCEncoder(
            o.latent_dim, o.encoder_width, o.encoder_layers, o.mean_weights, inputs=o.encoder_input
        )
        self.decoder = IGRDecoder(o.latent_dim, o.width, o.depth)
        # The decoder's noise sigma_theta is learned, from sigma_init down to at most sigma_min: a
        # sigma far below the fit's residuals makes the likelihood outweigh the Eikonal term by
        # orders of magnitude, and the decoder then collapses to a flat function.
        self.log_sigma = nn.Parameter(torch.tensor(math.log(o.sigma_init)))

    def _log_sigma(self) -> torch.Tensor:
        return self.log_sigma.clamp(min=math.log(self.options.sigma_min))

    def sigma(self) -> torch.Tensor:
        return self._log_sigma().exp()

    def nll(self, f: torch.Tensor) -> torch.Tensor:
        """-log N(0 | f, sigma^2) per point (every observed point lies on the surface, s = 0)."""
        log_sigma = self._log_sigma()
        return 0.5 * (f / log_sigma.exp()) ** 2 + log_sigma + 0.5 * math.log(2 * math.pi)

    def training_step(self, batch: dict[str, torch.Tensor], batch_idx: int) -> torch.Tensor:
        o = self.options
        pts, nrm = batch["points"], batch["normals"]  # normals: the training-only normal term
        b, n, _ = pts.shape
        y = nrm if o.encoder_input == "normals" else None  # default: (x_n, s_n = 0), no normals
        mq, vq = self.encoder(pts, y)  # q = p(h | D_k)
        ctx, target = self.draw_subsets(n)
        # The "prior" of equation 3, from D_k^ctxt.
        mp, vp = self.encoder(pts[:, ctx], None if y is None else y[:, ctx])
        latent = mq + vq.sqrt() * torch.randn_like(mq)
        t = len(target)
        tp, tn = pts[:, target], nrm[:, target]
        off = offsurface_samples(pts, o.offsurface)
        x = torch.cat([tp, off], dim=1).detach().requires_grad_(True)
        f = self.decoder(latent, x)
        g = gradient(f, x)
        nll = self.nll(f[:, :t]).mean(dim=1) * n  # the sum over D_k, estimated from t points
        kl = gaussian_kl(mq, vq, mp, vp)
        elbo = ((nll + kl) / n).mean()
        eik = eikonal(g[:, t:]).mean()
        normals = normal_term(g[:, :t], tn).mean()
        loss = elbo + o.eikonal_weight * eik + o.normal_weight * normals
        self.log_dict(
            {
                "train/loss": loss,
                "train/elbo": elbo,
                "train/kl": kl.mean(),
                "train/eikonal": eik,
                "train/normals": normals,
                "train/sigma": self.sigma(),
            },
            on_step=False,
            on_epoch=True,
            batch_size=b,
            sync_dist=True,
        )
        return loss

    def draw_subsets(self, n: int) -> tuple[torch.Tensor, torch.Tensor]:
        """Indices of the context subset D_k^ctxt (size log-uniform in [1, n]) and of the target
        subset (size uniform in [1, max_target]), drawn from the training's seeded generator."""
        gen = step_generator(self)
        m = int(math.exp(torch.empty(1).uniform_(0.0, math.log(n), generator=gen).item()))
        perm = torch.randperm(n, generator=gen)
        t = int(torch.randint(1, min(self.options.max_target, n) + 1, (1,), generator=gen).item())
        target = perm[torch.randperm(n, generator=gen)[:t]]
        device = self.log_sigma.device
        return perm[:m].to(device), target.to(device)

    def configure_optimizers(self):
        o = self.options
        return adam_halving(self.parameters(), o.lr, o.lr_halve_every, o.lr_halve_steps)

    def context_nll(
        self, points: torch.Tensor, eikonal_weight: float = 0.0
    ) -> Callable[[torch.Tensor], torch.Tensor]:
        """Equation 6's objective per object: the negative log-likelihood of the context points,
        as the mean over points of 0.5 (f / sigma)^2.

        Equation 6 ascends the summed log-likelihood; the mean and the dropped constant
        (log sigma + log(2 pi) / 2 per point) leave the direction unchanged, and Adam is invariant
        to the loss scale. What they change is the value: a non-negative error per point, so that
        "lr x error_0" means the same for every context size (with the constant, the sum is
        negative once the residuals are below sigma, and so would be the step).
        ``eikonal_weight`` > 0 adds lambda * Eikonal around the context points (an optional
        regulariser that the paper does not use; off by default).
        """
        o = self.options
        # One code per object: the decoder's forward_shared (training keeps its forward).
        decoder = self.decoder.forward_shared

        def loss(z: torch.Tensor) -> torch.Tensor:
            if eikonal_weight <= 0:
                f = decoder(z, points)
                return 0.5 * (f / self.sigma()).pow(2).mean(dim=1)
            off = offsurface_samples(points, o.offsurface)
            x = torch.cat([points, off], dim=1).detach().requires_grad_(True)
            with torch.enable_grad():
                f = decoder(z, x)
                g = gradient(f, x)
            n = points.shape[1]
            data = 0.5 * (f[:, :n] / self.sigma()).pow(2).mean(dim=1)
            return data + eikonal_weight * eikonal(g[:, n:])

        return loss
