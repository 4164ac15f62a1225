"""Gauss densification (the baseline of the paper's Tables 1-3).

Every context point spawns isotropic Gaussian samples around itself until the output has as many
points as the ground truth. It models nothing beyond the observation, so it shows how much of a
score comes from densifying what was seen rather than completing what was not.

sigma defaults to 0.01 (1% of the object radius in the unit-sphere frame); the paper does not give
its value.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from shapebench.api.method import Method
from shapebench.api.types import Completion, Context


@dataclass(frozen=True)
class GaussOptions:
    sigma: float = field(
        default=0.01, metadata={"help": "standard deviation of the samples (unit-sphere frame)"}
    )


class GaussDensification(Method):
    name = "gauss"
    display_name = "Gauss densification"
    description = "isotropic Gaussian samples around each context point (no training)"
    trains = False
    Options = GaussOptions

    def complete(self, context: Context, n_points: int) -> Completion:
        k = context.size
        if k == 0:
            return Completion(points=np.empty((0, 3), dtype=np.float32))
        rng = np.random.default_rng(context.seed)
        per_point = -(-n_points // k)  # ceil: every point spawns the same number of samples
        centres = np.repeat(context.points, per_point, axis=0)
        noise = rng.normal(scale=self.options.sigma, size=centres.shape)
        points = (centres + noise)[rng.permutation(len(centres))[:n_points]]
        return Completion(points=points.astype(np.float32))
