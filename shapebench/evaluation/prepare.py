"""Preprocess (and cache) every object of some splits ahead of a run, in parallel processes.

``shapebench run`` loads objects lazily, one process, one object at a time; on a large dataset
(ShapeNet at the paper's 200k surface samples) preprocessing dominates, so it pays to fill the
cache first with all cores: ``shapebench prepare``. Nothing here is dataset-specific: it calls
``dataset.load(ref, need)`` for each object, and the dataset caches what it builds, so a second
prepare (or a run) reads the cache and an interrupted prepare resumes where it stopped.

Workers are started with the ``spawn`` method, so the dataset object must pickle (plain options,
paths and listings do) and its class must be importable (any registered plugin's is). Spawned
workers also avoid forking a process that may already hold threads (BLAS, embree, MLflow).
At most ``jobs`` objects are in flight at any time: when a worker dies (killed, out of memory),
only those objects are marked failed, a fresh pool takes over and the others go on.
"""

from __future__ import annotations

import multiprocessing
import pickle
import time
from collections.abc import Iterable, Iterator
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass, field
from pathlib import Path

from shapebench.api.dataset import Dataset, ObjectLoadError
from shapebench.api.errors import ConfigError, ShapebenchError
from shapebench.api.types import TRAIN, ObjectRef, Supervision


@dataclass(frozen=True)
class PrepareFailure:
    ref: ObjectRef
    reason: str


@dataclass
class PrepareReport:
    """What a prepare did: counts, the failed objects with their reasons, and timings.

    ``cached`` counts objects whose arrays were already on disk before this prepare started
    (known for datasets with a ``cache_path(ref)`` method, 0 otherwise). ``seconds_per_object`` is
    the mean time a worker spent per object, ``seconds_per_built_object`` the same over the objects
    that were not cached (what preprocessing costs), ``seconds`` the wall time.
    """

    total: int = 0
    ok: int = 0
    cached: int = 0
    failures: list[PrepareFailure] = field(default_factory=list)
    seconds: float = 0.0
    seconds_per_object: float = 0.0
    seconds_per_built_object: float = 0.0
    per_split: dict[str, int] = field(default_factory=dict)

    @property
    def failed(self) -> int:
        return len(self.failures)

    def summary(self) -> str:
        return (
            f"{self.ok}/{self.total} objects ready ({self.cached} already cached), "
            f"{self.failed} failed; {self.seconds:.1f} s, "
            f"{self.seconds_per_built_object:.2f} s per object built"
        )


def prepare(
    dataset: Dataset,
    splits: list[str],
    need: frozenset[Supervision] = frozenset(),
    jobs: int = 1,
    quiet: bool = False,
    categories: Iterable[str] | None = None,
    shard: tuple[int, int] | None = None,
) -> PrepareReport:
    """Load every object of ``splits`` (optionally only of ``categories``) so it is cached;
    ``shard=(i, n)`` takes every n-th object from the i-th (one task of an array job).

    Failures (an :class:`ObjectLoadError`, or any other exception one object raises) are
    collected with their reasons, never raised; ``KeyboardInterrupt`` stops the workers and is
    re-raised (what finished is cached). ``jobs`` <= 1 runs in this process.
    """
    refs, report = _select(dataset, splits, categories)
    if shard is not None:
        index, count = shard
        refs = refs[index::count]
        report.total = len(refs)
    if jobs > 1 and len(refs) > 1:
        _check_picklable(dataset)
    cached = {r.id for r in refs if _is_cached(dataset, r)}
    report.cached = len(cached)
    start = time.perf_counter()
    busy = built = 0.0
    with _progress(len(refs), f"preparing {dataset.name}", quiet) as bar:
        results = (
            _run_inline(dataset, refs, need)
            if jobs <= 1 or len(refs) <= 1
            else _run_pool(dataset, refs, need, min(jobs, len(refs)))
        )
        for ref, reason, seconds in results:
            busy += seconds
            if ref.id not in cached:
                built += seconds
            if reason is None:
                report.ok += 1
            else:
                report.failures.append(PrepareFailure(ref, reason))
            bar.update(1)
            bar.set_postfix(failed=report.failed, refresh=False)
    report.seconds = time.perf_counter() - start
    report.seconds_per_object = busy / len(refs) if refs else 0.0
    fresh = len(refs) - len(cached)
    report.seconds_per_built_object = built / fresh if fresh else 0.0
    order = {r.id: i for i, r in enumerate(refs)}
    report.failures.sort(key=lambda f: order[f.ref.id])
    return report


