"""MLflow as the record of every run: store selection, reachability, the cell ledger.

Layout: one experiment per dataset and split (``<dataset>-<split>``, e.g. ``synthetic-novel``).
Each ``shapebench run`` (or each method x dataset x split of a sweep) makes a *parent* run; each
cell (one context size and seed) is a *child* run tagged ``shapebench.cell_key``: a hash of the
cell's whole resolved config. A cell whose key already has a FINISHED run is skipped, which makes
runs and sweeps resumable after Ctrl-C or ``kill -9``; a RUNNING run left behind by a killed
process is marked KILLED when its cell is run again.

Several processes may share one workspace: the embedded store's schema is created under a lock
(:func:`_open_store`), and the runner claims each cell with a lock before computing it
(:func:`cell_lock_path`), so two runs started together compute and log every cell once.

All logging goes through an explicit :class:`~mlflow.tracking.MlflowClient` with an explicit URI:
MLflow >= 3.13 refuses the implicit ``./mlruns`` file store.
"""

from __future__ import annotations

import contextlib
import json
import os
import shutil
import urllib.error
import urllib.parse
import urllib.request
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from shapebench.api.errors import TrackingError
from shapebench.config import Settings
from shapebench.store import records as rec
from shapebench.store.paging import search_all_experiments, search_all_runs
from shapebench.store.provenance import run_context_tags
from shapebench.store.urls import VIEW_KEY, view_state


def experiment_name(dataset: str, split: str) -> str:
    return f"{dataset}-{split}"


def training_experiment_name(dataset: str) -> str:
    """The experiment of the trainings on ``dataset``. Stores written before it had this name
    hold them in ``<dataset>-train``, which sat beside ``<dataset>-trained`` and was easily
    taken for it; those are still read (every reader selects runs by their kind tag)."""
    return f"training/{dataset}"


#: Experiment names that held trainings in older stores (never a split of the leaderboards).
LEGACY_TRAINING_SUFFIX = "-train"


def check_reachable(uri: str, timeout: float = 5.0) -> None:
    """Fail fast, before any work, when the tracking server does not answer."""
    if not uri.startswith(("http://", "https://")):
        if uri.startswith("sqlite:///"):
            Path(uri[len("sqlite:///") :]).parent.mkdir(parents=True, exist_ok=True)
        return
    try:
        with urllib.request.urlopen(uri.rstrip("/") + "/health", timeout=timeout) as resp:
            if resp.status >= 400:
                raise OSError(f"HTTP {resp.status}")
    except (OSError, urllib.error.URLError) as exc:
        reason = getattr(exc, "reason", exc)
        raise TrackingError(
            f"cannot reach the MLflow tracking server at {uri} ({reason})",
            "start it (mlflow server --host 127.0.0.1 --port 5000 ...), fix --tracking-uri / "
            "MLFLOW_TRACKING_URI, or unset them to use the embedded sqlite store",
        ) from exc


@dataclass
class FinishedCell:
    run_id: str
    metrics: dict[str, float]
    #: Metrics that raised on some object of this cell (tag ``shapebench.metric_errors``).
    metric_errors: frozenset[str] = frozenset()
    #: The run's tags, read back (a :class:`shapebench.store.records.CellRecord`).
    record: Any = None


def local_artifact_path(artifact_uri: str | None, name: str = "") -> Path | None:
    """The file of artifact ``name`` under a local ``artifact_uri`` (``file:`` or a plain path);
    None for a remote one (a tracking server's, a bucket)."""
    if not artifact_uri:
        return None
    parsed = urllib.parse.urlparse(artifact_uri)
    if parsed.scheme == "file":
        return Path(urllib.request.url2pathname(parsed.path)) / name
    if parsed.scheme == "":
        return Path(artifact_uri) / name
    return None


def _finished_cell(run: Any) -> FinishedCell:
    record = rec.CellRecord.from_run(run)
    return FinishedCell(
        run.info.run_id, dict(run.data.metrics), frozenset(record.metric_errors), record
    )


