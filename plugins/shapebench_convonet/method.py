"""ConvONet: point features pooled into three feature planes, a U-Net, and an occupancy decoder
that reads the planes at each query (Peng et al., "Convolutional Occupancy Networks", ECCV 2020;
the official ``configs/pointcloud/shapenet_3plane.yaml``).

Where OccNet encodes a whole shape in one global code, ConvONet keeps features where the points
are: the network sees local structure, and a query's occupancy depends mostly on the features
around it. That is why it recovers detail OccNet loses, and why, like any local method, it can
only fill in what its planes' receptive field reaches from the context.

Training: ``input_points`` surface points with Gaussian noise of std 0.005 (official: 3,000 from
the dense point cloud), 2,048 occupancy queries uniform in the padded box, binary cross-entropy on
logits summed over the queries, averaged over objects; Adam lr 1e-4, batch 32.
Completion: the encoder on the context points, the coarse-to-fine marching cubes at the official
threshold 0.2 (logit log(0.2/0.8)), points sampled on the mesh.

Departures are options (docs/methods.md, ConvONet): ``input_points`` can be several sizes drawn
per batch (the ``quick`` profile draws the benchmark's 50 to 1000, as PCN's does here: a network
trained on 3,000 points only meets 50), and ``queries = near`` takes the queries from DeepSDF's
near-surface SDF samples (inside where sdf < 0) instead of the uniform box, as OccNet's paper
recipe does.
"""

from __future__ import annotations

from dataclasses import dataclass

from shapebench.api.errors import ConfigError
from shapebench.api.options import completion_option, option, steps_option
from shapebench.api.types import Context
from shapebench.implicit.occupancy import OccupancyMethod
from shapebench.implicit.options import largest_component_option


@dataclass(frozen=True)
class ConvONetOptions:
    c_dim: int = option(32, "feature channels of the planes (official: 32)")
    hidden: int = option(32, "encoder and decoder width (official: 32)")
    plane_resolution: int = option(64, "cells per side of each feature plane (official: 64)")
    unet_depth: int = option(4, "U-Net levels (official: 4)")
    unet_start: int = option(32, "U-Net channels of the first level (official: 32)")
    input_points: tuple[int, ...] = option(
        (3000,), "encoder points per training batch, one size drawn per batch (official: 3000)"
    )
    input_noise: float = option(0.005, "noise std on the encoder's training input (0.005)")
    queries: str = option(
        "uniform",
        "training queries: 'uniform' in the padded box (official) or 'near' (DeepSDF's SDF "
        "samples, inside where sdf < 0)",
    )
    query_points: int = option(2048, "occupancy queries per object and step (2048)")
    epochs: int = option(300, "training epochs")
    steps: int = steps_option()
    batch_shapes: int = option(32, "objects per batch (32)")
    lr: float = option(1e-4, "learning rate (1e-4)")
    threshold: float = completion_option(0.2, "occupancy probability of the surface (0.2)")
    mesh_resolution: int = completion_option(
        128, "marching-cubes cells per axis (official: 32 refined twice to 128)"
    )
    largest_component: bool | None = largest_component_option()


class ConvONet(OccupancyMethod):
    display_name = "ConvONet"
    description = "point features pooled into 3 planes + U-Net + local occupancy decoder"
    Options = ConvONetOptions
    module_path = "shapebench_convonet.module:ConvONetModule"
    #: OccNet's ResnetBlockFC (shared from shapebench.train.blocks) is part of the network.
    code_modules = (*OccupancyMethod.code_modules, "shapebench.train.blocks")
    #: Tiny options for ``shapebench check``: near-surface queries and a threshold of 0.3, so
    #: that a network trained 30 steps has a surface to mesh. Its planes start almost blind to
    #: the points (empty cells are 0, the U-Net's biases dominate), so the first steps only learn
    #: the share of inside queries: after 30 steps every logit was in [-1.3, -0.43], below the
    #: paper's 0.2 and 0.5 (measured); with uniform queries (a few % inside) lower still.
    check_options = {
        "queries": "near",
        "c_dim": 8,
        "hidden": 8,
        "plane_resolution": 16,
        "unet_depth": 2,
        "unet_start": 8,
        "input_points": (64,),
        "query_points": 256,
        "epochs": 10,
        "lr": 0.01,
        "threshold": 0.3,
        "batch_shapes": 4,
        "mesh_resolution": 32,
    }
    #: ``uniform``: the padded box (official); ``near``: DeepSDF's SDF samples, as OccNet's
    #: ``queries = paper``.
    query_sources = {"uniform": False, "near": True}

    def __init__(self, options=None) -> None:
        super().__init__(options)
        o = self.options
        if not o.input_points or min(o.input_points) < 1:
            raise ConfigError(f"convonet: input_points must be sizes >= 1, got {o.input_points}")
        if o.plane_resolution % 2 ** (o.unet_depth - 1):
            raise ConfigError(
                f"convonet: plane_resolution {o.plane_resolution} must be divisible by "
                f"2^(unet_depth - 1) = {2 ** (o.unet_depth - 1)} (the U-Net halves it per level)"
            )

    def encoder_points(self) -> int:
        return max(self.options.input_points)

    def encode(self, contexts: list[Context]):
        """The three planes of each context, one dict per object (a batch of one each)."""
        import torch

        from shapebench.implicit.completion import stack_contexts

        points, _ = stack_contexts(contexts, self.device)
        with torch.no_grad():
            planes = self.module.encoder(points)
        return [
            {key: plane[i : i + 1] for key, plane in planes.items()} for i in range(len(points))
        ]

    def decoder_code(self, code):
        return code  # already a batch of one
