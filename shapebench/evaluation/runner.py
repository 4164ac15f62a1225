"""Evaluate one method on one dataset: every split, context size and seed is a *cell*.

For each cell the runner draws the (stored) contexts, asks the method for completions, scores
them with every metric, and logs one MLflow child run with the per-object table as an artifact;
the new cells of a split hang under one parent run. A failure of one object (unreadable mesh, NaN
output, an exception in the method) is recorded in that table and counted; the other objects go
on. What a cell is and its key: :mod:`~shapebench.evaluation.plan`; scoring:
:mod:`~shapebench.evaluation.scoring`; the failure reasons: :mod:`~shapebench.evaluation.failures`.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
import pandas as pd

from shapebench.api.contexts import ContextStore, contexts_digest
from shapebench.api.dataset import ObjectLoadError
from shapebench.api.method import Method
from shapebench.api.types import ObjectRef
from shapebench.evaluation.artifacts import EXAMPLE_PLYS, log_cell_artifacts
from shapebench.evaluation.completion import complete_chunk
from shapebench.evaluation.failures import distinct_errors, metric_errors, not_applicable_reasons
from shapebench.evaluation.objects import ObjectCache, check_context_sizes
from shapebench.evaluation.plan import RunPlan, cell_record, planned_cells
from shapebench.evaluation.results import CellResult
from shapebench.evaluation.scoring import score, summarize
from shapebench.hashing import stable_hash
from shapebench.progress import progress_bar
from shapebench.store import presentation
from shapebench.store.failures import store_failure
from shapebench.store.tracking import Tracker, experiment_name, flatten


def _cached(split: str, size: int, seed: int, done: Any, exp_id: str, cfg: dict) -> CellResult:
    """The result of a cell found finished (``done``, its run) rather than computed."""
    return CellResult(
        split, size, seed, done.run_id, True, done.metrics, exp_id, cards=cfg["metrics"]
    )


def _judging_metric(plan: RunPlan) -> Any:
    """The metric that names a cell's worst object: the dataset's default, else the first."""
    by_name = {m.name: m for m in plan.metrics}
    return by_name.get(plan.dataset.default_metric) or (plan.metrics[0] if plan.metrics else None)


def _badness(row: dict[str, Any], metric: Any) -> float | None:
    """How bad an object's score is by ``metric`` (larger: worse), None without a value."""
    if metric is None:
        return None
    value = row.get(metric.name)
    if value is None or not np.isfinite(value):
        return None
    return -float(value) if metric.higher_is_better else float(value)


@dataclass(frozen=True)
class SplitWork:
    """One split of a plan being computed: what every cell of it shares."""

    plan: RunPlan
    method: Method
    split: str
    refs: list[ObjectRef]
    cache: ObjectCache
    store: ContextStore
    exp_id: str


