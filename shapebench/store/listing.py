"""``shapebench runs`` and ``shapebench show``: what is in the store, without opening the UI.

Runs are found by their kind tag (``shapebench.kind``: cell, parent, training), never by
experiment name, so stores written by older versions (trainings in ``<dataset>-train``) list
the same way. Cells are read through :class:`shapebench.store.records.CellRecord`, like everything
else that reads them back.
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, field
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

from shapebench.api.errors import ShapebenchError
from shapebench.config import Settings
from shapebench.store import records as rec
from shapebench.store.paging import search_all_experiments, search_all_runs
from shapebench.store.records import CELL_KIND, PARENT_KIND, TRAINING_KIND, CellRecord
from shapebench.store.urls import run_url

KINDS = (CELL_KIND, PARENT_KIND, TRAINING_KIND)
STATUSES = ("FINISHED", "RUNNING", "FAILED", "KILLED")
#: Where ``shapebench ui`` serves by default: the base of the links printed for a local store.
LOCAL_UI = "http://127.0.0.1:5000"


@dataclass
class RunRow:
    """One line of ``shapebench runs``."""

    run_id: str
    kind: str
    name: str
    experiment: str
    experiment_id: str
    status: str
    variant: str
    method: str
    dataset: str
    split: str
    context_size: int | None
    seed: int | None
    metric: str
    #: The primary metric's mean over objects, as logged (the parent's: at its largest context
    #: size); ``value * scale`` is what tables show (``scale`` is the card's, x1000 for Chamfer).
    value: float | None
    scale: float
    failures: int | None
    objects: int | None
    seconds: float | None
    start: str


def _client(settings: Settings) -> Any:
    """A client on the store, refusing to create an empty one just to list it."""
    from shapebench.store.tracking import check_reachable, open_client

    uri = settings.tracking_uri
    if uri.startswith("sqlite:///") and not Path(uri[len("sqlite:///") :]).exists():
        raise ShapebenchError(
            f"no MLflow store at {uri[len('sqlite:///') :]}",
            "run something first (shapebench run --method gauss --dataset synthetic), or point "
            "--workspace / --tracking-uri at the store",
        )
    check_reachable(uri)
    return open_client(uri)


def _experiments(client: Any) -> dict[str, str]:
    return {e.experiment_id: e.name for e in search_all_experiments(client)}


def _primary_metric(dataset: str, cards: dict[str, str]) -> str:
    """The dataset's default metric when the run has it, else its first metric."""
    try:
        from shapebench.registry.discovery import get_registry

        default = get_registry().get("dataset", dataset).load().default_metric
    except Exception:  # a dataset whose plugin is gone still lists, by its first card
        default = ""
    if default in cards:
        return default
    return sorted(cards)[0] if cards else ""


def _scale(record: CellRecord, metric: str) -> float:
    card = record.card(metric)
    return card.scale if card is not None else 1.0


def _duration(info: Any) -> float | None:
    if info.end_time and info.start_time:
        return (info.end_time - info.start_time) / 1000.0
    return None


def _when(ms: int | None) -> str:
    if not ms:
        return ""
    return datetime.fromtimestamp(ms / 1000, tz=timezone.utc).strftime("%Y-%m-%d %H:%M:%S")


