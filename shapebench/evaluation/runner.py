"""Evaluate one method on one dataset: every split, context size and seed is a *cell*.

For each cell the runner draws the (stored) contexts, asks the method for completions, scores
them with every metric, and logs one MLflow child run with the per-object table as an artifact.
A failure of one object (unreadable mesh, NaN output, an exception in the method) is recorded in
that table and counted; the other objects go on.
"""

from __future__ import annotations

import dataclasses
import math
import sys
import tempfile
import time
from collections import OrderedDict
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from shapebench import __version__
from shapebench.api.contexts import CONTEXTS_VERSION, ContextStore, contexts_digest
from shapebench.api.dataset import Dataset, ObjectLoadError
from shapebench.api.errors import ShapebenchError
from shapebench.api.method import Method
from shapebench.api.metric import Metric, NotApplicable
from shapebench.api.protocol import Protocol
from shapebench.api.types import Completion, Context, GroundTruthArray, ObjectData, ObjectRef
from shapebench.hashing import stable_hash
from shapebench.registry.resolve import ResolvedMethod
from shapebench.registry.variant import Variant
from shapebench.store import presentation
from shapebench.store.failures import store_failure
from shapebench.store.provenance import git_commit
from shapebench.store.records import CellRecord
from shapebench.store.tracking import Tracker, experiment_name, flatten

#: Chart colors of the method variants in the MLflow UI (matplotlib's tab10).
EXAMPLE_PLYS = 3  # pictured objects per cell (shapebench.evaluation.pictures.PICTURES_PER_CELL)
#: Distinct failure reasons printed per cell: enough that a folder with a few broken files names
#: every one of them, few enough that a dataset failing object by object stays readable.
TOP_REASONS = 10
#: Per-object column prefix holding the error of a metric that raised on that object.
METRIC_ERROR = "metric_error."
#: Per-object column prefix holding why a metric does not apply to that object (the metric
#: raised :class:`~shapebench.api.metric.NotApplicable`): not an error, and no value.
NOT_APPLICABLE = "not_applicable."


def _traceback(exc: BaseException) -> str:
    import traceback

    return "".join(traceback.format_exception(exc)).strip()


@dataclass
class CellResult:
    split: str
    context_size: int
    seed: int
    run_id: str
    skipped: bool
    metrics: dict[str, float]
    experiment_id: str
    #: The most common failure reasons of this cell with their counts (new cells only).
    reasons: list[tuple[str, int]] = field(default_factory=list)
    #: Where the per-object table is (an artifact URI).
    table_uri: str = ""
    #: The traceback of the first object behind each reason (for ``--debug``).
    tracebacks: dict[str, str] = field(default_factory=dict)
    #: Metric name -> the card its values follow (:meth:`MetricCard.as_tag`).
    cards: dict[str, str] = field(default_factory=dict)
    #: (metric, reason, objects) for each metric that did not apply to some objects (new cells).
    not_applicable: list[tuple[str, str, int]] = field(default_factory=list)

    def scale(self, metric: str) -> float:
        """The factor ``metric``'s values are shown with (its card's), 1 when unknown."""
        from shapebench.api.metric import MetricCard

        try:
            return MetricCard.from_tag(self.cards[metric]).scale
        except (KeyError, ValueError):
            return 1.0

    @property
    def n_objects(self) -> int:
        return int(self.metrics.get("n_objects", 0))

    @property
    def n_ok(self) -> int:
        return self.n_objects - int(self.metrics.get("failures", 0))


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


def _cached(split: str, size: int, seed: int, done: Any, exp_id: str, cfg: dict) -> CellResult:
    """The result of a cell found finished (``done``, its run) rather than computed."""
    return CellResult(
        split, size, seed, done.run_id, True, done.metrics, exp_id, cards=cfg["metrics"]
    )


def failure_reasons(table: pd.DataFrame, top: int = TOP_REASONS) -> list[tuple[str, int]]:
    """The most common errors of a per-object table (failed objects, and metrics that raised
    on an object, as ``metric NAME: ...``), with their counts."""
    return [(reason, n) for reason, n, _ in distinct_errors(table, top)]


