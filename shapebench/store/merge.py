"""Merging MLflow stores: the offline workflow for compute nodes without a tracking server.

Jobs on nodes that cannot reach a server each log to a SQLite store of their own (a workspace per
job); ``shapebench merge STORE... --into URI`` then imports their finished work into the main
store. Runs are matched by what identifies them, never by run id:

- a cell by its cell key (``shapebench.cell_key``, see :mod:`shapebench.store.records`),
- a training by its checkpoint key,
- a parent run by its parent key,

so merging the same store twice, or two stores holding the same cell, adds each run once. A cell
already in the target keeps the target's scores; where the source's scores of that key differ by
more than the cell-key contract allows (:data:`shapebench.api.protocol.SCORE_RTOL`, relative: other
thread counts and machines agree to it, not bitwise), the merge reports the cell as
disagreeing, since the two stores then did not compute the same thing under one key. Only
FINISHED cells and trainings are imported (an unfinished one is work to redo); the copy keeps the
source's tags, params, metric histories (with their steps and timestamps), start and end times
and artifacts, and records where it came from (tag ``shapebench.merged_from``). A copied cell's
``training_run_id`` is re-pointed at the target's run of the same training (copied, or already
there under its checkpoint key): run ids mean nothing across stores, and the leaderboard's cost
column reads that tag.
"""

from __future__ import annotations

import shutil
import tempfile
from collections import defaultdict
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from shapebench.api.errors import ShapebenchError
from shapebench.api.protocol import SCORE_RTOL, scores_agree
from shapebench.store.paging import search_all_experiments, search_all_runs
from shapebench.store.records import (
    CELL_KEY_TAG,
    CELL_KIND,
    CHECKPOINT_KEY_TAG,
    KIND_TAG,
    MERGED_FROM_TAG,
    PARENT_KEY_TAG,
    PARENT_KIND,
    PARENT_RUN_TAG,
    TRAINING_KIND,
    TRAINING_RUN_TAG,
    CellRecord,
)

#: The tag that identifies each kind of run across stores.
IDENTITY = {
    CELL_KIND: CELL_KEY_TAG,
    TRAINING_KIND: CHECKPOINT_KEY_TAG,
    PARENT_KIND: PARENT_KEY_TAG,
}
MERGED_FROM = MERGED_FROM_TAG
#: The order runs are merged in: trainings first (their experiment may come after the cells'),
#: so that a copied cell can name its training's run in the target; parents before children.
_ORDER = {TRAINING_KIND: 0, PARENT_KIND: 1}
#: Source runs read per round: their metric histories are fetched together (one query per
#: metric key), and a round's histories are all that is held in memory at once.
_ROUND = 500
#: The most metric values one bulk query returns; a query that fills it may have been cut and is
#: asked again run by run.
_BULK_LIMIT = 1_000_000


def _rank(run: Any) -> int:
    return _ORDER.get(run.data.tags.get(KIND_TAG, ""), 2)


@dataclass
class MergeReport:
    """What one merge did, per kind of run."""

    added: dict[str, int] = field(default_factory=dict)
    present: dict[str, int] = field(default_factory=dict)
    skipped_unfinished: int = 0
    #: Cell keys present in both stores whose scores differ beyond the cell-key tolerance.
    disagreeing: list[str] = field(default_factory=list)

    def line(self) -> str:
        kinds = sorted(set(self.added) | set(self.present))
        parts = [
            f"{self.added.get(k, 0)} {k} runs added, {self.present.get(k, 0)} already there"
            for k in kinds
        ]
        if self.skipped_unfinished:
            parts.append(f"{self.skipped_unfinished} unfinished runs left out")
        if self.disagreeing:
            keys = ", ".join(self.disagreeing[:3]) + (", ..." if len(self.disagreeing) > 3 else "")
            parts.append(
                f"{len(self.disagreeing)} cells kept whose scores differ from the source's "
                f"beyond a relative {SCORE_RTOL:g} (keys {keys})"
            )
        return "; ".join(parts) or "nothing to merge"


def store_uri(store: str) -> str:
    """A tracking URI for ``store``: a URI as given, a ``.db`` file, or a workspace folder."""
    if "://" in store:
        return store
    path = Path(store).absolute()
    if path.is_dir():
        path = path / "mlflow.db"
    if not path.exists():
        raise ShapebenchError(
            f"no MLflow store at {store} (looked for {path})",
            "give a workspace folder, its mlflow.db, or a tracking URI",
        )
    return f"sqlite:///{path}"