def _row(run: Any, experiments: dict[str, str], primary: dict[tuple, str]) -> RunRow:
    tags = run.data.tags
    metrics = run.data.metrics
    kind = tags.get(rec.KIND_TAG, "")
    info = run.info
    record = CellRecord.from_tags(tags)
    dataset = tags.get(rec.DATASET_TAG, "")
    cards = record.cards
    if kind == PARENT_KIND and not cards:  # a parent of an older version: no cards
        cards = {k.rsplit(".", 1)[0]: "" for k in metrics if k.endswith(".mean")}
    key = (dataset, tuple(sorted(cards)))
    if key not in primary:
        primary[key] = _primary_metric(dataset, cards)
    metric = primary[key] if kind != TRAINING_KIND else ""
    value = metrics.get(f"{metric}.mean") if metric else None
    scale = _scale(record, metric) if metric else 1.0
    variant = tags.get(rec.VARIANT_LABEL_TAG) or tags.get(rec.METHOD_TAG, "")
    return RunRow(
        run_id=info.run_id,
        kind=kind,
        name=info.run_name or "",
        experiment=experiments.get(info.experiment_id, info.experiment_id),
        experiment_id=info.experiment_id,
        status=info.status,
        variant=variant,
        method=tags.get(rec.METHOD_TAG, ""),
        dataset=dataset,
        split=tags.get(rec.SPLIT_TAG, ""),
        context_size=record.context_size if kind == CELL_KIND else None,
        seed=record.seed if kind == CELL_KIND else None,
        metric=metric,
        value=None if value is None else float(value),
        scale=scale,
        failures=int(metrics["failures"]) if "failures" in metrics else None,
        objects=int(metrics["n_objects"]) if "n_objects" in metrics else None,
        seconds=_duration(info),
        start=_when(info.start_time),
    )


def list_runs(
    settings: Settings,
    kind: str = CELL_KIND,
    method: str | None = None,
    dataset: str | None = None,
    split: str | None = None,
    status: str | None = None,
    context_size: int | None = None,
    limit: int | None = 1000,
) -> list[RunRow]:
    """The store's runs of ``kind`` (or every kind with ``"all"``) matching the filters, sorted
    by dataset, split, variant, context size and seed: the newest ``limit`` (None: all)."""
    return list_runs_counted(settings, kind, method, dataset, split, status, context_size, limit)[0]


def list_runs_counted(
    settings: Settings,
    kind: str = CELL_KIND,
    method: str | None = None,
    dataset: str | None = None,
    split: str | None = None,
    status: str | None = None,
    context_size: int | None = None,
    limit: int | None = 1000,
) -> tuple[list[RunRow], bool]:
    """:func:`list_runs`, and whether ``limit`` left older matching runs out (so that a
    listing can say so instead of passing a cut for the whole)."""
    if kind != "all" and kind not in KINDS:
        raise ShapebenchError(f"unknown run kind {kind!r}", f"use one of: {', '.join(KINDS)}, all")
    client = _client(settings)
    experiments = _experiments(client)
    if not experiments:
        return [], False
    clauses = []
    if kind != "all":
        clauses.append(f"tags.`{rec.KIND_TAG}` = '{kind}'")
    for tag, value in (
        (rec.METHOD_TAG, method),
        (rec.DATASET_TAG, dataset),
        (rec.SPLIT_TAG, split),
    ):
        if value:
            clauses.append(f"tags.`{tag}` = '{_quote(value)}'")
    if context_size is not None:
        clauses.append(f"tags.`{rec.CONTEXT_SIZE_TAG}` = '{int(context_size)}'")
    if status:
        clauses.append(f"attributes.status = '{status.upper()}'")
    runs = search_all_runs(
        client,
        list(experiments),
        filter_string=" and ".join(clauses),
        order_by=["attributes.start_time DESC"],
        limit=None if limit is None else limit + 1,  # one more: are there more?
    )
    more = limit is not None and len(runs) > limit
    runs = runs[:limit] if more else runs
    primary: dict[tuple, str] = {}
    rows = [
        _row(r, experiments, primary)
        for r in runs
        if kind != "all" or r.data.tags.get(rec.KIND_TAG) in KINDS
    ]
    ordered = sorted(
        rows,
        key=lambda r: (
            r.dataset,
            r.split,
            r.kind,
            r.variant,
            r.context_size or 0,
            r.seed or 0,
            r.start,
        ),
    )
    return ordered, more


def _quote(value: str) -> str:
    if "'" in value:
        raise ShapebenchError(f"filter value {value!r} holds a quote", "names never contain one")
    return value


