"""IGR: an auto-decoder trained with the Implicit Geometric Regularization losses.

Training (official ``shapespace/train.py``; App. A.1 of the paper): one latent code per training
object, initialised at zero; loss = mean |f| on surface points + lambda * Eikonal on off-surface
samples + tau * ||grad f - n|| on surface points + 1e-3 * mean ||z||. Completion: a code drawn
from N(0, 0.01^2) is optimised on the context points alone (|f| on them, the Eikonal term around
them, 1e-3 * mean |z|), as the paper's protocol allows no normals or off-surface SDF at test time
(``test_normals=true`` adds the normal term), then meshed with marching cubes.

Paper vs official code (``recipe``): the paper trains with lr 1e-4, lambda = 1.0 and Eikonal
samples drawn from 5k surface points with variance 0.04; the official code uses lr 5e-3,
lambda = 0.1, per-point N(0, 0.01^2) plus uniform samples. The test-time optimiser and the
largest-component filter are shared with DeepSDF and MSC (``shapebench.implicit.recipes``):
"lr x error_0" with lr 1e-4 (paper) or Adam 5e-3 (official), 800 steps. Paper-scale network:
8 x 512 with a 256-d code; the ``quick`` profile shrinks it for CPUs.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from shapebench.implicit.method_base import ImplicitMethod
from shapebench.implicit.recipes import apply_recipe, with_shared
from shapebench.types import Context, Supervision
from shapebench_igr.options import (
    DecoderOptions,
    _c,
    opt_recipe_option,
    opt_scale_option,
    opt_steps_option,
)

#: IGR's training recipes (the decoder MSC shares); the test-time optimiser and meshing come from
#: the shared tables.
TRAINING_RECIPES = {
    "paper": {"lr": 1e-4, "eikonal_weight": 1.0, "offsurface": "paper"},
    "official": {"lr": 5e-3, "eikonal_weight": 0.1, "offsurface": "official"},
}
RECIPES = with_shared(TRAINING_RECIPES, decoder="igr")


@dataclass(frozen=True)
class IGROptions(DecoderOptions):
    latent_reg: float = field(default=1e-3, metadata={"help": "latent regularisation weight"})
    # The test-time optimiser, shared with DeepSDF and MSC (shapebench.implicit.recipes).
    opt_recipe: str | None = opt_recipe_option()
    opt_steps: int | None = opt_steps_option()
    opt_scale_by_error: bool | None = opt_scale_option()
    opt_lr: float | None = _c(
        None, "latent optimisation step [paper 1e-4 x error_0, official 5e-3]"
    )
    init_std: float = _c(0.01, "std of the initial latent code (paper: 0.01)")
    test_normals: bool = _c(False, "use context normals at completion (the paper does not)")


class IGR(ImplicitMethod):
    display_name = "IGR"
    description = "auto-decoder with Eikonal and normal regularisation; latent optimisation"
    supervision = frozenset({Supervision.SURFACE_POINTS})
    Options = IGROptions

    def __init__(self, options=None) -> None:
        super().__init__(options)
        self.options = apply_recipe(self.options, RECIPES, "igr")

    @property
    def Module(self):  # imported lazily: torch stays out of registration
        from shapebench_igr.module import IGRModule

        return IGRModule

    def build_module(self, n_shapes: int):
        o = self.options
        return self.Module(n_shapes=n_shapes, latent_dim=o.latent_dim, width=o.width,
                           depth=o.depth, lr=o.lr, lr_halve_every=o.lr_halve_every,
                           eikonal_weight=o.eikonal_weight, normal_weight=o.normal_weight,
                           latent_reg=o.latent_reg, offsurface=o.offsurface)  # fmt: skip

    def infer_latents(self, contexts: list[Context]):
        from shapebench.implicit.completion import (
            initial_latents,
            optimise_latents,
            require_normals,
            stack_contexts,  # fmt: skip
        )

        o = self.options
        pts, nrm = stack_contexts(contexts, self.device)
        # Context normals are read only when this option asks for them.
        if o.test_normals:
            nrm = require_normals(nrm, "test_normals=true", self.name or "igr")
        else:
            nrm = None
        z0 = initial_latents(contexts, o.latent_dim, o.init_std, self.device)
        loss = self.module.completion_loss(pts, nrm)
        z, _ = optimise_latents(loss, z0, o.opt_steps, o.opt_lr, o.opt_scale_by_error)
        return z