def distinct_errors(table: pd.DataFrame, top: int = TOP_REASONS) -> list[tuple[str, int, str]]:
    """(first line of the error, count, the first such object's traceback), most common first."""
    errors: list[tuple[str, str]] = []
    tracebacks = table["traceback"] if "traceback" in table else pd.Series("", index=table.index)
    if "status" in table and "error" in table:
        for i in table.index[table["status"] != "ok"]:
            errors.append((_first_line(table.at[i, "error"]), tracebacks.get(i, "")))
    for col in [c for c in table.columns if str(c).startswith(METRIC_ERROR)]:
        name = str(col)[len(METRIC_ERROR) :]
        for i in table.index[table[col].notna() & (table[col] != "")]:
            errors.append(
                (f"metric {name}: {_first_line(table.at[i, col])}", tracebacks.get(i, ""))
            )
    counts: dict[str, list] = {}
    for reason, tb in errors:
        entry = counts.setdefault(reason, [0, tb if isinstance(tb, str) else ""])
        entry[0] += 1
    ranked = sorted(counts.items(), key=lambda kv: -kv[1][0])[:top]
    return [(reason, n, tb) for reason, (n, tb) in ranked]


def _first_line(error: object) -> str:
    text = str(error) if isinstance(error, str) and error else "unknown"
    return text.splitlines()[0][:200]


def not_applicable(table: pd.DataFrame, metric: str) -> pd.Series:
    """Per row of a per-object table, whether ``metric`` did not apply to that object."""
    col = f"{NOT_APPLICABLE}{metric}"
    if col not in table:
        return pd.Series(False, index=table.index)
    return table[col].notna() & (table[col].astype(str) != "")


def not_applicable_reasons(table: pd.DataFrame) -> list[tuple[str, str, int]]:
    """(metric, reason, objects) for every metric that did not apply to some object."""
    out = []
    for col in [c for c in table.columns if str(c).startswith(NOT_APPLICABLE)]:
        reasons = table[col][not_applicable(table, str(col)[len(NOT_APPLICABLE) :])]
        for reason, n in reasons.astype(str).value_counts().items():
            out.append((str(col)[len(NOT_APPLICABLE) :], str(reason), int(n)))
    return out


def metric_errors(table: pd.DataFrame) -> list[str]:
    """The metrics that raised on some object of this per-object table."""
    return sorted(
        str(c)[len(METRIC_ERROR) :]
        for c in table.columns
        if str(c).startswith(METRIC_ERROR) and table[c].notna().any() and (table[c] != "").any()
    )


class ObjectCache:
    """Keeps recently loaded objects in memory across the cells of a run."""

    def __init__(
        self, dataset: Dataset, capacity: int = 64, need: frozenset[GroundTruthArray] = frozenset()
    ) -> None:
        self.dataset = dataset
        self.capacity = capacity
        #: Ground-truth arrays the run's metrics read, among those the dataset can build.
        self.need = need & dataset.provides_ground_truth
        self._items: OrderedDict[str, ObjectData | ObjectLoadError] = OrderedDict()

    def get(self, ref: ObjectRef) -> ObjectData:
        item = self._items.get(ref.id)
        if item is None:
            try:
                item = self.dataset.load(ref, self.need) if self.need else self.dataset.load(ref)
            except ObjectLoadError as exc:
                item = exc
            self._items[ref.id] = item
            if len(self._items) > self.capacity:
                self._items.popitem(last=False)
        else:
            self._items.move_to_end(ref.id)
        if isinstance(item, ObjectLoadError):
            raise item
        return item


def _progress(total: int, desc: str, quiet: bool):
    from shapebench.progress import progress_bar

    return progress_bar(total, desc, quiet)


