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
from that mean, nothing else unless ``opt_eikonal`` > 0) with the test-time optimiser IGR and
DeepSDF use in the same recipe (``shapebench.implicit.recipes``; the paper gives no step size or
count for MSC, and says the optimised variant "becomes a version of IGR", so the paper recipe
uses IGR's "1e-4 x error_0"). With ``posterior_samples = K`` the completion also carries K shapes
decoded from codes drawn from the posterior; the objects the report pictures get
``pictured_samples`` (4) such shapes by default.

Encoder inputs are the context points and their observed signed distance, 0 on the surface (the
(x_n, y_n) of equation 2 with y_n = s_n): no normals, which the protocol does not give at test
time. The precision is kept non-negative per point (see
``shapebench.implicit.networks.MSCEncoder``).
"""

from __future__ import annotations

from dataclasses import dataclass

from shapebench.api.options import completion_option, option
from shapebench.api.types import Completion, Context, Supervision
from shapebench.implicit.method_base import ImplicitMethod
from shapebench.implicit.options import IGRDecoderOptions, auto_decoder_check_options
from shapebench.implicit.recipes import IGR_TRAINING, with_shared


@dataclass(frozen=True)
class MSCOptions(IGRDecoderOptions):
    latent_dim: int = option(1024, "latent size (paper: 1024 ShapeNet)")
    encoder_width: int = option(512, "width of the f and g MLPs")
    encoder_layers: int = option(3, "hidden layers of f and g")
    encoder_input: str = option(
        "sdf",
        "y_n of equation 2: 'sdf' (the observed signed distance, 0 on the surface; no normals) "
        "or 'normals' (needs context normals at test time)",
    )
    mean_weights: str = option(
        "printed", "posterior mean weights: 'printed' (eq. 2, 1/g_n^2) or 'increment'"
    )
    max_target: int = option(5000, "largest target subset (paper: 5000)")
    sigma_init: float = option(0.1, "initial decoder noise sigma")
    sigma_min: float = option(0.01, "lower bound of the learned sigma")
    # The post-encoder optimiser (msc only) is IGR's and DeepSDF's (shapebench.implicit.recipes).
    opt_lr: float | None = completion_option(
        None, "post-encoder optimisation step (msc only) [paper 1e-4 x error_0, official 5e-3]"
    )
    opt_eikonal: float = completion_option(
        0.0,
        "Eikonal weight around the context in the post-encoder optimisation (msc only; "
        "0: equation 6 as written)",
    )
    posterior_samples: int = completion_option(
        0, "also decode this many posterior samples per object"
    )
    pictured_samples: int = completion_option(
        4,
        "posterior samples decoded for the pictured objects only (3 per cell), for the "
        "report's 'Posterior uncertainty' section; posterior_samples, when set, wins",
    )


class MSCNoOpt(ImplicitMethod):
    display_name = "MSC (w/o opt)"
    description = "Bayesian meta-learning encoder + IGR decoder, posterior mean (no optimisation)"
    supervision = frozenset({Supervision.SURFACE_POINTS})
    Options = MSCOptions
    checkpoint_family = "msc"
    module_path = "shapebench_msc.module:MSCModule"
    #: Tiny options for ``shapebench check`` (MSC inherits them): small networks, one epoch.
    check_options = auto_decoder_check_options(
        surface_points=64, encoder_width=16, encoder_layers=1, max_target=64
    )
    #: IGR's training recipes (same decoder, same Eikonal term); IGR's test-time optimiser.
    recipes = with_shared(IGR_TRAINING, decoder="igr")
    optimise = False

    def sample_sizes(self) -> dict[Supervision, int]:
        return {Supervision.SURFACE_POINTS: self.options.surface_points}

    def posterior(self, contexts: list[Context]):
        """The context points and the posterior (mean, variance) of each context's code."""
        from shapebench.implicit.completion import require_normals, stack_contexts

        pts, nrm = stack_contexts(contexts, self.device)
        if self.options.encoder_input != "normals":  # the default reads no normals
            return pts, self.module.encoder(pts)
        nrm = require_normals(nrm, "encoder_input=normals", self.label)
        return pts, self.module.encoder(pts, nrm)

    def encode(self, contexts: list[Context]):
        """(code, posterior variance) per context: the posterior mean, optimised by ``msc``."""
        pts, (mean, var) = self.posterior(contexts)
        z = mean
        if self.optimise:
            z = self.optimise_codes(self.module.context_nll(pts, self.options.opt_eikonal), mean)
        return list(zip(z, var, strict=True))

    def decode(self, code, ctx: Context, n_points: int) -> Completion:
        z, var = code
        completion = self.mesh(z, ctx, n_points)
        # Samples never change the scored completion (their generator is the context's own),
        # so the pictured objects get a few by default: the report's uncertainty section then
        # exists without a run having to ask for it, at the cost of 3 objects per cell.
        k = self.options.posterior_samples or (self.options.pictured_samples if ctx.pictured else 0)
        if k:
            import torch

            std = var.sqrt()
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
