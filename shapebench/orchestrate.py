"""``shapebench run``: resolve names, train if needed, run the cells, collect the outcome."""

from __future__ import annotations

import os
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from shapebench.config import Settings
from shapebench.dataset import Dataset
from shapebench.errors import ShapebenchError
from shapebench.method import Method, TrainerOptions
from shapebench.registry import get_registry
from shapebench.resolve import ResolvedMethod, resolve_dataset, resolve_method, resolve_metrics
from shapebench.runner import CellResult, Runner, RunPlan, validate_contexts
from shapebench.tracking import Tracker
from shapebench.training import checkpoint_key, ensure_checkpoint
from shapebench.types import TRAIN


@dataclass
class EvalRequest:
    method: str
    dataset: str
    splits: list[str] | None = None
    contexts: list[int] = field(default_factory=lambda: [50, 100, 300, 1000])
    seeds: list[int] = field(default_factory=lambda: [0])
    method_opts: dict[str, Any] = field(default_factory=dict)
    dataset_opts: dict[str, Any] = field(default_factory=dict)
    data_root: str | None = None
    metrics: list[str] | None = None
    checkpoint: str | None = None
    force: bool = False
    quiet: bool = False


@dataclass
class EvalOutcome:
    method: ResolvedMethod
    dataset: Dataset
    primary_metric: str
    cells: list[CellResult]


def _check_splits(dataset: Dataset, splits: list[str] | None) -> list[str]:
    if not splits:
        return list(dataset.eval_splits)
    unknown = [s for s in splits if s not in dataset.eval_splits]
    if unknown:
        raise ShapebenchError(
            f"dataset {dataset.name!r} has no evaluation split {', '.join(unknown)}",
            f"use one of: {', '.join(dataset.eval_splits)}",
        )
    return splits


def _given_checkpoint_key(path: str) -> str:
    st = os.stat(path)
    return f"file:{Path(path).resolve()}:{st.st_size}:{int(st.st_mtime)}"


def evaluate(
    req: EvalRequest,
    settings: Settings,
    trainer_for_seed: Callable[[int], TrainerOptions],
    tracker: Tracker | None = None,
) -> EvalOutcome:
    registry = get_registry()
    method = resolve_method(registry, req.method, settings, req.method_opts)
    dataset = resolve_dataset(registry, req.dataset, settings, req.data_root, req.dataset_opts)
    splits = _check_splits(dataset, req.splits)
    contexts = validate_contexts(req.contexts)
    bound = dataset.max_context_size()
    if bound is not None and max(contexts) > bound:
        raise ShapebenchError(
            f"context size {max(contexts)} is larger than the {bound} surface points that dataset "
            f"{dataset.name!r} samples per object",
            "use smaller context sizes, or sample more surface points (-D surface_candidates=...)",
        )
    metrics = resolve_metrics(registry, req.metrics)
    primary = (
        dataset.default_metric
        if any(m.name == dataset.default_metric for m in metrics)
        else metrics[0].name
    )
    if method.cls.trains and not req.checkpoint and not dataset.objects(TRAIN):
        raise ShapebenchError(
            f"method {method.name!r} needs training, and dataset {dataset.name!r} has no "
            "training objects",
            f"train on a dataset that has some (e.g. shapebench train -m {method.name} -d "
            "synthetic) and pass the checkpoint with --checkpoint PATH",
        )
    tracker = tracker or Tracker(settings)  # an unreachable server fails here, before any work
    runner = Runner(tracker)
    cells: list[CellResult] = []
    for seed in req.seeds:
        checkpoint: dict[str, str] = {}
        if method.cls.trains:
            checkpoint["key"] = (
                _given_checkpoint_key(req.checkpoint)
                if req.checkpoint
                else checkpoint_key(method, dataset, seed)
            )
        plan = RunPlan(
            method, dataset, splits, contexts, [seed], metrics, req.force, req.quiet, checkpoint
        )
        cells += runner.run(
            plan,
            _method_factory(method, dataset, req, settings, trainer_for_seed(seed), checkpoint),
        )
    return EvalOutcome(method, dataset, primary, cells)


def _method_factory(
    method: ResolvedMethod,
    dataset: Dataset,
    req: EvalRequest,
    settings: Settings,
    trainer: TrainerOptions,
    checkpoint: dict[str, str],
) -> Callable[[], Method]:
    def make() -> Method:
        instance = method.instantiate()
        if method.cls.trains:
            if req.checkpoint:
                path = req.checkpoint
            else:
                record = ensure_checkpoint(
                    method,
                    dataset,
                    trainer,
                    settings,
                    Path(req.data_root) if req.data_root else None,
                    req.quiet,
                )
                path = record["path"]
                if record.get("run_id"):
                    checkpoint["run_id"] = record["run_id"]
            instance.load_checkpoint(Path(path))
        return instance

    return make