class Tracker:
    """Thin layer over MlflowClient with shapebench's naming and tagging conventions."""

    def __init__(self, settings: Settings) -> None:
        check_reachable(settings.tracking_uri)
        self.settings = settings
        self.uri = settings.tracking_uri
        self.client = open_client(self.uri)
        self._experiments: dict[str, str] = {}
        # Where the runs a search returned keep their artifacts (run id -> artifact URI): a local
        # artifact is then read from its folder, not through MLflow's download, which looks the
        # run up twice per file (35 ms a cell, most of a large leaderboard's time).
        self._artifact_uris: dict[str, str] = {}

    def experiment_id(self, name: str, create: bool = True) -> str | None:
        if name in self._experiments:
            return self._experiments[name]
        exp = self.client.get_experiment_by_name(name)
        if exp is None:
            if not create:
                return None
            location = None
            if not self.settings.is_remote:  # keep artifacts beside the embedded store
                path = self.settings.artifact_root / name
                path.mkdir(parents=True, exist_ok=True)
                location = path.as_uri()
            exp_id = self._create_experiment(name, location)
        else:
            exp_id = exp.experiment_id
        self._experiments[name] = exp_id
        return exp_id

    def _create_experiment(self, name: str, location: str | None) -> str:
        from mlflow.exceptions import MlflowException

        try:
            # The UI opens a "custom model development" experiment on its runs table and charts
            # (without the tag it guesses, and may open the GenAI traces views).
            return self.client.create_experiment(
                name, artifact_location=location, tags={rec.EXPERIMENT_KIND_TAG: EXPERIMENT_KIND}
            )
        except MlflowException:
            # Another process created it between our lookup and our creation: use theirs.
            exp = self.client.get_experiment_by_name(name)
            if exp is None:
                raise
            return exp.experiment_id

    def describe_experiment(self, exp_id: str, note: str, metrics: Sequence[str] = ()) -> None:
        """The experiment's description (``mlflow.note.content``, shown above its runs) and,
        given the metrics of its cells, shapebench's view of it: the runs table with those
        metrics as columns (see :func:`~shapebench.store.urls.view_state`), opened by
        :func:`~shapebench.store.urls.experiment_url`."""
        tags = {rec.NOTE_TAG: note}
        if metrics:
            tags[rec.VIEW_TAG_PREFIX + VIEW_KEY] = json.dumps(view_state(metrics))
        exp = self.client.get_experiment(exp_id)
        for key, value in tags.items():
            if exp.tags.get(key) != value:  # written once per change, not per run
                self.client.set_experiment_tag(exp_id, key, value)

    def find_cell(self, exp_id: str, key: str) -> FinishedCell | None:
        finished = "attributes.status = 'FINISHED'"
        runs = self.client.search_runs(
            [exp_id],
            filter_string=f"tags.`{rec.CELL_KEY_TAG}` = '{key}' and {finished}",
            order_by=["attributes.start_time DESC"],
            max_results=1,
        )
        return _finished_cell(runs[0]) if runs else None

    def finished_cell_index(self, exp_id: str) -> dict[str, FinishedCell]:
        """Every finished cell of an experiment by its key (the newest run of each key, as
        :meth:`find_cell` gives it), read in one paged search: for a caller that looks up many
        keys (a sweep's plan), where a search per key costs a scan of the store each."""
        runs = search_all_runs(
            self.client,
            [exp_id],
            filter_string="attributes.status = 'FINISHED'",
            order_by=["attributes.start_time DESC"],
        )
        index: dict[str, FinishedCell] = {}
        for run in runs:
            key = run.data.tags.get(rec.CELL_KEY_TAG)
            if key and key not in index:
                index[key] = _finished_cell(run)
        return index

    def abandon_stale(self, exp_id: str, key: str, tag: str = rec.CELL_KEY_TAG) -> int:
        """Mark RUNNING runs with this key (left by a killed process) KILLED; return how many."""
        runs = search_all_runs(
            self.client,
            [exp_id],
            filter_string=f"tags.`{tag}` = '{key}' and attributes.status = 'RUNNING'",
        )
        for run in runs:
            self.client.set_terminated(run.info.run_id, status="KILLED")
        return len(runs)

    def start_run(
        self,
        exp_id: str,
        name: str,
        tags: dict[str, str],
        parent_id: str | None = None,
    ) -> str:
        # MLflow's own tags (user, source, commit: the UI's Source and User columns) and where
        # the result came from (library versions, hardware), then shapebench's.
        all_tags = {**run_context_tags(), **tags}
        if parent_id:
            all_tags[rec.PARENT_RUN_TAG] = parent_id
        run = self.client.create_run(exp_id, run_name=name, tags=all_tags)
        return run.info.run_id

    def log_params(self, run_id: str, params: dict[str, Any]) -> None:
        from mlflow.entities import Param

        items = [Param(k, _param_str(v)) for k, v in sorted(params.items())]
        for start in range(0, len(items), 100):
            self.client.log_batch(run_id, params=items[start : start + 100])

    def log_metrics(self, run_id: str, metrics: dict[str, float], step: int = 0) -> None:
        import time

        from mlflow.entities import Metric

        now = int(time.time() * 1000)
        items = [Metric(k, float(v), now, step) for k, v in sorted(metrics.items())]
        self.client.log_batch(run_id, metrics=items)

    def log_dataset(
        self,
        run_id: str,
        name: str,
        digest: str,
        source: dict[str, Any],
        profile: dict[str, Any],
        context: str,
    ) -> None:
        """Record the evaluated objects as the run's dataset input (the UI's Dataset column)."""
        from mlflow.entities import Dataset, DatasetInput, InputTag
        from mlflow.exceptions import MlflowException

        dataset = Dataset(
            name=name,
            digest=digest[:36],
            source_type="local",
            source=json.dumps(source, default=str),
            profile=json.dumps(profile, default=str),
        )
        tags = [InputTag(key=rec.DATASET_CONTEXT_TAG, value=context)]
        inputs = [DatasetInput(dataset=dataset, tags=tags)]
        try:
            self.client.log_inputs(run_id, datasets=inputs)
        except MlflowException as exc:
            # Two workers logging the same dataset at once: MLflow's store looks it up, finds
            # none, and both insert it; the second insert breaks the table's unique key. The
            # dataset exists now, so the same call links it to this run.
            if "UNIQUE constraint failed: datasets." not in str(exc):
                raise
            self.client.log_inputs(run_id, datasets=inputs)

    def end(self, run_id: str, status: str = "FINISHED") -> None:
        self.client.set_terminated(run_id, status=status)

    def end_after(self, run_id: str, exc: BaseException, status: str = "KILLED") -> None:
        """Mark ``run_id`` ended by ``exc`` (in an ``except`` block, before re-raising it). When
        the store itself failed (a full disk, a server that stopped answering) nothing is written:
        it would fail again, or retry for minutes; the run is left RUNNING and the next run of its
        cell marks it abandoned. Any other failure to mark it is left to that run too, so that
        ``exc``, the error that matters, is the one raised."""
        from shapebench.store.failures import store_failure

        if store_failure(exc, self.uri) is not None:
            return
        with contextlib.suppress(Exception):  # exc is re-raised by the caller; see above
            self.end(run_id, status)

    # -- reading and annotating runs, for the rooms above the store --------------------------

    def set_tags(self, run_id: str, tags: dict[str, str]) -> None:
        """Tags built by :mod:`shapebench.store.records` (or this room) on a run."""
        for key, value in tags.items():
            self.client.set_tag(run_id, key, value)

    def set_note(self, run_id: str, markdown: str) -> None:
        """The run's description, shown on its page in the UI."""
        self.client.set_tag(run_id, rec.NOTE_TAG, markdown)

    def tags(self, run_id: str) -> dict[str, str]:
        return dict(self.client.get_run(run_id).data.tags)

    def experiment_of(self, run_id: str) -> str | None:
        """The experiment id of ``run_id``, or None when the run is not in this store."""
        try:
            return self.client.get_run(run_id).info.experiment_id
        except Exception:  # a checkpoint trained in another store, a deleted run
            return None

    def artifact_uri(self, run_id: str, name: str = "") -> str:
        uri = self.client.get_run(run_id).info.artifact_uri.rstrip("/")
        return f"{uri}/{name}" if name else uri

    def log_artifacts(self, run_id: str, folder: Path, path: str | None = None) -> None:
        """Every file of ``folder`` as artifacts of the run (under ``path``)."""
        self.client.log_artifacts(run_id, str(folder), path)

    def log_artifact(self, run_id: str, file: Path) -> None:
        self.client.log_artifact(run_id, str(file))

    def download_artifact(self, run_id: str, name: str, dst: Path) -> Path:
        """The run's artifact ``name``, copied to ``dst / name``."""
        local = local_artifact_path(self._artifact_uris.get(run_id), name)
        if local is not None and local.is_file():
            target = Path(dst) / name
            target.parent.mkdir(parents=True, exist_ok=True)
            shutil.copyfile(local, target)
            return target
        # MLflow draws a progress bar per download (read at call time): in a notebook reading a
        # hundred cells that is a hundred bars. The command line turns them off for good.
        os.environ.setdefault("MLFLOW_ENABLE_ARTIFACTS_PROGRESS_BAR", "false")
        return Path(self.client.download_artifacts(run_id, name, str(dst)))

    def list_artifacts(self, run_id: str, folder: str) -> list[str]:
        return [a.path for a in self.client.list_artifacts(run_id, folder)]

    def experiment_names(self, prefix: str = "") -> list[str]:
        experiments = search_all_experiments(self.client)
        return [e.name for e in experiments if e.name.startswith(prefix)]

    def finished_cells(self, exp_id: str) -> list[tuple[str, int, rec.CellRecord]]:
        """(run id, start time, record) of every finished cell of an experiment, newest first."""
        runs = search_all_runs(
            self.client,
            [exp_id],
            filter_string=(
                f"tags.`{rec.KIND_TAG}` = '{rec.CELL_KIND}' and attributes.status = 'FINISHED'"
            ),
            order_by=["attributes.start_time DESC"],
        )
        self._artifact_uris.update((r.info.run_id, r.info.artifact_uri) for r in runs)
        return [(r.info.run_id, r.info.start_time, rec.CellRecord.from_run(r)) for r in runs]

    def runs_of_kind(self, exp_id: str, kind: str, tags: dict[str, str] | None = None) -> list:
        """The runs of ``kind`` (:mod:`~shapebench.store.records`) in an experiment whose tags
        equal ``tags``, oldest first, as ``(run id, tags)``."""
        clauses = [f"tags.`{rec.KIND_TAG}` = '{kind}'"]
        clauses += [f"tags.`{k}` = '{v}'" for k, v in (tags or {}).items()]
        runs = search_all_runs(self.client, [exp_id], " and ".join(clauses))
        runs = sorted(runs, key=lambda r: r.info.start_time)
        return [(r.info.run_id, dict(r.data.tags)) for r in runs]

    def run_summary(self, run_id: str) -> tuple[dict[str, float], dict[str, str]] | None:
        """The metrics and tags of a run, or None when it is not in this store."""
        try:
            run = self.client.get_run(run_id)
        except Exception:  # deleted or in another store (merged cells)
            return None
        return dict(run.data.metrics), dict(run.data.tags)


