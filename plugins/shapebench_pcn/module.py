"""PCN's LightningModule: k context points in, the complete cloud as target."""

from __future__ import annotations

import pytorch_lightning as pl
import torch

from shapebench.lightning_fit import step_generator
from shapebench_pcn.losses import alpha, chamfer_l1_halved, sinkhorn_emd
from shapebench_pcn.network import PCNNetwork


class PCNModule(pl.LightningModule):
    def __init__(self, feature: int, num_coarse: int, grid_size: int, grid_scale: float,
                 lr: float, lr_decay: float, lr_decay_steps: int, alpha_steps: list[int],
                 context_sizes: list[int], sinkhorn_eps: float = 0.01) -> None:  # fmt: skip
        super().__init__()
        self.save_hyperparameters()
        self.network = PCNNetwork(feature, num_coarse, grid_size, grid_scale)

    def losses(self, points: torch.Tensor, target: torch.Tensor) -> dict[str, torch.Tensor]:
        coarse, fine = self.network(points)
        # The official coarse target is the first num_coarse points of a shuffled GT cloud.
        coarse_gt = target[:, : coarse.shape[1]]
        return {
            "coarse": sinkhorn_emd(coarse, coarse_gt, self.hparams.sinkhorn_eps).mean(),
            "fine": chamfer_l1_halved(fine, target).mean(),
        }

    def training_step(self, batch: dict[str, torch.Tensor], batch_idx: int) -> torch.Tensor:
        # Every batch sees one of the benchmark's context sizes, drawn from the seeded generator.
        sizes = self.hparams.context_sizes
        k = sizes[int(torch.randint(len(sizes), (1,), generator=step_generator(self)))]
        terms = self.losses(batch["points"][:, :k], batch["complete"])
        a = alpha(self.global_step, tuple(self.hparams.alpha_steps))
        loss = terms["coarse"] + a * terms["fine"]
        self.log_dict({"train/loss": loss, "train/coarse_emd": terms["coarse"],
                       "train/fine_cd": terms["fine"], "train/alpha": a},
                      on_step=False, on_epoch=True, batch_size=len(batch["points"]),
                      sync_dist=True)  # fmt: skip
        return loss

    def configure_optimizers(self):
        h = self.hparams
        opt = torch.optim.Adam(self.parameters(), lr=h.lr)
        # x0.7 every lr_decay_steps steps (the paper's schedule; the code's --lr_decay flag).
        floor = 1e-6 / h.lr
        sched = torch.optim.lr_scheduler.LambdaLR(
            opt, lambda step: max(h.lr_decay ** (step // h.lr_decay_steps), floor)
        )
        return {"optimizer": opt, "lr_scheduler": {"scheduler": sched, "interval": "step"}}
