"""``shapebench run``: resolve names, train if needed, run the cells, collect the outcome."""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from shapebench.api import options as opts
from shapebench.api.dataset import Dataset
from shapebench.api.errors import ShapebenchError
from shapebench.api.method import Method, TrainerOptions
from shapebench.api.protocol import Protocol
from shapebench.api.types import TRAIN
from shapebench.config import Settings, plugin_overrides
from shapebench.evaluation.plan import RunPlan, validate_contexts
from shapebench.evaluation.results import CellResult
from shapebench.evaluation.runner import Runner
from shapebench.registry.discovery import get_registry
from shapebench.registry.resolve import (
    ResolvedMethod,
    resolve_dataset,
    resolve_method,
    resolve_metrics,
)
from shapebench.registry.variant import Variant, make_variant
from shapebench.store.tracking import Tracker
from shapebench.train.references import GivenCheckpoint, given_checkpoint
from shapebench.train.ticket import (
    TrainingTicket,
    apply_trainer,
    training_identity,
    training_ticket,
)
from shapebench.train.training import ensure_checkpoint, profile_trainer


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
    protocol: Protocol = field(default_factory=Protocol)
    label: str | None = None
    #: Train locally even when a reference checkpoint of the key is shipped.
    retrain: bool = False


@dataclass
class EvalOutcome:
    method: ResolvedMethod
    dataset: Dataset
    primary_metric: str
    cells: list[CellResult]
    variant: Variant | None = None
    #: Wall seconds of this outcome spent getting weights (training, or installing a shipped
    #: checkpoint) rather than evaluating: progress estimates leave them out.
    train_seconds: float = 0.0

    @property
    def all_failed_cells(self) -> list[CellResult]:
        """Cells in which no object could be scored: the run must not look successful."""
        return [c for c in self.cells if c.n_objects and c.n_ok == 0]


def _check_splits(dataset: Dataset, splits: list[str] | None) -> list[str]:
    if not splits:
        return list(dataset.eval_splits)
    allowed = [*dataset.eval_splits, *dataset.validation_splits]
    unknown = [s for s in splits if s not in allowed]
    if unknown:
        raise ShapebenchError(
            f"dataset {dataset.name!r} has no evaluation split {', '.join(unknown)}",
            f"use one of: {', '.join(allowed)}",
        )
    empty = [s for s in splits if not dataset.objects(s)]
    if empty:  # asked for by name: an empty split is a mistake, not something to skip quietly
        notes = "; ".join(n for s in empty for n in dataset.selection_notes(s))
        raise ShapebenchError(
            f"split {', '.join(empty)} of dataset {dataset.name!r} has no objects"
            + (f" ({notes})" if notes else ""),
            "check the dataset options that select objects (shapebench datasets lists them)",
        )
    return splits


@dataclass
class Resolved:
    """A request with its names resolved and checked: what every seed of it evaluates."""

    method: ResolvedMethod
    dataset: Dataset
    splits: list[str]
    contexts: list[int]
    metrics: list[Any]
    primary: str


@dataclass
class SeedPlan:
    """One seed of a request: its trainer settings, method (with ``--max-epochs`` applied), the
    cells' plan and the checkpoint it needs (``checkpoint["key"]`` for trainable methods), and
    the ticket of its training (None: the method does not train, or ``--checkpoint`` gave the
    weights)."""

    seed: int
    trainer: TrainerOptions
    method: ResolvedMethod
    plan: RunPlan
    checkpoint: dict[str, Any]
    variant: Variant
    ticket: TrainingTicket | None = None


def resolve_request(req: EvalRequest, settings: Settings) -> Resolved:
    """Resolve and check the names and sizes of ``req``, before any work."""
    registry = get_registry()
    method = resolve_method(registry, req.method, settings, req.method_opts)
    dataset = resolve_dataset(registry, req.dataset, settings, req.data_root, req.dataset_opts)
    splits = _check_splits(dataset, req.splits)
    if req.protocol.context in ("crop", "depth") and not dataset.has_ground_truth:
        raise ShapebenchError(
            f"{req.protocol.context} contexts are cut from the ground truth, and dataset "
            f"{dataset.name!r} has none",
            "use --protocol sparse: its contexts are drawn from the scans themselves",
        )
    if req.protocol.context_normals and not dataset.has_normals:
        raise ShapebenchError(
            f"dataset {dataset.name!r} has points without normals: --context-normals cannot be "
            "given",
            "drop --context-normals",
        )
    contexts = validate_contexts(req.contexts)
    # Crop and depth contexts come from the ground-truth points: checked per object before any
    # cell.
    bound = dataset.max_context_size() if req.protocol.context == "sparse" else None
    if bound is not None and max(contexts) > bound:
        raise ShapebenchError(
            f"context size {max(contexts)} is larger than the {bound} surface points that dataset "
            f"{dataset.name!r} samples per object",
            "use smaller context sizes, or sample more surface points (-D surface_candidates=...)",
        )
    metrics = resolve_metrics(registry, req.metrics, dataset)
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
    return Resolved(method, dataset, splits, contexts, metrics, primary)