EXPERIMENT_KIND = "custom_model_development"


def _retire_default_experiment(client: Any) -> None:
    """MLflow creates an experiment "Default" in every new store, with its artifacts in
    ``./mlruns`` of whatever directory the store was opened from. shapebench never logs to it,
    so an empty one is deleted: the UI then lists only shapebench's experiments, and nothing
    can write to a stray ./mlruns."""
    from mlflow.exceptions import MlflowException

    try:
        exp = client.get_experiment("0")
        if exp is None or exp.name != "Default" or exp.lifecycle_stage != "active":
            return
        if client.search_runs(["0"], max_results=1, run_view_type=3):
            return  # someone logged to it: theirs to keep
        client.delete_experiment("0")
    except MlflowException:
        pass  # already deleted by another process, or a store without an experiment 0


def open_client(uri: str) -> Any:
    """An ``MlflowClient`` for ``uri``; an embedded store is opened under a lock.

    MLflow creates (or upgrades) a SQLite store's schema when a client opens it; two processes
    doing that at once make the second fail (``duplicate column name``). The lock beside the
    database file makes them take turns.
    """
    from mlflow.tracking import MlflowClient

    if not uri.startswith("sqlite:///"):
        return MlflowClient(tracking_uri=uri)
    from shapebench.store.locks import wait_lock

    db = Path(uri[len("sqlite:///") :])
    with wait_lock(db.with_name(db.name + ".init.lock")):
        client = MlflowClient(tracking_uri=uri)
        _retire_default_experiment(client)
        return client