def format_rows(rows: list[RunRow]) -> list[str]:
    """The lines ``shapebench runs`` prints: a fixed-width table."""
    header = [
        "variant",
        "dataset/split",
        "k",
        "seed",
        "status",
        "metric",
        "mean",
        "failed",
        "time",
        "run id",
    ]
    table = [header]
    for r in rows:
        value = "-" if r.value is None else f"{r.value * r.scale:.3f}"
        metric = f"{r.metric} x{r.scale:g}" if r.metric else "-"
        variant = r.variant if r.kind == CELL_KIND else f"{r.variant} ({r.kind})"
        table.append(
            [
                variant,
                f"{r.dataset}/{r.split}" if r.split else r.dataset,
                "" if r.context_size is None else str(r.context_size),
                "" if r.seed is None else str(r.seed),
                r.status,
                metric,
                value,
                "" if r.failures is None else f"{r.failures}/{r.objects}",
                _seconds(r.seconds),
                r.run_id,
            ]
        )
    widths = [max(len(row[i]) for row in table) for i in range(len(header))]
    numeric = {2, 3, 6, 7, 8}
    return [
        "  ".join(
            cell.rjust(w) if i in numeric else cell.ljust(w)
            for i, (cell, w) in enumerate(zip(row, widths, strict=True))
        ).rstrip()
        for row in table
    ]


def _seconds(seconds: float | None) -> str:
    if seconds is None:
        return "-"
    if seconds < 60:
        return f"{seconds:.1f}s"
    if seconds < 3600:
        return f"{seconds / 60:.1f}m"
    return f"{seconds / 3600:.1f}h"


def rows_json(rows: list[RunRow]) -> str:
    return json.dumps([asdict(r) for r in rows], indent=2)


@dataclass
class RunDetails:
    """Everything ``shapebench show`` says about one run."""

    run_id: str
    name: str
    kind: str
    experiment: str
    experiment_id: str
    status: str
    start: str
    seconds: float | None
    tags: dict[str, str]
    params: dict[str, str]
    metrics: dict[str, float]
    artifacts: list[str]
    parent_id: str = ""
    children: list[str] = field(default_factory=list)
    url: str = ""
    training_url: str = ""


def find_run(client: Any, ref: str) -> Any:
    """The run with id ``ref``, or the only shapebench run whose id starts with it."""
    from mlflow.exceptions import MlflowException

    ref = ref.strip()
    if len(ref) == 32:
        try:
            return client.get_run(ref)
        except MlflowException:
            pass
    if len(ref) >= 4:
        experiments = _experiments(client)
        matches = (
            [r for r in search_all_runs(client, list(experiments)) if r.info.run_id.startswith(ref)]
            if experiments
            else []
        )
        if len(matches) == 1:
            return matches[0]
        if len(matches) > 1:
            raise ShapebenchError(
                f"run id prefix {ref!r} matches {len(matches)} runs",
                "give more characters of the run id",
            )
    raise ShapebenchError(
        f"no run {ref!r} in this store",
        "list them with 'shapebench runs' (the last column is the run id; a unique prefix of at "
        "least 4 characters is enough)",
    )


def _artifacts(client: Any, run_id: str, path: str = "", depth: int = 0) -> list[str]:
    out = []
    for item in client.list_artifacts(run_id, path or None):
        if item.is_dir and depth < 2:
            out += _artifacts(client, run_id, item.path, depth + 1)
        else:
            out.append(item.path + ("/" if item.is_dir else ""))
    return out


def ui_base(settings: Settings) -> str:
    """Where the MLflow UI of this store is: the server itself, or ``shapebench ui``'s."""
    return settings.tracking_uri if settings.is_remote else LOCAL_UI


