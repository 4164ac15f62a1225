"""OccNet: a point-cloud encoder and an occupancy decoder, meshed at a probability threshold.

Training (official ``configs/pointcloud/onet.yaml``; the paper's Appendix A.1): 300 surface
points with Gaussian noise of std 0.005 to the ResnetPointnet encoder, 2048 labelled queries per
object, binary cross-entropy on logits summed over the queries; Adam lr 1e-4, batch 64.
Completion: the encoder on the context points, then the coarse-to-fine marching cubes at the
official threshold tau = 0.2 (a logit of log(0.2/0.8)), and points sampled on the mesh.

Paper vs official (``recipe``):

* decoder: the paper names ``DecoderBatchNorm``; the official point-cloud configuration uses
  ``DecoderCBatchNorm`` (``-O decoder=...``).
* queries (``-O queries=...``): the paper (§4.1) draws them from DeepSDF's SDF samples, mostly
  near the surface, labelled inside where sdf < 0 (``paper``); the official code samples
  uniformly in the padded box (``uniform``, labels from an inside test, see
  ``shapebench.preprocess.samples.occupancy_samples``). In the unit-sphere frame only about 2 %
  of uniform queries fall inside a thin object, and the trained logits then stay below
  logit(0.2) and whole objects fail to mesh.
* meshing: the largest-component filter is shared with the other implicit methods.
"""

from __future__ import annotations

from dataclasses import dataclass

from shapebench.api.errors import ConfigError
from shapebench.api.options import completion_option, option, steps_option
from shapebench.implicit.occupancy import OccupancyMethod
from shapebench.implicit.options import largest_component_option, recipe_option
from shapebench.implicit.recipes import with_shared


@dataclass(frozen=True)
class OccNetOptions:
    recipe: str = recipe_option(
        "'paper' (DecoderBatchNorm, SDF-sample queries) or 'official' (DecoderCBatchNorm, "
        "uniform queries)"
    )
    decoder: str | None = option(
        None, "batchnorm or cbatchnorm [paper: batchnorm, official: cbatchnorm]"
    )
    queries: str | None = option(
        None,
        "training queries: 'paper' (DeepSDF's SDF samples, inside where sdf < 0) or 'uniform' "
        "(the padded box) [paper: paper, official: uniform]",
    )
    c_dim: int = option(512, "code size (512)")
    hidden_dim: int = option(512, "encoder width (512)")
    decoder_hidden: int = option(256, "decoder width (256)")
    input_points: int = option(300, "encoder points in training (300)")
    context_sizes: tuple[int, ...] = option(
        (),
        "encoder point counts the training batches draw from, one per batch, instead of "
        "input_points (empty: input_points always, official); surface_points must cover the "
        "largest",
    )
    input_noise: float = option(0.005, "noise std on encoder input")
    query_points: int = option(2048, "occupancy queries per step")
    surface_points: int = option(300, "surface points loaded per step")
    epochs: int = option(5000, "training epochs (paper: 5000)")
    steps: int = steps_option()
    batch_shapes: int = option(64, "objects per batch (64)")
    lr: float = option(1e-4, "learning rate (1e-4)")
    precise_bn_batches: int = option(
        0,
        "training batches the BatchNorm statistics are recomputed over once training ends "
        "(0: the running averages as trained, official)",
    )
    threshold: float = completion_option(
        0.2, "occupancy probability of the surface (official: 0.2)"
    )
    mesh_resolution: int = completion_option(
        128, "marching-cubes cells per axis (official: 32 refined to 128)"
    )
    largest_component: bool | None = largest_component_option()


class OccNet(OccupancyMethod):
    display_name = "OccNet"
    description = "ResnetPointnet encoder + occupancy decoder, meshed at tau = 0.2"
    Options = OccNetOptions
    module_path = "shapebench_occnet.module:OccNetModule"
    #: Its encoder's residual blocks (shared with ConvONet) and the recomputation of its
    #: decoder's BatchNorm statistics when training ends.
    code_modules = (
        *OccupancyMethod.code_modules,
        "shapebench.train.blocks",
        "shapebench.train.batchnorm",
    )
    #: Tiny options for ``shapebench check``. Three epochs and a threshold of 0.5: after fewer
    #: steps, or at the paper's 0.2, the tiny network has no surface to mesh.
    check_options = {
        "c_dim": 16,
        "hidden_dim": 16,
        "decoder_hidden": 16,
        "query_points": 256,
        "epochs": 3,
        "lr": 0.003,
        "threshold": 0.5,
        "batch_shapes": 4,
        "mesh_resolution": 32,
    }
    recipes = with_shared(
        {
            "paper": {"decoder": "batchnorm", "queries": "paper"},
            "official": {"decoder": "cbatchnorm", "queries": "uniform"},
        }
    )
    #: ``paper``: DeepSDF's SDF samples (the paper's §4.1); ``uniform``: the padded box.
    query_sources = {"paper": True, "uniform": False}

    def __init__(self, options=None) -> None:
        super().__init__(options)
        sizes, loaded = self.options.context_sizes, self.options.surface_points
        if sizes and (min(sizes) < 1 or max(sizes) > loaded):
            raise ConfigError(
                f"occnet: context_sizes {list(sizes)} must lie in 1..surface_points ({loaded}); "
                f"raise surface_points (-O surface_points={max(max(sizes), loaded)})"
            )
