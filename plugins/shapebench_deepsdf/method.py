"""DeepSDF: an auto-decoder trained on SDF samples.

Training (official ``train_deep_sdf.py`` and ``specs.json``): SDF samples near the surface
(DeepSDF's preprocessing, see ``shapebench.preprocess.samples``), half outside and half inside per
object and step; loss = L1 between prediction and target, both clamped to [-0.1, 0.1], plus
1e-4 * min(1, epoch/100) * mean ||z|| (codes in an embedding with max norm 1, initialised
N(0, 1/latent_dim)); Adam with the decoder and the codes in two groups, both halved every 500
epochs. Decoder: ReLU as the paper says, dropout 0.2, weight norm, final tanh.

Completion follows the paper's protocol, not ``reconstruct.py``: only the context points are
available, so the code (from N(0, 0.01^2)) is optimised to make the SDF zero on them, plus
1e-4 * mean(z^2); no off-surface SDF values and no normals.

Paper vs official (``recipe``): decoder lr 1e-3 (paper) or 5e-4 (official). The test-time
optimiser and the largest-component filter are shared with IGR and MSC
(``shapebench.implicit.recipes``): "lr x error_0" with lr 1e-3 (paper) or Adam 5e-3 (official),
800 steps.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from shapebench_igr.options import _c, opt_recipe_option, opt_scale_option, opt_steps_option

from shapebench.implicit.method_base import ImplicitMethod
from shapebench.implicit.recipes import apply_recipe, with_shared
from shapebench.types import Context, Supervision

RECIPES = with_shared({"paper": {"lr": 1e-3}, "official": {"lr": 5e-4}}, decoder="deepsdf")


@dataclass(frozen=True)
class DeepSDFOptions:
    recipe: str = field(
        default="paper",
        metadata={"help": "where paper and official code disagree: 'paper' or 'official' values"},
    )
    latent_dim: int = field(default=256, metadata={"help": "latent code size (official: 256)"})
    width: int = field(default=512, metadata={"help": "decoder layer width (512)"})
    depth: int = field(default=8, metadata={"help": "decoder hidden layers (8)"})
    dropout: float = field(default=0.2, metadata={"help": "dropout after each hidden layer"})
    epochs: int = field(default=5000, metadata={"help": "training epochs (paper: 5000)"})
    batch_shapes: int = field(default=32, metadata={"help": "objects per batch (paper: 32)"})
    sdf_points: int = field(default=16384, metadata={"help": "SDF samples per object and step"})
    lr: float | None = field(
        default=None, metadata={"help": "decoder learning rate [paper 1e-3, official 5e-4]"}
    )
    latent_lr: float = field(default=1e-3, metadata={"help": "code learning rate"})
    lr_halve_every: int = field(default=500, metadata={"help": "epochs between lr halvings"})
    clamp: float = field(default=0.1, metadata={"help": "SDF clamping distance delta"})
    code_reg: float = field(default=1e-4, metadata={"help": "code regularisation weight"})
    # The test-time optimiser, shared with IGR and MSC (shapebench.implicit.recipes).
    opt_recipe: str | None = opt_recipe_option()
    opt_steps: int | None = opt_steps_option()
    opt_scale_by_error: bool | None = opt_scale_option()
    opt_lr: float | None = _c(
        None, "latent optimisation step [paper 1e-3 x error_0, official 5e-3]"
    )
    init_std: float = _c(0.01, "std of the initial latent code (0.01)")
    mesh_resolution: int = _c(256, "marching-cubes grid points per axis (paper: 256)")
    mesh_bf16: bool = _c(False, "evaluate the decoder in bfloat16 while meshing")
    largest_component: bool | None = _c(
        None, "keep only the mesh's largest connected component, by area [paper: no, official: yes]"
    )


class DeepSDF(ImplicitMethod):
    display_name = "DeepSDF"
    description = "auto-decoder trained on SDF samples; latent optimisation on the context"
    supervision = frozenset({Supervision.SDF_SAMPLES})
    Options = DeepSDFOptions

    def __init__(self, options=None) -> None:
        super().__init__(options)
        self.options = apply_recipe(self.options, RECIPES, "deepsdf")

    @property
    def Module(self):  # imported lazily: torch stays out of registration
        from shapebench_deepsdf.module import DeepSDFModule

        return DeepSDFModule

    def build_module(self, n_shapes: int):
        o = self.options
        return self.Module(n_shapes=n_shapes, latent_dim=o.latent_dim, width=o.width,
                           depth=o.depth, dropout=o.dropout, lr=o.lr, latent_lr=o.latent_lr,
                           lr_halve_every=o.lr_halve_every, clamp=o.clamp,
                           code_reg=o.code_reg)  # fmt: skip

    def infer_latents(self, contexts: list[Context]):
        from shapebench.implicit.completion import (
            initial_latents,
            optimise_latents,
            stack_contexts,  # fmt: skip
        )

        o = self.options
        pts, _ = stack_contexts(contexts, self.device)
        z0 = initial_latents(contexts, o.latent_dim, o.init_std, self.device)
        loss = self.module.completion_loss(pts)
        z, _ = optimise_latents(loss, z0, o.opt_steps, o.opt_lr, o.opt_scale_by_error)
        return z