def show_run(settings: Settings, ref: str) -> RunDetails:
    client = _client(settings)
    run = find_run(client, ref)
    info = run.info
    experiments = _experiments(client)
    children = search_all_runs(
        client,
        [info.experiment_id],
        filter_string=f"tags.`{rec.PARENT_RUN_TAG}` = '{info.run_id}'",
    )
    base = ui_base(settings)
    training = run.data.tags.get(rec.TRAINING_RUN_TAG, "")
    training_url = ""
    if training:
        from mlflow.exceptions import MlflowException

        try:
            trained = client.get_run(training)
            training_url = run_url(base, trained.info.experiment_id, training)
        except MlflowException:
            training_url = ""
    return RunDetails(
        run_id=info.run_id,
        name=info.run_name or "",
        kind=run.data.tags.get(rec.KIND_TAG, ""),
        experiment=experiments.get(info.experiment_id, info.experiment_id),
        experiment_id=info.experiment_id,
        status=info.status,
        start=_when(info.start_time),
        seconds=_duration(info),
        tags=dict(sorted(run.data.tags.items())),
        params=dict(sorted(run.data.params.items())),
        metrics=dict(sorted(run.data.metrics.items())),
        artifacts=_artifacts(client, info.run_id),
        parent_id=run.data.tags.get(rec.PARENT_RUN_TAG, ""),
        children=sorted(c.info.run_id for c in children),
        url=run_url(base, info.experiment_id, info.run_id),
        training_url=training_url,
    )


#: Tags ``show`` prints in its head, in this order (the rest follow under "tags").
_HEAD_TAGS = [
    rec.VARIANT_LABEL_TAG,
    rec.METHOD_TAG,
    rec.DATASET_TAG,
    rec.SPLIT_TAG,
    rec.CONTEXT_SIZE_TAG,
    rec.SEED_TAG,
    rec.FRAME_TAG,
    rec.CELL_KEY_TAG,
    rec.CHECKPOINT_KEY_TAG,
    rec.TRAINING_RUN_TAG,
    rec.GIT_COMMIT_TAG,
    rec.SHAPEBENCH_VERSION_TAG,
]


def format_details(d: RunDetails, all_tags: bool = False) -> list[str]:
    lines = [
        f"{d.name}  ({d.kind or 'run'}, {d.status})",
        f"  run id:      {d.run_id}",
        f"  experiment:  {d.experiment} (id {d.experiment_id})",
        f"  started:     {d.start} UTC, took {_seconds(d.seconds)}",
        f"  open:        {d.url}",
    ]
    if d.training_url:
        lines.append(f"  training:    {d.training_url}")
    if d.parent_id:
        lines.append(f"  parent run:  {d.parent_id}")
    if d.children:
        lines.append(f"  child runs:  {len(d.children)} (shapebench show <id> for each)")
    for tag in _HEAD_TAGS:
        if d.tags.get(tag):
            lines.append(f"  {tag + ':':<26} {d.tags[tag]}")
    record = CellRecord.from_tags(d.tags)
    if d.metrics:
        lines.append("metrics:")
        for key, value in d.metrics.items():
            base = key.rsplit(".", 1)[0]
            card = record.card(base)
            shown = f"{value:.6g}"
            if card is not None and card.scale != 1 and key.endswith((".mean", ".std", ".median")):
                shown += f"  (x{card.scale:g}: {value * card.scale:.3f})"
            lines.append(f"  {key + ':':<26} {shown}")
    if d.artifacts:
        lines.append("artifacts:")
        lines += [f"  {a}" for a in d.artifacts]
    extra = {k: v for k, v in d.tags.items() if k not in _HEAD_TAGS}
    if all_tags:
        lines.append("tags:")
        lines += [f"  {k}: {v}" for k, v in extra.items() if k != rec.NOTE_TAG]
        lines.append("params:")
        lines += [f"  {k}: {v}" for k, v in d.params.items()]
    else:
        lines.append(f"({len(extra)} more tags and {len(d.params)} params: --all)")
    return lines


def details_json(d: RunDetails) -> str:
    return json.dumps(asdict(d), indent=2, default=str)