def seed_plans(
    req: EvalRequest,
    resolved: Resolved,
    settings: Settings,
    trainer_for_seed: Callable[[int], TrainerOptions],
) -> list[SeedPlan]:
    """The plan of each seed of ``req``: what :func:`evaluate` runs, and what a cluster launcher
    looks at to decide which cells and trainings are missing (:mod:`shapebench.sweeps.plan`)."""
    method, dataset = resolved.method, resolved.dataset
    # Read (hashed) once: the same file serves every seed and the row.
    given = given_checkpoint(req.checkpoint) if req.checkpoint else None
    out = []
    for seed in req.seeds:
        trainer = trainer_for_seed(seed)
        # The seed's training, computed once here: its key, folder and shipped reference serve
        # the cells' keys, the row and ensure_checkpoint alike.
        ticket = None
        checkpoint: dict[str, Any]
        if not method.cls.trains:
            seed_method, checkpoint = method, {}
        elif given is not None:  # the given file's digest stands for the checkpoint key
            seed_method, checkpoint = apply_trainer(method, trainer), {"key": given.digest}
        else:
            ticket = training_ticket(method, dataset, trainer, settings, req.retrain)
            seed_method, checkpoint = ticket.method, ticket.cell_checkpoint()
        variant = _variant(seed_method, dataset, req, settings, ticket, given)
        plan = RunPlan(
            seed_method,
            dataset,
            resolved.splits,
            resolved.contexts,
            [seed],
            resolved.metrics,
            req.force,
            req.quiet,
            checkpoint,
            req.protocol,
            variant,
        )
        out.append(SeedPlan(seed, trainer, seed_method, plan, checkpoint, variant, ticket))
    return out


def evaluate(
    req: EvalRequest,
    settings: Settings,
    trainer_for_seed: Callable[[int], TrainerOptions],
    tracker: Tracker | None = None,
) -> EvalOutcome:
    resolved = resolve_request(req, settings)
    tracker = tracker or Tracker(settings)  # an unreachable server fails here, before any work
    runner = Runner(tracker)
    cells: list[CellResult] = []
    variant = None
    weights_seconds: list[float] = []
    for sp in seed_plans(req, resolved, settings, trainer_for_seed):
        variant = sp.variant
        make = _method_factory(sp, req, settings, weights_seconds)
        cells += runner.run(sp.plan, make)
    return EvalOutcome(
        resolved.method, resolved.dataset, resolved.primary, cells, variant, sum(weights_seconds)
    )


def _variant(
    method: ResolvedMethod,
    dataset: Dataset,
    req: EvalRequest,
    settings: Settings,
    ticket: TrainingTicket | None = None,
    given: GivenCheckpoint | None = None,
) -> Variant:
    """The leaderboard row of this run (see :mod:`shapebench.registry.variant`); ``ticket``: the
    seed's training (None: no training of this process gives the weights); ``given``: the
    checkpoint file of ``run --checkpoint``."""
    training_overrides: dict[str, Any] = {}
    training = None
    if ticket is not None:
        training = {k: v for k, v in ticket.identity.items() if k != "seed"}
        profile = profile_trainer(settings, ticket.seed)
        # The row's label shows what differs from the profile's trainer; with that very trainer
        # (no command-line override), the baseline is the ticket's own identity.
        base = ticket.identity if profile == ticket.trainer else training_identity(method, profile)
        shown = {k for k in ("epochs", "steps") if hasattr(method.options, k)}
        training_overrides = {  # the budget shows as the method's own option when it has one
            k: v for k, v in training.items() if k not in shown and base.get(k) != v
        }
        # The training data is part of the row (its fingerprint is in the key); a changed
        # training scale (-D train_per_category=20) shows in the label too, so that the rows of
        # a data-scaling sweep read apart.
        training_overrides.update(_training_data_overrides(dataset, settings))
    return make_variant(
        method.name,
        method.config(),
        method.overrides(),
        req.protocol,
        settings.profile_name,
        training=training,
        training_overrides=training_overrides,
        train_data=dataset.training_fingerprint() if training is not None else None,
        checkpoint_file=given.digest if given else None,
        checkpoint_name=given.name if given else None,
        label=req.label,
        weights=ticket.row_weights if ticket is not None else None,
    )


def _training_data_overrides(dataset: Dataset, settings: Settings) -> dict[str, Any]:
    """The dataset's training-only options (``training_only`` in their metadata) that differ
    from the profile's values: what a training saw beyond the evaluation data."""
    from dataclasses import fields

    profile = plugin_overrides("dataset", dataset.name, settings.profile)
    defaults = opts.build(type(dataset.options), profile, f"dataset {dataset.name!r}")
    return {
        f.name: getattr(dataset.options, f.name)
        for f in fields(dataset.options)
        if f.metadata.get("training_only")
        and getattr(dataset.options, f.name) != getattr(defaults, f.name)
    }


def _method_factory(
    sp: SeedPlan,
    req: EvalRequest,
    settings: Settings,
    weights_seconds: list[float],
) -> Callable[[], Method]:
    """The runner's method factory for seed plan ``sp``; the wall time of each
    :func:`ensure_checkpoint` of its ticket (a training, or a reference install) is appended to
    ``weights_seconds``."""
    method, ticket, checkpoint = sp.method, sp.ticket, sp.checkpoint

    def make() -> Method:
        instance = method.instantiate()
        if method.cls.trains:
            if ticket is None:  # --checkpoint
                path = req.checkpoint
            else:
                start = time.perf_counter()
                record = ensure_checkpoint(
                    ticket,
                    settings,
                    Path(req.data_root) if req.data_root else None,
                    req.quiet,
                )
                weights_seconds.append(time.perf_counter() - start)
                path = record["path"]
                if record.get("run_id"):
                    checkpoint["run_id"] = record["run_id"]
            instance.load_checkpoint(Path(path))
        return instance

    return make