def check_context_sizes(
    refs: list[ObjectRef],
    cache: ObjectCache,
    sizes: list[int],
    quiet: bool,
    label: str,
    protocol: Protocol,
    store: ContextStore,
) -> None:
    """Load (and if needed preprocess) every object; refuse sizes some object cannot provide
    (visible surface points; under ``--protocol crop`` or ``depth`` the partial cloud the store
    samples contexts from: what a crop leaves, what the camera sees)."""
    partial = protocol.context in ("crop", "depth")
    fewest: tuple[int, str] | None = None
    with _progress(len(refs), f"preparing {label}", quiet) as bar:
        for ref in refs:
            try:
                data = cache.get(ref)
                if partial:
                    n = len(store.partial_points(data, protocol))
                else:
                    n = len(data.surface_points)
                if fewest is None or n < fewest[0]:
                    fewest = (n, ref.id)
            except ObjectLoadError:
                pass  # counted as a failure in every cell
            bar.update()
    if fewest is None or max(sizes) <= fewest[0]:
        return
    n, obj = fewest
    if not partial:
        raise ShapebenchError(
            f"context size {max(sizes)} is larger than the {n} visible surface points of "
            f"object {obj!r} ({label})",
            f"use context sizes up to {n}, or sample more surface points "
            "(-D surface_candidates=...)",
        )
    if protocol.context == "depth":
        what = f"object {obj!r} shows its depth camera"
    else:
        what = f"a crop of {protocol.crop_fraction:g} leaves of object {obj!r}"
    raise ShapebenchError(
        f"context size {max(sizes)} is larger than the {n} ground-truth points {what} ({label})",
        f"use context sizes up to {n}, or more ground-truth points (-D gt_points=...)",
    )


def _valid_points(completion: Any) -> str | None:
    """Why a completion cannot be scored, or None if it can."""
    if not isinstance(completion, Completion):
        return f"complete() returned {type(completion).__name__}, not a Completion"
    pts = np.asarray(completion.points)
    if pts.ndim != 2 or pts.shape[1] != 3:
        return f"completion points have shape {pts.shape}, expected (n, 3)"
    if len(pts) == 0:
        return "completion has no points"
    if not np.all(np.isfinite(pts)):
        return f"completion has {int((~np.isfinite(pts)).any(axis=1).sum())} NaN/inf points"
    return None


def scaled(data: ObjectData, ctx: Context, completion: Completion, factor: float):
    """Copies of what metrics read, with every coordinate multiplied by ``factor`` (the
    protocol's evaluation frame); the originals, and the caches built on them, are untouched."""
    from dataclasses import replace

    if factor == 1.0:
        return data, ctx, completion
    sdata = replace(
        data,
        gt_points=data.gt_points * factor,
        surface_points=data.surface_points * factor,
        extra={k: _scaled_extra(k, v, factor) for k, v in data.extra.items()},
        cache={},
    )
    sctx = replace(ctx, points=ctx.points * factor)
    mesh = completion.mesh
    if mesh is not None:
        mesh = mesh.copy()
        mesh.apply_scale(factor)
    scomp = Completion(
        points=(completion.points * factor).astype(np.float32),
        mesh=mesh,
        samples=[s * factor for s in completion.samples] if completion.samples else None,
        info=completion.info,
    )
    return sdata, sctx, scomp


def _scaled_extra(name: str, array: np.ndarray, factor: float) -> np.ndarray:
    """A ground-truth array in the evaluation frame: its first three columns are coordinates;
    normals and occupancy labels do not scale."""
    if name not in {k.value for k in GroundTruthArray}:
        return array
    out = np.array(array, copy=True)
    out[:, :3] *= factor
    return out


def score(
    outcome: Completion | Exception,
    data: ObjectData,
    ctx: Context,
    metrics: list[Metric],
    frame_scale: float = 1.0,
) -> tuple[dict[str, Any], Completion | None]:
    """The per-object row for one method output: scores (in the protocol's frame, scaled by
    ``frame_scale``), or the reason it failed."""
    row: dict[str, Any] = {"status": "ok", "error": ""}
    if isinstance(outcome, Exception):  # the method's failure must not lose the other objects
        row.update(
            status="failed",
            error=f"{type(outcome).__name__}: {outcome}",
            traceback=_traceback(outcome),
        )
        return row, None
    problem = _valid_points(outcome)
    if problem:
        row.update(status="failed", error=problem)
        return row, None
    outcome.points = np.asarray(outcome.points, dtype=np.float32)
    row["n_points"] = len(outcome.points)
    sdata, sctx, scomp = scaled(data, ctx, outcome, frame_scale)
    for metric in metrics:
        # A metric that crashes costs its own value only: the other metrics of the object stand,
        # and the object's status (the method's success) is unchanged.
        try:
            value = float(metric.compute(scomp, sdata, sctx))
            if not math.isfinite(value):
                raise ValueError(f"the metric returned {value}")
        except NotApplicable as exc:  # no value, and no error: the reason is recorded
            row[metric.name] = math.nan
            row[f"{NOT_APPLICABLE}{metric.name}"] = str(exc) or "not applicable"
            continue
        except Exception as exc:
            row[metric.name] = math.nan
            row[f"{METRIC_ERROR}{metric.name}"] = f"{type(exc).__name__}: {exc}"
            row.setdefault("traceback", _traceback(exc))
            continue
        row[metric.name] = value
    for key, value in (outcome.info or {}).items():
        row[f"info.{key}"] = value
    if outcome.samples:
        spread = posterior_spread(outcome.points, outcome.samples)
        outcome.cache["spread"] = spread
        row["posterior_spread"] = float(spread.mean()) * frame_scale
    return row, outcome


