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

import math
from dataclasses import dataclass, field

import numpy as np
from shapebench_igr.options import _c

from shapebench.errors import ConfigError
from shapebench.implicit.method_base import LightningMethod
from shapebench.implicit.recipes import apply_recipe, with_shared
from shapebench.types import Completion, Context, Supervision

RECIPES = with_shared({"paper": {"decoder": "batchnorm", "queries": "paper"},
                       "official": {"decoder": "cbatchnorm", "queries": "uniform"}})  # fmt: skip
QUERY_SOURCES = ("paper", "uniform")


@dataclass(frozen=True)
class OccNetOptions:
    recipe: str = field(
        default="paper",
        metadata={
            "help": "'paper' (DecoderBatchNorm, SDF-sample queries) or 'official' "
            "(DecoderCBatchNorm, uniform queries)"
        },
    )
    decoder: str | None = field(
        default=None,
        metadata={"help": "batchnorm or cbatchnorm [paper: batchnorm, official: cbatchnorm]"},
    )
    queries: str | None = field(
        default=None,
        metadata={
            "help": "training queries: 'paper' (DeepSDF's SDF samples, inside where "
            "sdf < 0) or 'uniform' (the padded box) [paper: paper, official: uniform]"
        },
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
    largest_component: bool | None = _c(
        None,
        "keep only the mesh's largest connected component, by area [paper: no, official: "
        "yes, as for every implicit method]",
    )


class OccNet(LightningMethod):
    display_name = "OccNet"
    description = "ResnetPointnet encoder + occupancy decoder, meshed at tau = 0.2"
    #: Every kind either query source may need (``prepare -m occnet`` builds both); an instance
    #: asks for one through :meth:`needs`.
    supervision = frozenset(
        {Supervision.SURFACE_POINTS, Supervision.OCCUPANCY_SAMPLES, Supervision.SDF_SAMPLES}
    )
    Options = OccNetOptions

    def __init__(self, options=None) -> None:
        super().__init__(options)
        self.options = apply_recipe(self.options, RECIPES, "occnet")
        if self.options.queries not in QUERY_SOURCES:
            raise ConfigError(f"occnet: queries must be one of {list(QUERY_SOURCES)}, "
                              f"got {self.options.queries!r}")  # fmt: skip

    def needs(self) -> frozenset[Supervision]:
        queries = (Supervision.SDF_SAMPLES if self.options.queries == "paper"
                   else Supervision.OCCUPANCY_SAMPLES)  # fmt: skip
        return frozenset({Supervision.SURFACE_POINTS, queries})

    def data_module(self, ctx):
        data = super().data_module(ctx)
        data.queries_from_sdf = self.options.queries == "paper"
        return data

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
                               level=math.log(tau / (1 - tau)), inside_is_negative=False,
                               keep_largest=bool(self.options.largest_component))  # fmt: skip
