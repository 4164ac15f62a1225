"""OccNet: a point-cloud encoder and an occupancy decoder, meshed at a probability threshold.

Training (official ``configs/pointcloud/onet.yaml``; the paper's Appendix A.1): 300 surface
points with Gaussian noise of std 0.005 to the ResnetPointnet encoder, 2048 occupancy queries
drawn from 100k points uniform in the padded bounding box (labels from an inside test, see
``shapebench.preprocess.samples.occupancy_samples``), binary cross-entropy on logits summed over
the queries; Adam lr 1e-4, batch 64. Completion: the encoder on the context points, then the
coarse-to-fine marching cubes at the official threshold tau = 0.2 (a logit of log(0.2/0.8)), and
points sampled on the mesh.

Paper vs official (``recipe``): the paper names ``DecoderBatchNorm``; the official point-cloud
configuration uses ``DecoderCBatchNorm``. ``-O recipe=official`` (or ``-O decoder=cbatchnorm``)
switches.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from shapebench_igr.options import _c

from shapebench.implicit.method_base import LightningMethod
from shapebench.implicit.recipes import apply_recipe
from shapebench.types import Completion, Context, Supervision

RECIPES = {"paper": {"decoder": "batchnorm"}, "official": {"decoder": "cbatchnorm"}}


@dataclass(frozen=True)
class OccNetOptions:
    recipe: str = field(
        default="paper",
        metadata={"help": "'paper' (DecoderBatchNorm) or 'official' (DecoderCBatchNorm)"},
    )
    decoder: str | None = field(
        default=None,
        metadata={"help": "batchnorm or cbatchnorm [paper: batchnorm, official: cbatchnorm]"},
    )
    c_dim: int = field(default=512, metadata={"help": "code size (512)"})
    hidden_dim: int = field(default=512, metadata={"help": "encoder width (512)"})
    decoder_hidden: int = field(default=256, metadata={"help": "decoder width (256)"})
    input_points: int = field(default=300, metadata={"help": "encoder points in training (300)"})
    input_noise: float = field(default=0.005, metadata={"help": "noise std on encoder input"})
    query_points: int = field(default=2048, metadata={"help": "occupancy queries per step"})
    surface_points: int = field(default=300, metadata={"help": "surface points loaded per step"})
    epochs: int = field(default=5000, metadata={"help": "training epochs (paper: 5000)"})
    batch_shapes: int = field(default=64, metadata={"help": "objects per batch (64)"})
    lr: float = field(default=1e-4, metadata={"help": "learning rate (1e-4)"})
    threshold: float = _c(0.2, "occupancy probability of the surface (official: 0.2)")
    mesh_resolution: int = _c(128, "marching-cubes cells per axis (official: 32 refined to 128)")


class OccNet(LightningMethod):
    display_name = "OccNet"
    description = "ResnetPointnet encoder + occupancy decoder, meshed at tau = 0.2"
    supervision = frozenset({Supervision.SURFACE_POINTS, Supervision.OCCUPANCY_SAMPLES})
    Options = OccNetOptions

    def __init__(self, options=None) -> None:
        super().__init__(options)
        self.options = apply_recipe(self.options, RECIPES, "occnet")

    @property
    def Module(self):  # imported lazily: torch stays out of registration
        from shapebench_occnet.module import OccNetModule

        return OccNetModule

    def build_module(self, n_shapes: int):
        o = self.options
        return self.Module(c_dim=o.c_dim, hidden_dim=o.hidden_dim, decoder=o.decoder,
                           decoder_hidden=o.decoder_hidden, lr=o.lr,
                           input_points=o.input_points, input_noise=o.input_noise)  # fmt: skip

    def complete_batch(self, contexts: list[Context], n_points: int):
        import torch

        from shapebench.implicit.completion import stack_contexts

        if self.module is None:
            raise RuntimeError("occnet: load_checkpoint() was not called")
        pts, _ = stack_contexts(contexts, self.device)
        with torch.no_grad():
            codes = self.module.encoder(pts)
        out: list[Completion | Exception] = []
        for code, ctx in zip(codes, contexts, strict=True):
            try:
                out.append(self._mesh(code, ctx, n_points))
            except Exception as exc:  # no surface at tau, NaN: this object fails alone
                out.append(exc)
        return out

    def _mesh(self, code, ctx: Context, n_points: int) -> Completion:
        import torch

        from shapebench.implicit.completion import mesh_completion

        decoder = self.module.decoder

        @torch.no_grad()
        def logits(points: np.ndarray) -> np.ndarray:
            x = torch.from_numpy(np.ascontiguousarray(points, dtype=np.float32))[None]
            return decoder(x.to(self.device), code[None]).cpu().numpy()[0]

        tau = self.options.threshold
        return mesh_completion(logits, ctx, n_points, self.options.mesh_resolution,
                               level=math.log(tau / (1 - tau)),
                               inside_is_negative=False)  # fmt: skip
