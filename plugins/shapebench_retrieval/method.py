"""Nearest training shape (issue 58 §3, "the floors"): does a method recall or complete?

No learning. For a context, the training shape nearest to it, by the one-sided Chamfer from the
context points to the shape (the mean over the context points of the squared distance to the
nearest point of the shape), is returned whole: that shape's ground-truth points, subsampled (or
resampled, when more are asked for) with the context's seed to ``n_points``. Both are in the
unit-sphere frame the dataset gives every object, so no alignment is searched. A method that
scores no better than this row recalls training shapes rather than completing the observed one.

The candidates are every object of the dataset's ``train`` split, all categories together: the
method is not told the context's category, since a real user's context carries no label (the
category is read only afterwards, for the ``same_category`` diagnostic in the per-object table).

"Training" builds the index of the training shapes (:mod:`shapebench_retrieval.index`), which
is the method's checkpoint: a computation on the training data that no trainer setting changes
(``fit_ignores_trainer``). So the checkpoint key, and through it every cell key, holds the
training data's fingerprint and the option ``index_points``, but no seed, budget, precision or
device count: one index serves every seed, another training set (``-D train_per_category=...``)
is another index and other cells, and options that pick test objects only
(``test_per_category``) reuse the index. The index is self-contained (the training shapes' ground
truths are in it), holds ``index_points`` points per shape for the search, one KD-tree each,
searched exactly with early termination (ties: the lowest index in the ``train`` split's order).
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import ClassVar

import numpy as np

from shapebench.api.method import Method, TrainingContext
from shapebench.api.options import option
from shapebench.api.types import Completion, Context


@dataclass(frozen=True)
class RetrievalOptions:
    index_points: int = option(
        2048,
        "ground-truth points kept per training shape for the search (a seeded subsample): more "
        "is a finer and slower search; the completion is the retrieved shape's whole ground truth "
        "whatever this is",
    )


class Retrieval(Method):
    name = "retrieval"
    display_name = "Nearest training shape"
    description = (
        "the training shape nearest to the context (one-sided Chamfer), returned whole: "
        "no learning, the recall floor"
    )
    #: Its "training" builds the index of the training shapes: the checkpoint, keyed on them.
    trains = True
    #: ... from the data alone (32 s at standard once the objects are prepared): one index for
    #: every seed and trainer, and no shipped reference (the first run that needs it builds it).
    fit_ignores_trainer = True
    Options = RetrievalOptions
    #: The search runs on this KD-tree, and the index's subsample on these seeds.
    code_modules: ClassVar[tuple[str, ...]] = (
        "shapebench.geometry.nearest",
        "shapebench.hashing",
    )
    check_options: ClassVar[dict] = {"index_points": 256}

    def __init__(self, options=None) -> None:
        super().__init__(options)
        self.index = None

    def fit(self, ctx: TrainingContext) -> Path:
        from shapebench_retrieval.index import build_index

        built = build_index(ctx.dataset, self.options.index_points, Path(ctx.workdir), ctx.quiet)
        summary = {
            "wall_seconds": built.seconds,
            "device": "cpu x1",  # one process reads the objects and builds the index
            "devices": 1,
            "device_hours": built.seconds / 3600.0,
            "training_shapes": built.shapes,
            "epochs": 0,
            "optimizer_steps": 0,
            "final": {},
        }
        # Beside the checkpoint, as Lightning trainings leave theirs: the training run records
        # it (shapebench.train.training), so the leaderboard's cost columns show the build.
        (Path(ctx.workdir) / "summary.json").write_text(json.dumps(summary, indent=1))
        return built.path

    def load_checkpoint(self, path: Path) -> None:
        from shapebench_retrieval.index import RetrievalIndex

        self.index = RetrievalIndex.load(Path(path), self.options.index_points)

    def complete(self, context: Context, n_points: int) -> Completion:
        if self.index is None:
            raise RuntimeError("retrieval: load_checkpoint() was not called")
        best, score, searched = self.index.nearest(context.points)
        gt = self.index.cloud(best)
        rng = np.random.default_rng(context.seed)
        if n_points <= len(gt):
            rows = rng.choice(len(gt), size=n_points, replace=False)
        else:  # every point, then repeats drawn at random
            rows = np.concatenate([np.arange(len(gt)), rng.choice(len(gt), n_points - len(gt))])
        info = {
            "retrieved": float(best),  # its position among the indexed training shapes
            "fit": float(score),  # the one-sided Chamfer that chose it
            "same_category": float(self.index.categories[best] == context.ref.category),
            "searched": float(searched),  # shapes whose score was computed to the end
        }
        return Completion(points=gt[rows], info=info)
