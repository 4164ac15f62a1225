"""Density-aware Chamfer distance (DCD; Wu et al., NeurIPS 2021), the official defaults.

For two clouds A and B and each point a of A: â is its nearest neighbour in B, d(a) the squared
distance to it, and c(a) how many points of A have â as their nearest neighbour. The term of A is

    mean over a in A of  1 - exp(-alpha d(a)) * (|A| / |B|) / c(a)^n_lambda

and ``dcd`` = 1/2 (term of the ground truth + term of the prediction). alpha = 1000 and
n_lambda = 1 are the official code's defaults (other copies use other values: the card states
them); the squared distance in the exponent and the size ratio are the official code's
(``calc_dcd`` with ``non_reg=False``). The value is 0 for identical clouds and at most 1.

The size ratio only cancels out when the clouds have about one size: with 30,000 ground-truth
points against a 2,000-point prediction, a ground-truth point whose neighbour is shared by few
others gets a weight near 15 and its term goes far below 0. The MVP benchmark, where DCD is
reported, compares 2,048 points with 2,048; ``dcd`` does the same, on equal-size seeded subsets
(:mod:`shapebench.metrics.subsets`). Computed on request (``--metric dcd``).
"""

from __future__ import annotations

from typing import ClassVar

import numpy as np

from shapebench.api.metric import UNIT_SPHERE_FRAME, Metric, MetricCard
from shapebench.api.types import Completion, Context, ObjectData
from shapebench.geometry.nearest import kdtree
from shapebench.metrics.subsets import equal_subsets


def density_aware_term(a: np.ndarray, b: np.ndarray, alpha: float, n_lambda: float) -> float:
    """The term of ``a`` (see the module docstring)."""
    squared, nearest = kdtree(b).query(a, k=1)
    squared = np.asarray(squared, dtype=np.float64) ** 2
    shared = np.bincount(nearest, minlength=len(b))[nearest].astype(np.float64)
    # The official code adds 1e-6 to the count, which is never below 1 here (a point counts
    # itself): left out, so that identical clouds score exactly 0 (the official ~1e-6).
    weight = (len(a) / len(b)) / shared**n_lambda
    return float(np.mean(1.0 - np.exp(-alpha * squared) * weight))


def density_aware_chamfer(
    pred: np.ndarray, gt: np.ndarray, alpha: float = 1000.0, n_lambda: float = 1.0
) -> float:
    """DCD of two clouds (see the module docstring)."""
    return 0.5 * (
        density_aware_term(gt, pred, alpha, n_lambda)
        + density_aware_term(pred, gt, alpha, n_lambda)
    )


class DCD(Metric):
    name = "dcd"
    description = (
        "density-aware Chamfer distance (alpha 1000, n_lambda 1, the official defaults) on "
        "2,048-point seeded subsets; 0 to 1, lower is better (on request)"
    )
    by_default = False
    alpha: ClassVar[float] = 1000.0
    n_lambda: ClassVar[float] = 1.0
    #: Points drawn from each cloud.
    points: ClassVar[int] = 2048

    def card(self, eval_points: int) -> MetricCard:
        return MetricCard(
            metric=self.name,
            power=0,
            reduction="mean",
            direction="symmetric",
            combine="mean",
            halved=False,
            scale=1.0,
            frame=UNIT_SPHERE_FRAME,
            eval_points=eval_points,
            quantity=(
                f"1 - exp(-alpha d^2) r / c^n_lambda with d the NN distance, c how many points "
                f"of the set share that neighbour, r the ratio of the set sizes, "
                f"alpha={self.alpha:g}, n_lambda={self.n_lambda:g} (Wu et al. 2021), on "
                f"{self.points}-point subsets drawn with the context's seed"
            ),
        )

    def compute(self, prediction: Completion, ground_truth: ObjectData, context: Context) -> float:
        pred, gt = equal_subsets(prediction, ground_truth, context, self.points, self.name)
        return density_aware_chamfer(pred, gt, self.alpha, self.n_lambda)
