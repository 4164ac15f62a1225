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

import json
import urllib.error
import urllib.request
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from shapebench.config import Settings
from shapebench.errors import TrackingError

CELL_KIND = "cell"
PARENT_KIND = "parent"
TRAINING_KIND = "training"


def experiment_name(dataset: str, split: str) -> str:
    return f"{dataset}-{split}"


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
    #: The run's tags, read back (a :class:`shapebench.records.CellRecord`).
    record: Any = None


class Tracker:
    """Thin layer over MlflowClient with shapebench's naming and tagging conventions."""

    def __init__(self, settings: Settings) -> None:
        check_reachable(settings.tracking_uri)
        self.settings = settings
        self.uri = settings.tracking_uri
        self.client = open_client(self.uri)
        self._experiments: dict[str, str] = {}

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
            return self.client.create_experiment(name, artifact_location=location)
        except MlflowException:
            # Another process created it between our lookup and our creation: use theirs.
            exp = self.client.get_experiment_by_name(name)
            if exp is None:
                raise
            return exp.experiment_id

    def find_cell(self, exp_id: str, key: str) -> FinishedCell | None:
        finished = "attributes.status = 'FINISHED'"
        runs = self.client.search_runs(
            [exp_id],
            filter_string=f"tags.`shapebench.cell_key` = '{key}' and {finished}",
            order_by=["attributes.start_time DESC"],
            max_results=1,
        )
        if not runs:
            return None
        from shapebench.records import CellRecord

        record = CellRecord.from_run(runs[0])
        return FinishedCell(runs[0].info.run_id, dict(runs[0].data.metrics),
                            frozenset(record.metric_errors), record)  # fmt: skip

    def abandon_stale(self, exp_id: str, key: str, tag: str = "shapebench.cell_key") -> int:
        """Mark RUNNING runs with this key (left by a killed process) KILLED; return how many."""
        runs = self.client.search_runs(
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
        all_tags = dict(tags)
        if parent_id:
            all_tags["mlflow.parentRunId"] = parent_id
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

    def end(self, run_id: str, status: str = "FINISHED") -> None:
        self.client.set_terminated(run_id, status=status)


def open_client(uri: str) -> Any:
    """An ``MlflowClient`` for ``uri``; an embedded store is opened under a lock.

    MLflow creates (or upgrades) a SQLite store's schema when a client opens it; two processes
    doing that at once make the second fail (``duplicate column name``). The lock beside the
    database file makes them take turns.
    """
    from mlflow.tracking import MlflowClient

    if not uri.startswith("sqlite:///"):
        return MlflowClient(tracking_uri=uri)
    from shapebench.locks import wait_lock

    db = Path(uri[len("sqlite:///") :])
    with wait_lock(db.with_name(db.name + ".init.lock")):
        return MlflowClient(tracking_uri=uri)


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