def merge_stores(
    sources: list[str], target_uri: str, echo: Callable[[str], None] = print
) -> MergeReport:
    """Import the finished runs of every store in ``sources`` into ``target_uri``."""
    from shapebench.store.tracking import open_client

    target = open_client(target_uri)
    report = MergeReport()
    for source in sources:
        uri = store_uri(source)
        if uri == target_uri:
            raise ShapebenchError(f"cannot merge {source} into itself")
        before = dict(report.added)
        _merge_one(open_client(uri), uri, target, target_uri, report)
        new = sum(report.added.values()) - sum(before.values())
        echo(f"{source}: {new} runs added")
    return report


def _merge_one(
    source: Any, source_uri: str, target: Any, target_uri: str, report: MergeReport
) -> None:
    batches = []
    for exp in search_all_experiments(source):
        runs = sorted(search_all_runs(source, [exp.experiment_id]), key=_rank)
        if runs:
            batches.append((exp, runs))
    batches.sort(key=lambda batch: _rank(batch[1][0]))
    merged: dict[str, str] = {}  # source run id -> target run id (trainings and parents)
    for exp, runs in batches:
        target_exp = _experiment(target, target_uri, exp.name)
        present = _TargetRuns(target, target_exp)
        for start in range(0, len(runs), _ROUND):
            chunk = [run for run in runs[start : start + _ROUND] if _wanted(run, report)]
            histories = _metric_histories(source, [r for r in chunk if not _found(present, r)])
            for run in chunk:
                kind = run.data.tags[KIND_TAG]
                key = run.data.tags.get(IDENTITY[kind], "")
                existing = present.find(kind, key, run)
                if existing is not None:
                    merged[run.info.run_id] = existing.run_id
                    if kind == CELL_KIND and _scores_differ(run, existing):
                        report.disagreeing.append(key)
                    report.present[kind] = report.present.get(kind, 0) + 1
                    continue
                parent = merged.get(run.data.tags.get(PARENT_RUN_TAG, ""))
                training = merged.get(run.data.tags.get(TRAINING_RUN_TAG, ""))
                history = histories[run.info.run_id]  # not present before the round either
                merged[run.info.run_id] = _copy(
                    source, target, target_exp, run, history, source_uri, parent, training
                )
                present.add(kind, key, run, merged[run.info.run_id])
                report.added[kind] = report.added.get(kind, 0) + 1


def _wanted(run: Any, report: MergeReport) -> bool:
    """Whether ``run`` is a kind of run merge imports, in a state it imports (counting the
    unfinished ones it leaves out)."""
    kind = run.data.tags.get(KIND_TAG, "")
    if kind not in IDENTITY:
        return False
    if kind != PARENT_KIND and run.info.status != "FINISHED":
        report.skipped_unfinished += 1
        return False
    return True


def _found(present: _TargetRuns, run: Any) -> bool:
    kind = run.data.tags[KIND_TAG]
    return present.find(kind, run.data.tags.get(IDENTITY[kind], ""), run) is not None


def _metric_histories(client: Any, runs: Sequence[Any]) -> dict[str, list[Any]]:
    """Every logged value of every metric of ``runs`` (steps and timestamps kept), by run id.

    An SQL store answers one query per metric key for all the runs
    (``get_metric_history_bulk``, which MLflow's SQL store has and its abstract store does
    not); any other store, or a query that may have been cut at :data:`_BULK_LIMIT`, is asked
    per run and key. Asking per run and key was half of a merge's time (19 queries per cell)."""
    out: dict[str, list[Any]] = {run.info.run_id: [] for run in runs}
    by_key: dict[str, list[str]] = defaultdict(list)
    for run in runs:
        for key in run.data.metrics:
            by_key[key].append(run.info.run_id)
    store = getattr(getattr(client, "_tracking_client", None), "store", None)
    bulk = getattr(store, "get_metric_history_bulk", None)
    for key, run_ids in by_key.items():
        found = bulk(run_ids, key, _BULK_LIMIT) if bulk is not None else None
        if found is not None and len(found) < _BULK_LIMIT:
            for metric in found:
                out[metric.run_id].append(metric)
            continue
        for run_id in run_ids:
            out[run_id].extend(client.get_metric_history(run_id, key))
    return out


def _experiment(client: Any, uri: str, name: str) -> str:
    exp = client.get_experiment_by_name(name)
    if exp is not None:
        return exp.experiment_id
    location = None
    if uri.startswith("sqlite:///"):  # artifacts beside the embedded store, as shapebench does
        path = Path(uri[len("sqlite:///") :]).parent / "artifacts" / name
        path.mkdir(parents=True, exist_ok=True)
        location = path.as_uri()
    return client.create_experiment(name, artifact_location=location)


