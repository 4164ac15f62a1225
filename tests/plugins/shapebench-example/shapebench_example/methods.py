"""Three small methods exercising what the interface allows.

* ``example-sphere``: fits a sphere (centroid, mean radius) to the context; no training.
* ``example-template``: *trains* by averaging the radius of the training objects' surface points,
  saves it as a checkpoint, and completes with a sphere of that radius around the context centroid.
* ``example-flaky``: returns NaNs for some objects, raises for others, and a sphere otherwise:
  shapebench must record the failures and carry on.
"""

from __future__ import annotations

import json
import time
import zlib
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from shapebench.api.method import Method, TrainingContext
from shapebench.api.types import TRAIN, Completion, Context, Supervision


def sphere_points(center: np.ndarray, radius: float, n: int, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    v = rng.normal(size=(n, 3))
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    return (center + radius * v).astype(np.float32)


@dataclass(frozen=True)
class SphereOptions:
    radius_scale: float = field(default=1.0, metadata={"help": "multiplies the fitted radius"})
    delay: float = field(default=0.0, metadata={"help": "seconds to sleep per object (tests)"})


class SphereFit(Method):
    display_name = "Sphere fit (example)"
    description = "fits a sphere to the context points"
    Options = SphereOptions

    def complete(self, context: Context, n_points: int) -> Completion:
        time.sleep(self.options.delay)
        c = context.points.mean(axis=0)
        r = float(np.linalg.norm(context.points - c, axis=1).mean()) * self.options.radius_scale
        return Completion(sphere_points(c, r, n_points, context.seed), info={"radius": r})


class MeanRadiusTemplate(Method):
    display_name = "Mean-radius template (example)"
    description = "learns the mean object radius on the train split"
    supervision = frozenset({Supervision.SURFACE_POINTS})
    trains = True

    def fit(self, ctx: TrainingContext) -> Path:
        radii = []
        for ref in ctx.dataset.objects(TRAIN):
            data = ctx.dataset.load(ref)
            radii.append(float(np.linalg.norm(data.surface_points, axis=1).mean()))
        path = ctx.workdir / "template.json"
        path.write_text(json.dumps({"radius": float(np.mean(radii)), "n": len(radii)}))
        if ctx.run_id:
            from mlflow.tracking import MlflowClient

            MlflowClient(ctx.tracking_uri).log_metric(ctx.run_id, "train_objects", len(radii))
        return path

    def load_checkpoint(self, path: Path) -> None:
        self.radius = json.loads(Path(path).read_text())["radius"]

    def complete(self, context: Context, n_points: int) -> Completion:
        c = context.points.mean(axis=0)
        return Completion(sphere_points(c, self.radius, n_points, context.seed))


class Flaky(Method):
    display_name = "Flaky (example)"
    description = "fails on purpose for some objects"

    def complete(self, context: Context, n_points: int) -> Completion:
        bucket = zlib.crc32(context.ref.id.encode()) % 3
        if bucket == 0:
            return Completion(np.full((n_points, 3), np.nan, dtype=np.float32))
        if bucket == 1:
            raise RuntimeError("flaky method gave up")
        return Completion(sphere_points(context.points.mean(axis=0), 0.5, n_points, context.seed))