def posterior_spread(points: np.ndarray, samples: list[np.ndarray]) -> np.ndarray:
    """Per point of the completion, the RMS over posterior samples of the distance to the nearest
    point of each sample: how uncertain the completion is there."""
    from shapebench.geometry.nearest import nearest_distances

    d = np.stack([nearest_distances(points, s) for s in samples if len(s)])
    return np.sqrt((d**2).mean(axis=0)).astype(np.float32)


@contextmanager
def subnormals_flushed() -> Iterator[None]:
    """Subnormal floats flushed to zero in torch's CPU arithmetic on this thread, for the span of
    a completion; the setting it found is restored after.

    Softplus(beta=100), the activation of IGR's, MSC's and MSC-hier's decoders, computes
    ``exp(100 x)``, which is subnormal for x below about -0.87: everywhere far from the surface,
    where meshing evaluates the field most. x86 CPUs compute on subnormals many times slower.
    Flushed, a one-thread completion is 2.1x (IGR) to 3.2x (MSC w/o opt) faster, with bitwise the
    same points (benchmarks/bench_completion.py; benchmarks/README.md). The flag is per thread:
    torch's own worker threads keep subnormals, so the gain is a one-thread worker's (``sweep
    -j 2`` on 2 cores), hardly a two-thread process's (1.02-1.07x). Nothing here imports torch:
    a method that uses it has imported it by now. Training is left as it is (its weights are what
    keys name).
    """
    torch = sys.modules.get("torch")
    if torch is None:
        yield
        return
    flushed = bool((torch.tensor([1e-39]) * 1.0).item() == 0.0)  # no getter for the flag
    torch.set_flush_denormal(True)
    try:
        yield
    finally:
        torch.set_flush_denormal(flushed)


def complete_chunk(method: Method, contexts: list[Context], n_points: int):
    """The method's outputs for a chunk of contexts, and the seconds spent per object."""
    start = time.perf_counter()
    try:
        with subnormals_flushed():
            outputs = method.complete_batch(contexts, n_points)
        if len(outputs) != len(contexts):
            raise RuntimeError(
                f"complete_batch returned {len(outputs)} results for {len(contexts)} contexts"
            )
    except Exception as exc:  # a crash of the whole batch fails these objects only
        outputs = [exc] * len(contexts)
    return outputs, (time.perf_counter() - start) / max(len(contexts), 1)


