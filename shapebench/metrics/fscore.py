"""F-score at a distance threshold, as point-completion benchmarks report it.

Precision is the fraction of predicted points within ``tau`` of the ground truth, recall the
fraction of ground-truth points within ``tau`` of the prediction, F = 2PR / (P + R) (0 when both
are 0). ``tau = 0.01`` in the unit-sphere frame, the common default (PoinTr, GRNet).
"""

from __future__ import annotations

from typing import ClassVar

from shapebench.api.metric import UNIT_SPHERE_FRAME, Metric, MetricCard
from shapebench.api.types import Completion, Context, ObjectData
from shapebench.metrics.chamfer import gt_to_pred, pred_to_gt


class FScore(Metric):
    name = "fscore"
    description = "F-score of points within tau = 0.01 of the other set (higher is better)"
    higher_is_better = True
    tau: ClassVar[float] = 0.01

    def card(self, eval_points: int) -> MetricCard:
        return MetricCard(
            metric=self.name,
            power=1,
            reduction="fraction",
            threshold=self.tau,
            direction="symmetric",
            combine="harmonic-mean",
            halved=False,
            scale=1.0,
            frame=UNIT_SPHERE_FRAME,
            eval_points=eval_points,
            higher_is_better=True,
        )

    def compute(self, prediction: Completion, ground_truth: ObjectData, context: Context) -> float:
        precision = float((pred_to_gt(prediction, ground_truth) < self.tau).mean())
        recall = float((gt_to_pred(prediction, ground_truth) < self.tau).mean())
        if precision + recall == 0:
            return 0.0
        return 2 * precision * recall / (precision + recall)
