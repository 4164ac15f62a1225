"""Fidelity: how far the completion strays from its own input, with no ground truth needed.

``fidelity`` = mean over the context points c of d(c, P), the Euclidean distance from each point
the method was given to the nearest point of its completion P: a completion that drops or moves
what was observed scores badly. It is the one-sided input-referenced measure PCN and PoinTr report
on KITTI's real scans, where there is no complete shape to compare with. On datasets without
ground truth it is computed by default; elsewhere on request (``--metric fidelity``).
"""

from __future__ import annotations

import numpy as np

from shapebench.api.metric import UNIT_SPHERE_FRAME, Metric, MetricCard
from shapebench.api.types import Completion, Context, ObjectData
from shapebench.geometry.nearest import as_numpy, nearest_distances


class Fidelity(Metric):
    name = "fidelity"
    description = (
        "mean distance from each context point to the completion (input-referenced, needs no "
        "ground truth: KITTI-style scans)"
    )
    by_default = False
    needs_ground_truth = False

    def card(self, eval_points: int) -> MetricCard:
        return MetricCard(
            metric=self.name,
            power=1,
            reduction="mean",
            direction="context->pred",
            halved=False,
            scale=1000.0,
            frame=UNIT_SPHERE_FRAME,
            eval_points=eval_points,
        )

    def compute(self, prediction: Completion, ground_truth: ObjectData, context: Context) -> float:
        return float(np.mean(as_numpy(nearest_distances(context.points, prediction.points))))
