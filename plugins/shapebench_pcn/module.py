"""PCN's LightningModule: k context points in, the complete cloud as target."""

from __future__ import annotations

import torch

from shapebench.train.losses import chamfer_l1_halved
from shapebench.train.point_cloud_module import PointCloudModule
from shapebench_pcn.losses import alpha, sinkhorn_emd
from shapebench_pcn.method import PCNOptions
from shapebench_pcn.network import PCNNetwork


class PCNModule(PointCloudModule):
    Options = PCNOptions
    options: PCNOptions
    #: The entropic regularisation of the Sinkhorn EMD (see :mod:`shapebench_pcn.losses`).
    sinkhorn_eps = 0.01

    def __init__(self, options: PCNOptions | None = None, n_shapes: int = 0, **saved) -> None:
        super().__init__(options, n_shapes, **saved)
        o = self.options
        self.network = PCNNetwork(
            o.feature, o.num_coarse, o.grid_size, o.grid_scale, o.decoder_width
        )

    def losses(self, points: torch.Tensor, target: torch.Tensor) -> dict[str, torch.Tensor]:
        coarse, fine = self.network(points)
        # The official coarse target is the first num_coarse points of a shuffled GT cloud.
        coarse_gt = target[:, : coarse.shape[1]]
        return {
            "coarse": sinkhorn_emd(coarse, coarse_gt, self.sinkhorn_eps).mean(),
            "fine": chamfer_l1_halved(fine, target).mean(),
        }

    def combine(self, terms: dict[str, torch.Tensor]):
        # The fine term's weight alpha grows at the step boundaries (the official schedule).
        a = alpha(self.global_step, tuple(self.options.alpha_steps))
        loss = terms["coarse"] + a * terms["fine"]
        return loss, {"coarse_emd": terms["coarse"], "fine_cd": terms["fine"], "alpha": a}

    def configure_optimizers(self):
        o = self.options
        opt = torch.optim.Adam(self.parameters(), lr=o.lr)
        # x0.7 every lr_decay_steps steps (the paper's schedule; the code's --lr_decay flag).
        floor = 1e-6 / o.lr
        sched = torch.optim.lr_scheduler.LambdaLR(
            opt, lambda step: max(o.lr_decay ** (step // o.lr_decay_steps), floor)
        )
        return {"optimizer": opt, "lr_scheduler": {"scheduler": sched, "interval": "step"}}
