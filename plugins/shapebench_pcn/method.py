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

from dataclasses import dataclass, field

import numpy as np

from shapebench.implicit.method_base import LightningMethod
from shapebench.types import Completion, Context, Supervision


@dataclass(frozen=True)
class PCNOptions:
    feature: int = field(default=1024, metadata={"help": "global feature size (1024)"})
    num_coarse: int = field(default=1024, metadata={"help": "coarse output points (1024)"})
    grid_size: int = field(default=4, metadata={"help": "folding grid per axis (4: 16 points)"})
    grid_scale: float = field(default=0.05, metadata={"help": "folding grid half-width"})
    target_points: int = field(default=16384, metadata={"help": "target points per object"})
    surface_points: int = field(default=1000, metadata={"help": "largest context size drawn"})
    context_sizes: tuple[int, ...] = field(
        default=(50, 100, 300, 1000), metadata={"help": "context sizes the batches draw from"}
    )
    epochs: int = field(default=5000, metadata={"help": "training epochs (paper: 5000)"})
    batch_shapes: int = field(default=32, metadata={"help": "objects per batch (32)"})
    lr: float = field(default=1e-4, metadata={"help": "learning rate (1e-4)"})
    lr_decay: float = field(default=0.7, metadata={"help": "lr factor every lr_decay_steps"})
    lr_decay_steps: int = field(default=50_000, metadata={"help": "steps between lr decays"})
    alpha_steps: tuple[int, ...] = field(
        default=(10_000, 20_000, 50_000),
        metadata={"help": "steps where the fine-loss weight becomes 0.1, 0.5 and 1.0"},
    )


class PCN(LightningMethod):
    display_name = "PCN"
    description = "point completion network: encoder, coarse points, folding to a dense cloud"
    supervision = frozenset({Supervision.SURFACE_POINTS, Supervision.COMPLETE_POINTS})
    Options = PCNOptions
    batch_size = 16

    @property
    def Module(self):  # imported lazily: torch stays out of registration
        from shapebench_pcn.module import PCNModule

        return PCNModule

    def build_module(self, n_shapes: int):
        o = self.options
        return self.Module(feature=o.feature, num_coarse=o.num_coarse, grid_size=o.grid_size,
                           grid_scale=o.grid_scale, lr=o.lr, lr_decay=o.lr_decay,
                           lr_decay_steps=o.lr_decay_steps, alpha_steps=list(o.alpha_steps),
                           context_sizes=list(o.context_sizes))  # fmt: skip

    def complete_batch(self, contexts: list[Context], n_points: int):
        import torch

        from shapebench.implicit.completion import stack_contexts

        if self.module is None:
            raise RuntimeError("pcn: load_checkpoint() was not called")
        pts, _ = stack_contexts(contexts, self.device)
        with torch.no_grad():
            _, fine = self.module.network(pts)
        out: list[Completion | Exception] = []
        for cloud in fine.cpu().numpy().astype(np.float32):
            out.append(Completion(points=cloud))
        return out
