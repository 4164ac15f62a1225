"""PCN: encodes the k context points and decodes a complete cloud directly (no mesh).

Faithful to the official TensorFlow code (``models/pcn_emd.py``, ``train.py``): network in
:mod:`shapebench_pcn.network`; loss = approximate EMD on the 1024-point coarse cloud (against the
first 1024 points of the shuffled target; see :mod:`shapebench_pcn.losses` for the Sinkhorn
approximation) + alpha * halved Chamfer on the 16384-point fine cloud, alpha = 0.01, 0.1, 0.5, 1
at 10k, 20k, 50k steps; Adam lr 1e-4 x 0.7 every 50k steps (floor 1e-6), batch 32. As the paper
says, PCN is trained with k context points as input: each batch draws k from the benchmark's
context sizes. The target is the complete cloud (16384 points) sampled over the whole mesh.
Completion returns the fine cloud as it is; Chamfer averages per set, so its size (16384) may
differ from the ground truth's (30k).
"""

from __future__ import annotations

from dataclasses import dataclass

from shapebench.api.options import option, steps_option
from shapebench.train.point_cloud_method import PointCloudMethod


@dataclass(frozen=True)
class PCNOptions:
    feature: int = option(1024, "global feature size (1024)")
    decoder_width: int = option(1024, "width of the coarse decoder's two hidden layers (1024)")
    num_coarse: int = option(1024, "coarse output points (1024)")
    grid_size: int = option(4, "folding grid per axis (4: 16 points)")
    grid_scale: float = option(0.05, "folding grid half-width")
    target_points: int = option(16384, "target points per object")
    surface_points: int = option(1000, "largest context size drawn")
    context_sizes: tuple[int, ...] = option(
        (50, 100, 300, 1000), "context sizes the batches draw from"
    )
    epochs: int = option(5000, "training epochs (paper: 5000)")
    steps: int = steps_option()
    batch_shapes: int = option(32, "objects per batch (32)")
    lr: float = option(1e-4, "learning rate (1e-4)")
    lr_decay: float = option(0.7, "lr factor every lr_decay_steps")
    lr_decay_steps: int = option(50_000, "steps between lr decays")
    alpha_steps: tuple[int, ...] = option(
        (10_000, 20_000, 50_000), "steps where the fine-loss weight becomes 0.1, 0.5 and 1.0"
    )


class PCN(PointCloudMethod):
    display_name = "PCN"
    description = "point completion network: encoder, coarse points, folding to a dense cloud"
    Options = PCNOptions
    module_path = "shapebench_pcn.module:PCNModule"
    #: The shared Chamfer loss with the nearest-neighbour search it runs on, and
    #: ``shapebench.implicit`` (the network's ``mlp``): they shape its results, so they are part
    #: of its keys.
    code_modules = (
        *PointCloudMethod.code_modules,
        "shapebench.train.losses",
        "shapebench.geometry.nearest",
        "shapebench.implicit.networks",
    )
    #: Tiny options for ``shapebench check``: a small network, one epoch.
    check_options = {
        "feature": 32,
        "num_coarse": 16,
        "grid_size": 2,
        "target_points": 256,
        "epochs": 1,
        "batch_shapes": 4,
    }