def summarize(table: pd.DataFrame, metrics: list[Metric]) -> dict[str, float]:
    ok = table[table["status"] == "ok"]
    out: dict[str, float] = {
        "n_objects": float(len(table)),
        "failures": float(len(table) - len(ok)),
    }
    for m in metrics:
        values = ok[m.name].to_numpy(dtype=float) if m.name in ok else np.array([])
        values = values[np.isfinite(values)]  # NaN: the metric raised or did not apply
        na = not_applicable(ok, m.name)
        if na.any():
            out[f"{m.name}.not_applicable"] = float(na.sum())
        if f"{METRIC_ERROR}{m.name}" in ok:
            out[f"{m.name}.errors"] = float(len(ok) - len(values) - int(na.sum()))
        if len(values):
            out[f"{m.name}.mean"] = float(values.mean())
            out[f"{m.name}.std"] = float(values.std(ddof=1)) if len(values) > 1 else 0.0
            out[f"{m.name}.median"] = float(np.median(values))
    out["seconds_per_object"] = float(table["seconds"].mean()) if len(table) else 0.0
    return out


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

    def finished(self, plan: RunPlan, exp_id: str, key: str):
        """The finished run of this cell, unless recomputing on purpose or one of the plan's
        metrics raised in it (it is computed again, for every metric, once that is fixed)."""
        if plan.force:
            return None
        done = self.tracker.find_cell(exp_id, key)
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
        record = self._record(plan, split, size, seed, key, cfg)
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
            label = f"{plan.method.name} {plan.dataset.name}/{split} k={size}"
            chunk = max(1, int(getattr(method, "batch_size", 1)))
            with _progress(len(refs), label, plan.quiet) as bar:
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
                        bar.update()
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
            self._log_artifacts(
                run_id,
                table,
                contexts,
                examples,
                truths,
                f"{self._label(plan)} k={size}",
                spare[: max(EXAMPLE_PLYS - len(examples), 0)],
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

    def _record(
        self, plan: RunPlan, split: str, size: int, seed: int, key: str, cfg: dict
    ) -> CellRecord:
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

    def _log_artifacts(
        self, run_id, table, contexts, examples, truths=None, title="", spare=()
    ) -> None:
        """The per-object table, the contexts, and for the pictured objects their completed
        clouds (``completions/*.ply``) and pictures (``pictures/<object>.png``, drawn from the
        arrays kept beside it as ``.npz``: context, completion, ground truth, spread); when
        pictured objects failed, ``spare`` successes fill the ``.ply`` examples up."""
        import trimesh

        from shapebench.evaluation.pictures import file_stem, picture_arrays, picture_png

        with tempfile.TemporaryDirectory() as tmp:
            tmpdir = Path(tmp)
            table.to_csv(tmpdir / "per_object.csv", index=False)
            if contexts:
                arrays = {
                    "objects": np.array([c.ref.id for c in contexts]),
                    "points": np.stack([c.points for c in contexts]),
                }
                if all(c.normals is not None for c in contexts):  # given to the method
                    arrays["normals"] = np.stack([c.normals for c in contexts])
                np.savez_compressed(tmpdir / "contexts.npz", **arrays)
            self.tracker.log_artifacts(run_id, tmpdir)
            if examples:
                pic_dir = tmpdir / "pictures"
                pic_dir.mkdir()
                start = time.perf_counter()
                try:
                    for ctx, completion in examples:
                        obj = ctx.ref.id
                        arrays = picture_arrays(
                            ctx.points,
                            completion.points,
                            (truths or {}).get(obj),
                            completion.cache.get("spread"),
                        )
                        np.savez_compressed(pic_dir / f"{file_stem(obj)}.npz", **arrays)
                        png = picture_png(arrays, f"{title}: {obj}" if title else obj)
                        (pic_dir / f"{file_stem(obj)}.png").write_bytes(png)
                except Exception as exc:  # a picture is a view of the results, not one of them
                    self.echo(
                        f"  warning: could not draw the pictures of this cell "
                        f"({type(exc).__name__}: {exc})"
                    )
                self.tracker.log_artifacts(run_id, pic_dir, "pictures")
                seconds = time.perf_counter() - start
                self.tracker.log_metrics(run_id, {"pictures_seconds": seconds})
            if examples or spare:
                ex_dir = tmpdir / "completions"
                ex_dir.mkdir()
                for ctx, completion in [*examples, *spare]:
                    obj = ctx.ref.id
                    stem = obj.replace("/", "__")
                    trimesh.PointCloud(completion.points).export(ex_dir / f"{stem}.ply")
                    for j, sample in enumerate(completion.samples or []):
                        trimesh.PointCloud(sample).export(ex_dir / f"{stem}.sample{j}.ply")
                    if "spread" in completion.cache:
                        np.savez_compressed(
                            ex_dir / f"{stem}.spread.npz",
                            points=completion.points,
                            spread=completion.cache["spread"],
                        )
                self.tracker.log_artifacts(run_id, ex_dir, "completions")