def _select(
    dataset: Dataset, splits: list[str], categories: Iterable[str] | None
) -> tuple[list[ObjectRef], PrepareReport]:
    """The objects to prepare, each once, in split order; unknown splits or categories raise."""
    allowed = [
        *dataset.eval_splits,
        *dataset.validation_splits,
        *([TRAIN] if TRAIN not in dataset.eval_splits else []),
    ]
    unknown = [s for s in splits if s not in allowed]
    if unknown:
        raise ConfigError(
            f"dataset {dataset.name!r} has no split {', '.join(map(repr, unknown))}",
            f"use one of: {', '.join(allowed)}",
        )
    wanted = None
    if categories:
        names = {c.name.lower(): c.name for c in dataset.categories()}
        missing = [c for c in categories if c.lower() not in names]
        if missing:
            raise ConfigError(
                f"dataset {dataset.name!r} has no categor{'y' if len(missing) == 1 else 'ies'} "
                f"{', '.join(map(repr, missing))}",
                f"its categories: {', '.join(sorted(names.values()))}",
            )
        wanted = {names[c.lower()] for c in categories}
    report = PrepareReport()
    refs: list[ObjectRef] = []
    seen: set[str] = set()
    for split in splits:
        split_refs = [r for r in dataset.objects(split) if wanted is None or r.category in wanted]
        report.per_split[split] = len(split_refs)
        for ref in split_refs:  # an object listed in two splits is prepared once
            if ref.id not in seen:
                seen.add(ref.id)
                refs.append(ref)
    report.total = len(refs)
    return refs, report


Outcome = tuple[ObjectRef, "str | None", float]  # (object, failure reason or None, seconds)


def _load_one(dataset: Dataset, ref: ObjectRef, need: frozenset[Supervision]) -> Outcome:
    start = time.perf_counter()
    try:
        dataset.load(ref, need)
        reason = None
    except ObjectLoadError as exc:
        reason = str(exc)
    except Exception as exc:  # one object's bug must not stop the others
        reason = f"{type(exc).__name__}: {exc}"
    return ref, reason, time.perf_counter() - start


def _run_inline(dataset: Dataset, refs: list[ObjectRef], need: frozenset[Supervision]):
    for ref in refs:
        yield _load_one(dataset, ref, need)


# Set in each worker by the pool's initializer, so the dataset is pickled once per worker.
_WORKER_DATASET: Dataset | None = None


def _init_worker(dataset: Dataset) -> None:
    global _WORKER_DATASET
    _WORKER_DATASET = dataset


def _work(ref: ObjectRef, need: frozenset[Supervision]) -> Outcome:
    assert _WORKER_DATASET is not None
    return _load_one(_WORKER_DATASET, ref, need)


def _run_pool(dataset: Dataset, refs: list[ObjectRef], need: frozenset[Supervision], jobs: int):
    """Outcomes as objects finish. Objects in flight when a worker died are tried again, one at a
    time, so only an object that kills its worker by itself is reported as failed."""
    killed: list[ObjectRef] = []
    queue = list(reversed(refs))
    while queue:  # each pass ends with an empty queue or a broken pool, losing <= jobs objects
        yield from _pool_pass(dataset, queue, need, jobs, killed)
    for ref in killed:
        lost: list[ObjectRef] = []
        yield from _pool_pass(dataset, [ref], need, 1, lost)
        if lost:
            yield ref, "a worker process died while preparing it (killed, or out of memory?)", 0.0