def cell_lock_path(settings: Settings, key: str) -> Path:
    """The lock a process holds while it computes the cell with this key."""
    return settings.artifact_root.parent / "locks" / "cells" / f"{key}.lock"


def _param_str(value: Any) -> str:
    text = value if isinstance(value, str) else json.dumps(value, default=str)
    return text[:6000]  # MLflow's limit for a param value


def flatten(prefix: str, obj: Any) -> dict[str, Any]:
    """``{"a": {"b": 1}}`` -> ``{"a.b": 1}`` for MLflow params."""
    if isinstance(obj, dict):
        out: dict[str, Any] = {}
        for k, v in obj.items():
            out.update(flatten(f"{prefix}.{k}" if prefix else str(k), v))
        return out
    return {prefix: obj}


def lightning_logger(tracking_uri: str, run_id: str) -> Any:
    """Lightning's MLFlowLogger, writing a training's curves into its run ``run_id``."""
    from pytorch_lightning.loggers import MLFlowLogger

    return MLFlowLogger(tracking_uri=tracking_uri, run_id=run_id)


def log_training_summary(logger: Any, metrics: dict[str, float], step: int, device: str) -> None:
    """A finished training's ``summary/*`` metrics and its device tag, through its logger."""
    logger.log_metrics(metrics, step=step)
    logger.experiment.set_tag(logger.run_id, rec.TRAINING_DEVICE_TAG, device)
