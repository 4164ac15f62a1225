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

from dataclasses import dataclass

from shapebench.api.options import completion_option, option
from shapebench.api.types import Context, Supervision
from shapebench.implicit.method_base import ImplicitMethod
from shapebench.implicit.options import AutoDecoderOptions, auto_decoder_check_options
from shapebench.implicit.recipes import with_shared


@dataclass(frozen=True)
class DeepSDFOptions(AutoDecoderOptions):
    dropout: float = option(0.2, "dropout after each hidden layer")
    sdf_points: int = option(16384, "SDF samples per object and step")
    lr: float | None = option(None, "decoder learning rate [paper 1e-3, official 5e-4]")
    latent_lr: float = option(1e-3, "code learning rate")
    clamp: float = option(0.1, "SDF clamping distance delta")
    code_reg: float = option(1e-4, "code regularisation weight")
    # The test-time optimiser is shared with IGR and MSC (shapebench.implicit.recipes).
    opt_lr: float | None = completion_option(
        None, "latent optimisation step [paper 1e-3 x error_0, official 5e-3]"
    )
    init_std: float = completion_option(0.01, "std of the initial latent code (0.01)")


class DeepSDF(ImplicitMethod):
    display_name = "DeepSDF"
    description = "auto-decoder trained on SDF samples; latent optimisation on the context"
    supervision = frozenset({Supervision.SDF_SAMPLES})
    Options = DeepSDFOptions
    module_path = "shapebench_deepsdf.module:DeepSDFModule"
    #: Tiny options for ``shapebench check``. Five epochs, not one: after fewer steps the tiny
    #: network has no surface to mesh.
    check_options = auto_decoder_check_options(epochs=5, sdf_points=256)
    recipes = with_shared({"paper": {"lr": 1e-3}, "official": {"lr": 5e-4}}, decoder="deepsdf")

    def sample_sizes(self) -> dict[Supervision, int]:
        return {Supervision.SDF_SAMPLES: self.options.sdf_points}

    def encode(self, contexts: list[Context]):
        from shapebench.implicit.completion import initial_latents, stack_contexts

        o = self.options
        pts, _ = stack_contexts(contexts, self.device)
        z0 = initial_latents(contexts, o.latent_dim, o.init_std, self.device)
        return self.optimise_codes(self.module.completion_loss(pts), z0)
