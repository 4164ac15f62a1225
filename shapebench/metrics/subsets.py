"""Equal-size seeded subsets of the prediction and the ground truth, for the metrics defined on
two clouds of one size (EMD's one-to-one matching, DCD as the MVP benchmark computes it).

The subsets are drawn from ``context.seed``, which depends on the dataset, the object, the
context size and the run seed but not on the method: every method's prediction is scored
against the same ground-truth points, and a rerun draws the same points.
"""

from __future__ import annotations

import numpy as np

from shapebench.api.types import Completion, Context, ObjectData
from shapebench.hashing import stable_seed


def equal_subsets(
    prediction: Completion, ground_truth: ObjectData, context: Context, n: int, salt: str
) -> tuple[np.ndarray, np.ndarray]:
    """``m = min(n, |P|, |G|)`` points of each cloud, without replacement, as float64 arrays;
    ``salt`` (the metric's name) keeps two metrics' draws apart."""
    pred = np.asarray(prediction.points, dtype=np.float64)
    gt = np.asarray(ground_truth.gt_points, dtype=np.float64)
    m = min(n, len(pred), len(gt))
    if m == 0:
        raise ValueError("an empty point set has no subset to compare")
    rng_gt = np.random.default_rng(stable_seed(salt, "gt", context.seed))
    rng_pred = np.random.default_rng(stable_seed(salt, "prediction", context.seed))
    return (
        pred[rng_pred.choice(len(pred), m, replace=False)] if m < len(pred) else pred,
        gt[rng_gt.choice(len(gt), m, replace=False)] if m < len(gt) else gt,
    )
