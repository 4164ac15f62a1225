"""``shapebench.evaluate``: ``shapebench run`` as a Python call, for notebooks and scripts.

    import shapebench
    scores = shapebench.evaluate("gauss", "synthetic", contexts=(50, 1000), split="trained")
    scores.groupby(["context", "category"])["chamfer-l2"].mean()

It resolves and runs the same cells as the command line, through the same code
(:func:`shapebench.evaluation.orchestrate.evaluate`): the same keys, the same cache and the same
store, so a cell computed by one is found by the other. It returns the per-object scores of the
cells it ran (or found cached) in the layout of :func:`shapebench.load_results`. Reading results
back is :mod:`shapebench.boards.frames`; this module only adds the running. docs/python.md shows
both at work.
"""

from __future__ import annotations

import warnings
from collections.abc import Mapping, Sequence
from dataclasses import fields
from pathlib import Path
from typing import Any

import pandas as pd

from shapebench.api.errors import ShapebenchError
from shapebench.api.method import TrainerOptions
from shapebench.api.protocol import DEFAULT_CONTEXT, DEFAULT_FRAME, Protocol
from shapebench.boards.frames import RESULT_COLUMNS, results_of_runs
from shapebench.config import make_settings
from shapebench.evaluation.orchestrate import EvalRequest
from shapebench.evaluation.orchestrate import evaluate as run_request
from shapebench.store.tracking import Tracker
from shapebench.train.training import trainer_options

#: The context sizes of ``shapebench run`` (its ``--contexts`` default).
DEFAULT_CONTEXTS = (50, 100, 300, 1000)


def _ints(values: int | Sequence[int], name: str) -> list[int]:
    items = [values] if isinstance(values, int) else list(values)
    if not items or not all(isinstance(v, int) and not isinstance(v, bool) for v in items):
        raise ShapebenchError(
            f"{name}= must be an int or a sequence of ints, got {values!r}",
            f"e.g. {name}=(50, 1000)",
        )
    return items


def evaluate(
    method: str,
    dataset: str,
    *,
    contexts: int | Sequence[int] = DEFAULT_CONTEXTS,
    split: str | Sequence[str] | None = None,
    seeds: int | Sequence[int] = (0,),
    options: Mapping[str, Any] | None = None,
    dataset_options: Mapping[str, Any] | None = None,
    metrics: Sequence[str] | None = None,
    frame: str = DEFAULT_FRAME,
    context_normals: bool = False,
    protocol: str = DEFAULT_CONTEXT,
    crop_fraction: float = 0.0,
    context_noise: float = 0.0,
    checkpoint: str | Path | None = None,
    label: str | None = None,
    trainer: Mapping[str, Any] | None = None,
    force: bool = False,
    retrain: bool = False,
    progress: bool = True,
    profile: str | None = None,
    data_root: str | Path | None = None,
    workspace: str | Path | None = None,
    tracking_uri: str | None = None,
    cache_dir: str | Path | None = None,
) -> pd.DataFrame:
    """Evaluate ``method`` on ``dataset`` at every context size, as ``shapebench run`` does, and
    return the per-object scores of those cells (the layout of :func:`shapebench.load_results`).

    Each argument is the command's option of the same meaning: ``split`` ``--split`` (default:
    the dataset's evaluation splits), ``options`` ``-O`` (the method's options, e.g.
    ``{"sigma": 0.05}``), ``dataset_options`` ``-D``, ``metrics`` ``--metric`` (default: every
    installed metric computed by default, :attr:`Metric.by_default`; the others when named),
    ``frame`` ``--frame``, ``context_normals`` ``--context-normals``,
    ``protocol``, ``crop_fraction``, ``context_noise`` ``--protocol``, ``--crop-fraction``,
    ``--context-noise``,
    ``checkpoint`` ``--checkpoint``, ``label`` ``--label``, ``trainer`` the trainer options
    (``{"max_steps": 500, "accelerator": "cpu"}``, as ``--max-steps``, ``--accelerator``, ...),
    ``force`` ``--force``, ``retrain`` ``--retrain``, ``progress=False`` ``--quiet``; ``profile``,
    ``data_root``, ``workspace``, ``tracking_uri`` and ``cache_dir`` as the global options.

    Cells already in the store with the same key are not recomputed (``force=True`` recomputes
    them); a trainable method trains first unless a reference checkpoint or ``checkpoint`` has
    its weights. Objects a method could not complete are rows with ``failed`` True and their
    ``reason``; where every object of a cell failed a :class:`RuntimeWarning` says so (the
    command exits with status 1 there). Bad arguments raise
    :class:`~shapebench.ShapebenchError` naming them.
    """
    settings = make_settings(tracking_uri, cache_dir, profile, workspace)
    splits = [split] if isinstance(split, str) else (list(split) if split is not None else None)
    req = EvalRequest(
        method=method,
        dataset=dataset,
        splits=splits,
        contexts=_ints(contexts, "contexts"),
        seeds=_ints(seeds, "seeds"),
        method_opts=dict(options or {}),
        dataset_opts=dict(dataset_options or {}),
        data_root=str(data_root) if data_root is not None else None,
        metrics=list(metrics) if metrics else None,
        checkpoint=str(checkpoint) if checkpoint is not None else None,
        force=force,
        quiet=not progress,
        protocol=Protocol(
            context_normals=context_normals,
            frame=frame,
            context=protocol,
            crop_fraction=crop_fraction,
            context_noise=context_noise,
        ),
        label=label,
        retrain=retrain,
    )
    given = dict(trainer or {})
    unknown = sorted(set(given) - {f.name for f in fields(TrainerOptions)} - {"seed"})
    if unknown or "seed" in given:
        raise ShapebenchError(
            f"trainer= has no option {', '.join(map(repr, unknown or ['seed']))}",
            "trainer options: "
            + ", ".join(f.name for f in fields(TrainerOptions) if f.name != "seed")
            + " (training seeds are seeds=)",
        )
    tracker = Tracker(settings)
    outcome = run_request(
        req, settings, lambda seed: trainer_options(settings, seed, **given), tracker
    )
    for cell in outcome.all_failed_cells:
        reasons = "; ".join(f"{reason} ({n})" for reason, n in cell.reasons) or "see 'reason'"
        warnings.warn(
            f"every object of {method} {cell.split} k={cell.context_size} seed={cell.seed} "
            f"failed: {reasons}",
            RuntimeWarning,
            stacklevel=2,
        )
    by_split: dict[str, list[str]] = {}
    for cell in outcome.cells:
        by_split.setdefault(cell.split, []).append(cell.run_id)
    if not by_split:
        return pd.DataFrame(columns=list(RESULT_COLUMNS))
    return results_of_runs(tracker, dataset, by_split)
