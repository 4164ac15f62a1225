"""PoinTr: a transformer point-completion method (Yu et al., "PoinTr: Diverse Point Cloud
Completion with Geometry-Aware Transformers", ICCV 2021; official code yuxumin/PoinTr, the
PCN configuration ``cfgs/PCN_models/PoinTr.yaml``), the family (AdaPoinTr, ...) that leads the
completion tables since 2021.

Network in :mod:`shapebench_pointr.network`: point proxies from a DGCNN grouper, a
geometry-aware transformer encoder-decoder that predicts the missing proxies' centres and
features, and a FoldingNet head folding 64 points around each; the input is appended to the
output. Loss: the halved Chamfer-L1 (PoinTr's ``ChamferDistanceL1``) of the coarse cloud plus that
of the dense one, 1:1 (``fine_loss=folded``, an ablation: the dense one of the folded points
alone, without the input's copy). Optimiser: AdamW, lr 5e-4, weight decay 5e-4 except on biases
and norm weights, the lr multiplied by 0.9 every ``lr_decay_steps`` (official: every 21 epochs)
down to 0.02 of it, gradient norm clipped at 10.

As PCN here, it is trained with the benchmark's context sizes as inputs (each batch draws one):
the field trains and tests on 2,048 input points; a 50-point context then gives 50 proxies
instead of 128 (the grouper samples at most as many centres as there are points). The output
has ``num_query x fold_step^2`` folded points plus the context (official PCN: 224 x 64 + 2,048 =
16,384); its size is the method's, whatever the ground truth's.
"""

from __future__ import annotations

from dataclasses import dataclass

from shapebench.api.errors import ConfigError
from shapebench.api.options import option, steps_option
from shapebench.train.point_cloud_method import PointCloudMethod

#: Initialisations of the network: the official one (``network.official_init``), or PyTorch's
#: defaults everywhere (as the network here before 2026-11-28; for the ablation).
INITS = ("official", "torch")

#: What the dense loss scores: the whole output, folded points and input (official), or the
#: folded points alone (an ablation: the input no longer covers the ground truth for them).
FINE_LOSSES = ("output", "folded")


@dataclass(frozen=True)
class PoinTrOptions:
    dim: int = option(384, "transformer width (384)")
    heads: int = option(6, "attention heads (6)")
    encoder_depth: int = option(6, "encoder blocks (6)")
    decoder_depth: int = option(8, "decoder blocks (8)")
    num_query: int = option(224, "predicted proxies (PCN: 224; ShapeNet-55: 96)")
    fold_step: int = option(8, "folding grid per axis: fold_step^2 points per proxy (8)")
    global_dim: int = option(1024, "global feature size (1024)")
    proxies: int = option(128, "point proxies from the input, at most (128)")
    target_points: int = option(16384, "target points per object (PCN: 16384)")
    surface_points: int = option(1000, "largest context size drawn")
    context_sizes: tuple[int, ...] = option(
        (50, 100, 300, 1000), "context sizes the batches draw from"
    )
    epochs: int = option(300, "training epochs (PCN: 300)")
    steps: int = steps_option()
    batch_shapes: int = option(48, "objects per batch (PCN: 48)")
    lr: float = option(5e-4, "AdamW learning rate (5e-4)")
    weight_decay: float = option(5e-4, "AdamW weight decay, not on biases and norms (5e-4)")
    lr_decay: float = option(0.9, "lr factor every lr_decay_steps (0.9)")
    lr_decay_steps: int = option(
        12_700, "steps between lr decays (official: 21 epochs of PCN, 604 steps each)"
    )
    lr_floor: float = option(0.02, "lowest lr factor (0.02)")
    grad_clip: float = option(10.0, "gradient norm clip (10)")
    init: str = option(
        "official",
        "weight initialisation: 'official' (truncated normal 0.02, Xavier for the 1x1 "
        "convolutions, as PCTransformer._init_weights) or 'torch' (PyTorch's defaults)",
    )
    fine_loss: str = option(
        "output",
        "what the dense CD scores: 'output' (the folded points and the input, official) or "
        "'folded' (the folded points alone; ablation)",
    )
    precise_bn_batches: int = option(
        0,
        "training batches the BatchNorm statistics are recomputed over once training ends "
        "(0: the running averages as trained, official)",
    )


class PoinTr(PointCloudMethod):
    display_name = "PoinTr"
    description = "point proxies + geometry-aware transformer + folding head (ICCV 2021)"
    Options = PoinTrOptions
    module_path = "shapebench_pointr.module:PoinTrModule"
    #: The halved Chamfer (its loss) with the nearest-neighbour search it runs on, and the
    #: recomputation of its BatchNorm statistics, shape its results: they are part of its keys.
    code_modules = (
        *PointCloudMethod.code_modules,
        "shapebench.train.batchnorm",
        "shapebench.train.losses",
        "shapebench.geometry.nearest",
    )
    #: Tiny options for ``shapebench check``: a small network, one epoch.
    check_options = {
        "dim": 16,
        "heads": 2,
        "encoder_depth": 1,
        "decoder_depth": 1,
        "num_query": 8,
        "fold_step": 2,
        "global_dim": 32,
        "proxies": 16,
        "target_points": 256,
        "epochs": 1,
        "batch_shapes": 4,
    }

    def __init__(self, options=None) -> None:
        super().__init__(options)
        if self.options.init not in INITS:
            raise ConfigError(
                f"pointr: init must be one of {list(INITS)}, got {self.options.init!r}"
            )
        if self.options.fine_loss not in FINE_LOSSES:
            raise ConfigError(
                f"pointr: fine_loss must be one of {list(FINE_LOSSES)}, "
                f"got {self.options.fine_loss!r}"
            )
