"""What a run computes: a :class:`RunPlan` (one method on one dataset, its splits, context sizes,
seeds and metrics) and its *cells*, one per split, context size and seed, each identified by the
hash of :func:`cell_config` (the cell key) and described by a :class:`CellRecord` (its tags)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from shapebench import __version__
from shapebench.api.contexts import CONTEXTS_VERSION
from shapebench.api.dataset import Dataset
from shapebench.api.errors import ShapebenchError
from shapebench.api.metric import Metric
from shapebench.api.protocol import Protocol
from shapebench.hashing import stable_hash
from shapebench.registry.resolve import ResolvedMethod
from shapebench.registry.variant import Variant
from shapebench.store.provenance import git_commit
from shapebench.store.records import CellRecord


@dataclass
class RunPlan:
    method: ResolvedMethod
    dataset: Dataset
    splits: list[str]
    contexts: list[int]
    seeds: list[int]
    metrics: list[Metric]
    force: bool = False
    quiet: bool = False
    checkpoint: dict[str, Any] = field(default_factory=dict)  # key/path/run id when trained
    protocol: Protocol = field(default_factory=Protocol)
    variant: Variant | None = None


def validate_contexts(contexts: list[int]) -> list[int]:
    """The context sizes, sorted and without repeats; an empty list or a size that is not a
    positive integer is refused."""
    if not contexts:
        raise ShapebenchError("no context sizes given", "e.g. --contexts 50,100,300,1000")
    bad = [c for c in contexts if not isinstance(c, int) or c <= 0]
    if bad:
        raise ShapebenchError(f"context sizes must be positive integers, got {bad}")
    return sorted(set(contexts))


def cell_config(plan: RunPlan, split: str, size: int, seed: int, eval_points: int) -> dict:
    """Everything that determines a cell's result; its hash is the cell key. The method part
    holds a digest of its code, and the checkpoint key the training settings and data."""
    frame = plan.protocol.frame
    cfg = {
        "protocol": plan.protocol.config(),
        "method": plan.method.config(),
        "dataset": plan.dataset.config(),
        "split": split,
        "context_size": size,
        "seed": seed,
        "contexts": CONTEXTS_VERSION,
        "metrics": {m.name: m.card(eval_points).in_frame(frame).as_tag() for m in plan.metrics},
        "checkpoint": plan.checkpoint.get("key"),
        "training": plan.checkpoint.get("training"),
    }
    if plan.checkpoint.get("weights"):  # shipped weights (reference checkpoints); local: absent,
        cfg["weights"] = plan.checkpoint["weights"]  # so cells of local trainings keep their keys
    return cfg


def planned_cells(plan: RunPlan, split: str) -> list[tuple[int, int, dict, str]]:
    """``(seed, context size, config, cell key)`` of every cell of ``plan`` on ``split``."""
    opts = plan.dataset.options
    eval_points = opts.gt_points if hasattr(opts, "gt_points") else 0
    out = []
    for seed in plan.seeds:
        for size in validate_contexts(plan.contexts):
            cfg = cell_config(plan, split, size, seed, eval_points)
            out.append((seed, size, cfg, stable_hash(cfg)))
    return out


def cell_record(plan: RunPlan, split: str, size: int, seed: int, key: str, cfg: dict) -> CellRecord:
    """The record (the tags) of the cell ``key`` of ``plan``, whose config is ``cfg``."""
    ds = plan.dataset
    plugin = plan.method.registration.plugin
    variant = plan.variant
    return CellRecord(
        cell_key=key,
        method=plan.method.name,
        dataset=ds.name,
        split=split,
        context_size=size,
        seed=seed,
        cards=dict(cfg["metrics"]),
        display_name=plan.method.display_name,
        trains=bool(plan.method.cls.trains),
        method_code=cfg["method"]["code"],
        dataset_version=ds.version,
        fingerprint=ds.fingerprint(),
        data_root=str(ds.data_root) if ds.data_root else "",
        shapebench_version=__version__,
        plugin_distribution=plugin.distribution,
        plugin_version=plugin.version,
        git_commit=git_commit(),
        checkpoint_key=str(plan.checkpoint.get("key") or ""),
        training_run_id=str(plan.checkpoint.get("run_id") or ""),
        frame=plan.protocol.frame,
        context_normals=plan.protocol.context_normals,
        context_protocol="" if plan.protocol.is_default_context else plan.protocol.name,
        variant_key=variant.key if variant else "",
        variant_label=variant.label if variant else "",
        variant_overrides=dict(variant.overrides) if variant else {},
    )