def _scores_differ(run: Any, other: _Present) -> bool:
    """Whether two runs of one cell key hold scores (each metric's mean, median and std) that
    differ beyond the cell-key tolerance."""
    names = CellRecord.from_run(run).cards
    ours, theirs = run.data.metrics, other.metrics
    for name in names:
        for stat in ("mean", "median", "std"):
            key = f"{name}.{stat}"
            if key in ours and key in theirs and not scores_agree(ours[key], theirs[key]):
                return True
    return False


@dataclass
class _Present:
    """A run of the target, as the merge compares it: its id and its metrics."""

    run_id: str
    metrics: dict[str, float]


class _TargetRuns:
    """The target experiment's runs by identity, read in one paged search: a search per source
    run scans the growing target each time (merging 10,000 cells was quadratic)."""

    def __init__(self, client: Any, exp_id: str) -> None:
        self.by_identity: dict[tuple[str, str], _Present] = {}
        for run in search_all_runs(client, [exp_id]):  # newest first: the first of a key wins
            tags = run.data.tags
            kind = tags.get(KIND_TAG, "")
            if kind == PARENT_KIND:  # a parent is matched by the source run it came from
                source = tags.get(MERGED_FROM, "").rpartition("#")[2]
                key = (kind, source) if source else None
            elif kind in IDENTITY and run.info.status == "FINISHED":
                key = (kind, tags.get(IDENTITY[kind], ""))
            else:
                key = None
            if key is not None and key not in self.by_identity:
                self.by_identity[key] = _Present(run.info.run_id, dict(run.data.metrics))

    def find(self, kind: str, key: str, run: Any) -> _Present | None:
        """The target's run with the same identity (a parent: merged from the same source run)."""
        return self.by_identity.get((kind, run.info.run_id if kind == PARENT_KIND else key))

    def add(self, kind: str, key: str, run: Any, copied: str) -> None:
        identity = (kind, run.info.run_id if kind == PARENT_KIND else key)
        self.by_identity.setdefault(identity, _Present(copied, dict(run.data.metrics)))


def _copy(
    source: Any,
    target: Any,
    exp_id: str,
    run: Any,
    history: list[Any],
    source_uri: str,
    parent: str | None,
    training: str | None = None,
) -> str:
    """Copy ``run`` (whose metric values are ``history``) into experiment ``exp_id`` of the
    target; the new run's id."""
    from mlflow.entities import Metric, Param

    tags = {k: v for k, v in run.data.tags.items() if k != PARENT_RUN_TAG}
    tags[MERGED_FROM] = f"{source_uri}#{run.info.run_id}"
    if parent:
        tags[PARENT_RUN_TAG] = parent
    if training:
        tags[TRAINING_RUN_TAG] = training
    new = target.create_run(
        exp_id, start_time=run.info.start_time, tags=tags, run_name=run.info.run_name
    )
    run_id = new.info.run_id
    params = [Param(k, v) for k, v in run.data.params.items()]
    metrics = [Metric(m.key, m.value, m.timestamp, m.step) for m in history]
    # Params and metrics together, within MLflow's batch limits (100 params, 1,000 entities).
    for i in range(max(-(-len(params) // 100), -(-len(metrics) // 900))):
        target.log_batch(
            run_id, params=params[i * 100 : (i + 1) * 100], metrics=metrics[i * 900 : (i + 1) * 900]
        )
    _copy_artifacts(source, target, run, new)
    status = run.info.status if run.info.status in ("FINISHED", "FAILED", "KILLED") else "KILLED"
    target.set_terminated(run_id, status=status, end_time=run.info.end_time)
    return run_id


def _copy_artifacts(source: Any, target: Any, run: Any, new: Any) -> None:
    """The artifacts of ``run`` into those of the target's run ``new``: a copy of the folder
    when both stores keep artifacts on this machine's filesystem (as shapebench's workspaces
    do), else through MLflow's download and upload (a tracking server, a bucket)."""
    from shapebench.store.tracking import local_artifact_path

    here = local_artifact_path(run.info.artifact_uri)
    there = local_artifact_path(new.info.artifact_uri)
    if here is not None and there is not None:
        if here.is_dir():
            shutil.copytree(here, there, dirs_exist_ok=True)
        return
    with tempfile.TemporaryDirectory() as tmp:
        if source.list_artifacts(run.info.run_id):
            local = source.download_artifacts(run.info.run_id, "", tmp)
            target.log_artifacts(new.info.run_id, local)
