"""PoinTr's LightningModule: k context points in, CD-L1 of the coarse and dense clouds."""

from __future__ import annotations

import torch

from shapebench.train.batchnorm import is_final_step, recalibrate_batchnorm
from shapebench.train.losses import chamfer_l1_halved
from shapebench.train.point_cloud_module import PointCloudModule
from shapebench_pointr.method import PoinTrOptions
from shapebench_pointr.network import PoinTrNetwork


class PoinTrModule(PointCloudModule):
    Options = PoinTrOptions
    options: PoinTrOptions

    def __init__(self, options: PoinTrOptions | None = None, n_shapes: int = 0, **saved) -> None:
        super().__init__(options, n_shapes, **saved)
        o = self.options
        self.network = PoinTrNetwork(
            o.dim,
            o.heads,
            (o.encoder_depth, o.decoder_depth),
            num_query=o.num_query,
            fold_step=o.fold_step,
            global_dim=o.global_dim,
            proxies=o.proxies,
            init=o.init,
        )

    def losses(self, points: torch.Tensor, target: torch.Tensor) -> dict[str, torch.Tensor]:
        coarse, fine = self.network(points)
        if self.options.fine_loss == "folded":  # the ablation: the input's copy left out
            fine = fine[:, : fine.shape[1] - points.shape[1]]
        return {
            "coarse": chamfer_l1_halved(coarse, target).mean(),
            "fine": chamfer_l1_halved(fine, target).mean(),
        }

    def combine(self, terms: dict[str, torch.Tensor]):
        loss = terms["coarse"] + terms["fine"]  # 1:1, as the official
        return loss, {"coarse_cd": terms["coarse"], "fine_cd": terms["fine"]}

    def on_train_batch_end(self, outputs, batch, batch_idx: int) -> None:
        # The folding head's BatchNorm statistics, recomputed for the final weights before the
        # last checkpoint is written (shapebench.train.batchnorm says why).
        if self.options.precise_bn_batches and is_final_step(self.trainer):
            recalibrate_batchnorm(
                self.network,
                lambda b, gen: self.network(b["points"][:, : self.context_size(gen)]),
                self.trainer.train_dataloader,
                self.options.precise_bn_batches,
            )

    def configure_gradient_clipping(
        self, optimizer, gradient_clip_val=None, gradient_clip_algorithm=None
    ) -> None:
        # The official gradient-norm clip, whatever the Trainer is given.
        self.clip_gradients(optimizer, self.options.grad_clip, "norm")

    def configure_optimizers(self):
        o = self.options
        decay, plain = [], []
        for name, p in self.named_parameters():
            (plain if p.ndim <= 1 or name.endswith(".bias") else decay).append(p)
        opt = torch.optim.AdamW(
            [
                {"params": decay, "weight_decay": o.weight_decay},
                {"params": plain, "weight_decay": 0},
            ],
            lr=o.lr,
        )
        sched = torch.optim.lr_scheduler.LambdaLR(
            opt, lambda step: max(o.lr_decay ** (step / o.lr_decay_steps), o.lr_floor)
        )
        return {"optimizer": opt, "lr_scheduler": {"scheduler": sched, "interval": "step"}}