class Runner:
    """Runs the cells of a :class:`RunPlan`, logging each to MLflow."""

    def __init__(self, tracker: Tracker, echo: Callable[[str], None] = print) -> None:
        self.tracker = tracker
        self.echo = echo

    def run(self, plan: RunPlan, make_method: Callable[[], Method]) -> list[CellResult]:
        """Run the plan's pending cells; ``make_method`` is called only if some cell is pending
        (for trainable methods it trains or loads the checkpoint). A full disk or a tracking
        server that stops answering is raised as one :class:`StoreFailure` saying so."""
        try:
            return self._run_plan(plan, make_method)
        except Exception as exc:
            failure = store_failure(exc, self.tracker.uri)
            if failure is None or failure is exc:
                raise
            raise failure from exc

    def _run_plan(self, plan: RunPlan, make_method: Callable[[], Method]) -> list[CellResult]:
        method: Method | None = None
        results: list[CellResult] = []
        need = frozenset().union(*(getattr(m, "needs", frozenset()) for m in plan.metrics))
        cache = ObjectCache(plan.dataset, need=need)
        store = ContextStore(plan.dataset.cache_root, plan.dataset.data_fingerprint())
        for split in plan.splits:
            refs = plan.dataset.objects(split)
            self._announce(plan, split, refs)
            if not refs:
                continue
            exp_id = self.tracker.experiment_id(experiment_name(plan.dataset.name, split))
            pending = []
            for seed, size, cfg, key in planned_cells(plan, split):
                done = self.finished(plan, exp_id, key)
                if done is None:
                    pending.append((seed, size, cfg, key))
                    continue
                self._relabel(done.run_id, plan)
                results.append(_cached(split, size, seed, done, exp_id, cfg))
            if not pending:
                self._close_stale_parents(plan, split, exp_id)
                continue
            cached = [r for r in results if r.split == split and r.skipped]
            check_context_sizes(
                refs,
                cache,
                [p[1] for p in pending],
                plan.quiet,
                f"{plan.dataset.name}/{split}",
                plan.protocol,
                store,
            )
            if method is None:
                method = make_method()
            work = SplitWork(plan, method, split, refs, cache, store, exp_id)
            results += self._run_pending(work, pending, cached)
        return results

    def finished(self, plan: RunPlan, exp_id: str, key: str, index: dict[str, Any] | None = None):
        """The finished run of this cell, unless recomputing on purpose or one of the plan's
        metrics raised in it (it is computed again, for every metric, once that is fixed).
        ``index``: the experiment's finished cells by key, read once
        (:meth:`~shapebench.store.tracking.Tracker.finished_cell_index`), for many lookups."""
        if plan.force:
            return None
        done = index.get(key) if index is not None else self.tracker.find_cell(exp_id, key)
        if done is not None and done.metric_errors & {m.name for m in plan.metrics}:
            return None
        return done

    def _run_pending(self, work: SplitWork, pending: list, cached=()) -> list[CellResult]:
        """Compute the pending cells of a split, each under a claim (a lock per cell key): a cell
        another process is computing is left to it and its result read back at the end; a claim
        whose process died is free again (the kernel drops its lock). The parent run gets the
        metrics of every cell of the split, ``cached`` ones included
        (:func:`shapebench.store.presentation.finish_parent`)."""
        from shapebench.store.locks import try_lock, wait_lock
        from shapebench.store.tracking import cell_lock_path

        plan, split, exp_id = work.plan, work.split, work.exp_id
        parent: str | None = None
        parent_lock = None
        results: list[CellResult] = []
        deferred = []

        def start_parent() -> str:
            nonlocal parent, parent_lock
            if parent is None:
                parent, parent_lock = self._start_parent(plan, split, exp_id)
            return parent

        def compute(seed, size, cfg, key) -> None:
            # Finished by another process since we looked (unless recomputing on purpose).
            done = self.finished(plan, exp_id, key)
            if done is not None:
                results.append(_cached(split, size, seed, done, exp_id, cfg))
                return
            results.append(self._run_cell(work, start_parent(), seed, size, cfg, key))
            self._describe_cell(plan, split, results[-1])

        settings = self.tracker.settings
        try:
            for seed, size, cfg, key in pending:
                lock = try_lock(cell_lock_path(settings, key))
                if lock is None:  # another process is computing it: come back at the end
                    deferred.append((seed, size, cfg, key))
                    continue
                with lock:
                    compute(seed, size, cfg, key)
            for seed, size, cfg, key in deferred:

                def waiting(holder: str, size: int = size) -> None:
                    self.echo(f"  k={size}: waiting for {holder}, which is computing this cell")

                with wait_lock(cell_lock_path(settings, key), waiting):
                    compute(seed, size, cfg, key)
        except BaseException as exc:
            if parent is not None:
                self.tracker.end_after(parent, exc)
            raise
        finally:
            if parent_lock is not None:
                parent_lock.release()
        if parent is not None:
            cells = [*cached, *results]
            presentation.finish_parent(self.tracker, parent, self._heading(plan, split), cells)
            self.tracker.end(parent)
        return sorted(results, key=lambda r: (r.seed, r.context_size))

    @staticmethod
    def _parent_key(plan: RunPlan, split: str) -> str:
        return stable_hash(
            {
                "method": plan.method.config(),
                "variant": plan.variant.key if plan.variant else None,
                "dataset": plan.dataset.fingerprint(),
                "split": split,
            }
        )

    def _close_stale_parents(self, plan: RunPlan, split: str, exp_id: str) -> None:
        """Mark KILLED the parents of ``split`` left RUNNING by a process killed after its last
        cell, when nobody holds their lock. A run that finds every cell done starts no parent
        of its own, so this is the only moment it can close them."""
        from shapebench.store.locks import try_lock
        from shapebench.store.tracking import cell_lock_path

        parent_key = self._parent_key(plan, split)
        lock = try_lock(cell_lock_path(self.tracker.settings, "parent-" + parent_key))
        if lock is not None:
            with lock:
                presentation.abandon_stale_parents(self.tracker, exp_id, parent_key)

    def _start_parent(self, plan: RunPlan, split: str, exp_id: str):
        """The parent run of this plan's new cells on ``split``, and the lock that shows it is
        alive: RUNNING parents of the same key are marked KILLED only when nobody holds it."""
        from shapebench.store.locks import try_lock
        from shapebench.store.tracking import cell_lock_path

        parent_key = self._parent_key(plan, split)
        lock = try_lock(cell_lock_path(self.tracker.settings, "parent-" + parent_key))
        if lock is not None:
            presentation.abandon_stale_parents(self.tracker, exp_id, parent_key)
        metric = self._primary(plan)
        columns = [f"{metric}.mean", f"{metric}.std", "failures", "seconds_per_object"]
        heading = self._heading(plan, split)
        parent = presentation.start_parent(self.tracker, exp_id, heading, parent_key, columns)
        self._log_dataset(plan, split, parent)
        return parent, lock

    def _heading(self, plan: RunPlan, split: str) -> presentation.RunHeading:
        """How the runs of ``plan`` on ``split`` are named and described in the UI."""
        return presentation.RunHeading(
            label=self._label(plan),
            method=plan.method.name,
            dataset=plan.dataset.name,
            split=split,
            variant_key=plan.variant.key if plan.variant else "",
            frame=plan.protocol.frame,
            metric=self._primary(plan),
            training_run_id=str(plan.checkpoint.get("run_id") or ""),
            force=plan.force,
        )

    @staticmethod
    def _primary(plan: RunPlan) -> str:
        names = [m.name for m in plan.metrics]
        default = getattr(plan.dataset, "default_metric", "")
        return default if default in names else (names[0] if names else "")

    def _log_dataset(self, plan: RunPlan, split: str, run_id: str) -> None:
        ds = plan.dataset
        refs = ds.objects(split)
        self.tracker.log_dataset(
            run_id,
            f"{ds.name}/{split}",
            ds.fingerprint(),
            {"dataset": ds.name, "version": ds.version, "data_root": str(ds.data_root or "")},
            {"objects": len(refs), "categories": len({r.category for r in refs})},
            split,
        )

    def _describe_cell(self, plan: RunPlan, split: str, result: CellResult) -> None:
        """The cell's summary as its MLflow note (shown on the run's page), and the evaluated
        objects as its dataset input."""
        if result.skipped:
            return
        presentation.describe_cell(self.tracker, self._heading(plan, split), result)
        self._log_dataset(plan, split, result.run_id)

    def _run_cell(
        self, work: SplitWork, parent: str, seed: int, size: int, cfg: dict, key: str
    ) -> CellResult:
        plan, method, split, refs = work.plan, work.method, work.split, work.refs
        cache, store, exp_id = work.cache, work.store, work.exp_id
        tr = self.tracker
        tr.abandon_stale(exp_id, key)
        record = cell_record(plan, split, size, seed, key, cfg)
        run_id = tr.start_run(
            exp_id,
            self._heading(plan, split).run_name(f"k={size} seed={seed}"),
            record.to_tags(),
            parent,
        )
        try:
            rows, contexts, examples = [], [], []
            # The pictured objects depend on the split's object list only, never on which
            # objects failed: every method's pictures (and .ply files) show the same objects.
            from shapebench.evaluation.pictures import picture_objects

            pictured = set(picture_objects([r.id for r in refs]))
            truths: dict[str, np.ndarray] = {}
            spare: list = []
            # The cell's worst success by the dataset's metric is pictured too, when it is not
            # a fixed one (one completion kept aside): the report shows each row's failures.
            judge = _judging_metric(plan)
            worst: tuple[float, Any, Any, np.ndarray] | None = None
            label = f"{plan.method.name} {plan.dataset.name}/{split} k={size}"
            chunk = max(1, int(getattr(method, "batch_size", 1)))
            with progress_bar(len(refs), label, plan.quiet) as bar:
                for start in range(0, len(refs), chunk):
                    ready = []  # (row, data, ctx) of the objects that could be loaded
                    for ref in refs[start : start + chunk]:
                        row: dict[str, Any] = {"object": ref.id, "category": ref.category}
                        rows.append(row)
                        try:
                            data = cache.get(ref)
                            ctx = store.context(data, size, seed, protocol=plan.protocol)
                            if ref.id in pictured:
                                ctx = dataclasses.replace(ctx, pictured=True)
                        except (ObjectLoadError, ValueError) as exc:
                            row.update(status="failed", error=str(exc), seconds=0.0)
                            bar.update()
                            continue
                        row["gt_points"] = len(data.gt_points)
                        contexts.append(ctx)
                        ready.append((row, data, ctx))
                    if not ready:
                        continue
                    n_points = plan.dataset.points_to_complete(ready[0][1])
                    outputs, seconds = complete_chunk(method, [r[2] for r in ready], n_points)
                    for (row, data, ctx), output in zip(ready, outputs, strict=True):
                        result, completion = score(
                            output, data, ctx, plan.metrics, plan.protocol.scale
                        )
                        row.update(result, seconds=seconds)
                        if completion is not None and ctx.ref.id in pictured:
                            examples.append((ctx, completion))
                            if len(data.gt_points):  # none for real scans: no GT panel
                                truths[ctx.ref.id] = data.gt_points
                        elif completion is not None and len(spare) < EXAMPLE_PLYS:
                            spare.append((ctx, completion))  # .ply only, if pictured ones fail
                        badness = _badness(row, judge) if completion is not None else None
                        if badness is not None and (worst is None or badness > worst[0]):
                            # Kept only while unpictured: a pictured worst needs no extra copy.
                            keep = ctx.ref.id not in pictured
                            worst = (badness, ctx, completion if keep else None, data.gt_points)
                        bar.update()
            if worst is not None and worst[2] is not None:
                _, ctx, completion, gt = worst
                examples.append((ctx, completion))
                if len(gt):
                    truths[ctx.ref.id] = gt
            table = pd.DataFrame(rows)
            summary = summarize(table, plan.metrics)
            # Metrics that raised: the cell is not finished for them, the next run computes it.
            presentation.record_outcome(
                tr,
                run_id,
                contexts_digest(contexts),
                metric_errors(table),
                self._check_gt_points(plan, table),
            )
            tr.log_params(run_id, flatten("", cfg))
            tr.log_metrics(run_id, summary, step=size)
            log_cell_artifacts(
                tr,
                run_id,
                table,
                contexts,
                examples,
                truths,
                f"{self._label(plan)} k={size}",
                spare[: max(EXAMPLE_PLYS - len(examples), 0)],
                self.echo,
            )
        except BaseException as exc:
            tr.end_after(run_id, exc)
            raise
        tr.end(run_id)
        uri = tr.artifact_uri(run_id, "per_object.csv")
        errors = distinct_errors(table)
        return CellResult(
            split,
            size,
            seed,
            run_id,
            False,
            summary,
            exp_id,
            [(r, n) for r, n, _ in errors],
            uri,
            {r: tb for r, _, tb in errors if tb},
            cfg["metrics"],
            not_applicable_reasons(table),
        )

    def _check_gt_points(self, plan: RunPlan, table: pd.DataFrame) -> int:
        """The card promises ``gt_points`` evaluation points per object; a dataset that has
        fewer for some object (a sparse RGB-D fusion) is said so, and the fewest returned, to be
        recorded on the run (:attr:`CellRecord.eval_points_actual`; the real counts are column
        ``gt_points`` of the table); 0 when every object has enough."""
        promised = int(getattr(plan.dataset.options, "gt_points", 0) or 0)
        if not promised or "gt_points" not in table or table["gt_points"].isna().all():
            return 0
        fewest = int(table["gt_points"].min())
        if fewest >= promised:
            return 0
        short = int((table["gt_points"] < promised).sum())
        self.echo(
            f"  warning: {short} object(s) of {plan.dataset.name} have fewer ground-truth "
            f"points than the {promised} the metric card states (fewest: {fewest}); "
            "the real counts are in per_object.csv"
        )
        return fewest

    @staticmethod
    def _label(plan: RunPlan) -> str:
        return plan.variant.label if plan.variant else plan.method.name

    def _relabel(self, run_id: str, plan: RunPlan) -> None:
        """A finished cell reused under a new ``--label`` takes that label (results are equal)."""
        if plan.variant is None:
            return
        presentation.relabel(self.tracker, run_id, plan.variant.label)

    def _announce(self, plan: RunPlan, split: str, refs: list[ObjectRef]) -> None:
        """What is evaluated, and why objects were left out, before any work."""
        ds = plan.dataset
        if not refs:
            self.echo(f"  {ds.name}/{split}: no objects, skipped")
            return
        cats = len({r.category for r in refs})
        line = f"  {ds.name}/{split}: {len(refs)} objects in {cats} categories"
        notes = ds.selection_notes(split)
        self.echo(line + (f" ({'; '.join(notes)})" if notes else ""))
