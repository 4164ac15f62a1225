"""MSC: a posterior encoder (equation 2) in front of IGR's decoder, trained with an ELBO.

Training, per object and step (equations 3 and 5, Appendix A.1): ``surface_points`` surface
points with normals form D_k; the posterior q = p(h | D_k) comes from all of them and the "prior"
p(h | D_k^ctxt) from a random context subset whose size is drawn log-uniformly between 1 and
|D_k| (so small contexts, as at test time, are seen often); h is drawn from q with the
reparameterisation trick; the likelihood N(0 | SDF(x; h), sigma^2) (sigma learned) is evaluated on
a random target subset of 1 to 5000 points (App. A.1) and scaled to the whole set; the loss is
-E_q[log-likelihood] + KL(q || prior), divided by |D_k| so that lambda * Eikonal (eq. 5) and the
normal term (§3.4) keep IGR's per-point scale.

Completion: ``msc-noopt`` decodes the posterior mean of the context; ``msc`` then runs the
post-encoder latent optimisation of equation 6 (gradient ascent of the context log-likelihood
from that mean; Adam, ``opt_steps`` steps of ``opt_lr``; the paper gives neither). With
``--samples``-style option ``posterior_samples = K`` the completion also carries K shapes decoded
from codes drawn from the posterior.

Encoder inputs are the context points and their normals (the y_n of equation 2); the precision is
kept non-negative per point (see ``shapebench.implicit.networks.MSCEncoder``).
"""

from __future__ import annotations

from dataclasses import dataclass, field

from shapebench_igr.method import RECIPES as IGR_RECIPES
from shapebench_igr.options import DecoderOptions, _c

from shapebench.implicit.method_base import ImplicitMethod
from shapebench.implicit.recipes import apply_recipe
from shapebench.types import Completion, Context, Supervision

RECIPES = {name: {k: v for k, v in values.items() if not k.startswith("opt_")}
           for name, values in IGR_RECIPES.items()}  # fmt: skip


@dataclass(frozen=True)
class MSCOptions(DecoderOptions):
    latent_dim: int = field(default=1024, metadata={"help": "latent size (paper: 1024 ShapeNet)"})
    encoder_width: int = field(default=512, metadata={"help": "width of the f and g MLPs"})
    encoder_layers: int = field(default=3, metadata={"help": "hidden layers of f and g"})
    mean_weights: str = field(
        default="printed",
        metadata={"help": "posterior mean weights: 'printed' (eq. 2, 1/g_n^2) or 'increment'"},
    )
    max_target: int = field(default=5000, metadata={"help": "largest target subset (paper: 5000)"})
    sigma_init: float = field(default=0.1, metadata={"help": "initial decoder noise sigma"})
    sigma_min: float = field(default=0.01, metadata={"help": "lower bound of the learned sigma"})
    opt_steps: int = _c(200, "post-encoder optimisation steps (msc only; not in the paper)")
    opt_lr: float = _c(5e-3, "post-encoder optimisation Adam step (msc only)")
    posterior_samples: int = _c(0, "also decode this many posterior samples per object")


class MSCNoOpt(ImplicitMethod):
    display_name = "MSC (w/o opt)"
    description = "Bayesian meta-learning encoder + IGR decoder, posterior mean (no optimisation)"
    supervision = frozenset({Supervision.SURFACE_POINTS})
    Options = MSCOptions
    checkpoint_family = "msc"
    optimise = False

    def __init__(self, options=None) -> None:
        super().__init__(options)
        self.options = apply_recipe(self.options, RECIPES, self.name or "msc")

    @property
    def Module(self):  # imported lazily: torch stays out of registration
        from shapebench_msc.module import MSCModule

        return MSCModule

    def build_module(self, n_shapes: int):
        o = self.options
        return self.Module(latent_dim=o.latent_dim, width=o.width, depth=o.depth,
                           encoder_width=o.encoder_width, encoder_layers=o.encoder_layers,
                           mean_weights=o.mean_weights, lr=o.lr, lr_halve_every=o.lr_halve_every,
                           eikonal_weight=o.eikonal_weight, normal_weight=o.normal_weight,
                           offsurface=o.offsurface, max_target=o.max_target,
                           sigma_init=o.sigma_init, sigma_min=o.sigma_min)  # fmt: skip

    def posterior(self, contexts: list[Context]):
        from shapebench.implicit.completion import stack_contexts

        pts, nrm = stack_contexts(contexts, self.device)
        return pts, self.module.encoder(pts, nrm)

    def infer_latents(self, contexts: list[Context]):
        pts, (mean, var) = self.posterior(contexts)
        self._variance = var
        if not self.optimise:
            return mean
        from shapebench.implicit.completion import optimise_latents

        loss = self.module.context_nll(pts)
        z, _ = optimise_latents(loss, mean, self.options.opt_steps, self.options.opt_lr)
        return z

    def decode(self, i: int, z, ctx: Context, n_points: int) -> Completion:
        completion = self.mesh(z, ctx, n_points)
        k = self.options.posterior_samples
        if k:
            import torch

            std = self._variance[i].sqrt()
            gen = torch.Generator().manual_seed(ctx.seed % (2**63))
            samples = []
            for _ in range(k):
                eps = torch.randn(std.shape, generator=gen).to(std.device)
                try:
                    samples.append(self.mesh(z + std * eps, ctx, n_points).points)
                except Exception:  # a sample without a surface is left out, not fatal
                    continue
            completion.samples = samples
            completion.info["posterior_samples"] = float(len(samples))
            completion.info["posterior_std"] = float(std.mean())
        return completion


class MSC(MSCNoOpt):
    display_name = "MSC (w/ opt)"
    description = "MSC with post-encoder latent optimisation (eq. 6)"
    optimise = True