def _pool_pass(
    dataset: Dataset,
    queue: list[ObjectRef],
    need: frozenset[Supervision],
    jobs: int,
    killed: list[ObjectRef],
) -> Iterator[Outcome]:
    """Run ``queue`` (popped from its end) in one pool with at most ``jobs`` objects in flight,
    until it is empty or the pool breaks; objects lost with a broken pool go to ``killed``."""
    context = multiprocessing.get_context("spawn")
    pool = ProcessPoolExecutor(jobs, context, initializer=_init_worker, initargs=(dataset,))
    running: dict[Future, ObjectRef] = {}
    broken = False
    try:
        _wait_until_ready(pool, dataset)
        while (queue or running) and not broken:
            while queue and len(running) < jobs:
                ref = queue.pop()
                running[pool.submit(_work, ref, need)] = ref
            done, _ = wait(running, return_when=FIRST_COMPLETED)
            for future in done:
                ref = running.pop(future)
                try:
                    yield future.result()
                except BrokenProcessPool:
                    killed.append(ref)
                    broken = True
                except Exception as exc:  # e.g. an outcome that could not be sent back
                    yield ref, f"{type(exc).__name__}: {exc}", 0.0
        killed.extend(running.values())  # empty unless the pool broke with these in flight
    except BaseException:  # Ctrl-C or the consumer stopped: do not wait for running objects
        pool.shutdown(wait=False, cancel_futures=True)
        raise
    pool.shutdown(wait=True)


def _ready() -> bool:
    return _WORKER_DATASET is not None


def _wait_until_ready(pool: ProcessPoolExecutor, dataset: Dataset) -> None:
    """Fail at once, not once per object, when workers cannot even start (the dataset's class
    cannot be imported in a fresh interpreter, or unpickling it fails there)."""
    try:
        pool.submit(_ready).result()
    except BrokenProcessPool as exc:
        raise ShapebenchError(
            f"worker processes cannot load dataset {dataset.name!r} (see the error above)",
            "prepare it with --jobs 1; the dataset class must be importable by module path",
        ) from exc


def _check_picklable(dataset: Dataset) -> None:
    try:
        pickle.dumps(dataset)
    except Exception as exc:
        raise ShapebenchError(
            f"dataset {dataset.name!r} cannot be sent to worker processes: "
            f"{type(exc).__name__}: {exc}",
            "prepare it with --jobs 1, or keep only picklable state (options, paths, listings) "
            "on the dataset object",
        ) from exc


def _is_cached(dataset: Dataset, ref: ObjectRef) -> bool:
    path = getattr(dataset, "cache_path", None)
    if path is None:
        return False
    try:
        return Path(path(ref)).exists()
    except Exception:  # a dataset that cannot even name its cache file is simply not cached
        return False


def _progress(total: int, desc: str, quiet: bool):
    from shapebench.progress import progress_bar

    return progress_bar(total, desc, quiet, leave=True)


@dataclass
class PrepareRequest:
    """What ``shapebench prepare`` was asked for: picklable, so that a cluster job can run it."""

    dataset: str
    splits: list[str] | None
    categories: list[str] | None
    methods: list[str]
    method_opts: dict
    dataset_opts: dict
    data_root: str | None


def prepare_request(
    req: PrepareRequest,
    settings,
    jobs: int = 1,
    quiet: bool = False,
    shard: tuple[int, int] | None = None,
) -> list[PrepareReport]:
    """The evaluation splits, then the train split with what ``req.methods`` need."""
    from shapebench.registry.discovery import get_registry
    from shapebench.registry.resolve import resolve_dataset, resolve_method

    reg = get_registry()
    ds = resolve_dataset(reg, req.dataset, settings, req.data_root, req.dataset_opts)
    splits = req.splits or list(ds.eval_splits)
    reports = [prepare(ds, splits, jobs=jobs, quiet=quiet, categories=req.categories, shard=shard)]
    need: frozenset[Supervision] = frozenset()
    for name in req.methods:  # what this configuration needs (OccNet's depends on its recipe)
        instance = resolve_method(reg, name, settings, req.method_opts).instantiate()
        need |= instance.needs() if hasattr(instance, "needs") else instance.supervision
    if req.methods:
        reports.append(prepare(ds, [TRAIN], need, jobs, quiet, req.categories, shard))
    return reports
