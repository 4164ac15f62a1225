"""Results as pandas DataFrames, for notebooks: the store read the way the leaderboard reads it.

    import shapebench
    scores = shapebench.load_results("synthetic", "trained")     # one row per (object, cell)
    table = shapebench.load_leaderboard("synthetic", "trained")  # the leaderboard's CSV

Both select runs as ``shapebench leaderboard`` does (one frame, one data version, the newest run
per row, context size and seed, the newest variant per label) and read each cell through its
record (:mod:`shapebench.store.records`) and its ``per_object.csv`` artifact, so user code parses
no MLflow tags. The store is the workspace's (``./shapebench-runs``, ``$SHAPEBENCH_WORKSPACE``) or
``tracking_uri``, exactly as for the CLI. Exported from :mod:`shapebench`; docs/python.md shows
them at work.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from shapebench.api.errors import ShapebenchError
from shapebench.api.protocol import DEFAULT_CONTEXT, DEFAULT_FRAME
from shapebench.boards.leaderboard import BoardQuery, build_board
from shapebench.boards.selection import label_runs, load_runs, per_object_tables, select_runs
from shapebench.boards.splits import splits_with_runs
from shapebench.boards.tidy import tidy_csv
from shapebench.config import make_settings
from shapebench.store.records import CARD_PREFIX
from shapebench.store.tracking import Tracker, experiment_name

#: The identity columns of :func:`load_results`, first in every row, in this order.
RESULT_COLUMNS = (
    "method",
    "label",
    "variant",
    "dataset",
    "split",
    "context",
    "seed",
    "object",
    "category",
    "protocol",
    "frame",
    "failed",
    "reason",
    "run_id",
)


def _tracker(workspace: str | Path | None, tracking_uri: str | None) -> Tracker:
    return Tracker(make_settings(tracking_uri, None, None, workspace))


def _no_runs(dataset: str, split: str | None, uri: str) -> ShapebenchError:
    where = f"{dataset}" + (f"/{split}" if split else "")
    return ShapebenchError(
        f"no finished runs of {where} in {uri}",
        f"run one first (shapebench run -m gauss -d {dataset}), or pass workspace= or "
        "tracking_uri= to read another store",
    )


def load_results(
    dataset: str,
    split: str | None = None,
    *,
    metric: str | None = None,
    frame: str = DEFAULT_FRAME,
    data_version: str | None = None,
    workspace: str | Path | None = None,
    tracking_uri: str | None = None,
    protocol: str = DEFAULT_CONTEXT,
) -> pd.DataFrame:
    """One row per (object, cell) of ``dataset`` (every split with runs, or ``split``), of one
    context protocol (``protocol``: ``sparse``, the paper's, or a name like ``crop-0.5``).

    Columns: :data:`RESULT_COLUMNS` (``label`` is the leaderboard's row label, e.g.
    ``gauss[sigma=0.05]``; ``variant`` its key; ``protocol`` ``points`` or ``points+normals``,
    after the context protocol when it is not the paper's (``crop-0.5: points``);
    ``failed`` True where the method produced nothing for the object, with ``reason``), then one
    column per metric the cell scored (``metric=`` keeps that one), in the units the metric
    computes (the tables' x1000 is a display scale). Failed objects have NaN scores: the
    leaderboard's failure rule (worst successful score of the cell) is applied by
    :func:`load_leaderboard`, not here.
    """
    tracker = _tracker(workspace, tracking_uri)
    splits = [split] if split else splits_with_runs(tracker, dataset)
    frames = []
    for one in splits:
        exp_id = tracker.experiment_id(experiment_name(dataset, one), create=False)
        runs = load_runs(tracker, exp_id) if exp_id is not None else pd.DataFrame()
        if not runs.empty:
            runs, _, _ = select_runs(runs, frame, data_version, False, protocol)
        if not runs.empty:
            frames.append(_per_object_rows(tracker, runs, one))
    if not frames:
        raise _no_runs(dataset, split, tracker.uri)
    table = _ordered(pd.concat(frames, ignore_index=True))
    metrics = [c for c in table.columns if c not in RESULT_COLUMNS]
    if metric is not None:
        if metric not in metrics:
            raise ShapebenchError(
                f"no run of {dataset} recorded metric {metric!r}",
                f"metrics with values: {', '.join(metrics) or 'none'}",
            )
        metrics = [metric]
    return table[list(RESULT_COLUMNS) + metrics]


def results_of_runs(tracker: Tracker, dataset: str, run_ids: dict[str, list[str]]) -> pd.DataFrame:
    """:func:`load_results`' rows of exactly the cells ``run_ids`` names (split -> run ids of
    finished cells of ``dataset``), whatever their frame, data version or age: what
    :func:`shapebench.evaluate` ran."""
    frames = []
    for split, ids in run_ids.items():
        exp_id = tracker.experiment_id(experiment_name(dataset, split), create=False)
        runs = load_runs(tracker, exp_id) if exp_id is not None else pd.DataFrame()
        runs = runs[runs["run_id"].isin(ids)] if not runs.empty else runs
        if len(runs) != len(set(ids)):
            raise ShapebenchError(
                f"{len(set(ids)) - len(runs)} of the {len(set(ids))} cells of {dataset}/{split} "
                f"just run are not finished runs in {tracker.uri}",
                "another process may have deleted them; run again",
            )
        frames.append(_per_object_rows(tracker, label_runs(runs), split))
    return _ordered(pd.concat(frames, ignore_index=True))


def _ordered(table: pd.DataFrame) -> pd.DataFrame:
    """The identity columns first, then the metrics; rows by split, label, context, seed, object."""
    metrics = [c for c in table.columns if c not in RESULT_COLUMNS]
    return table[list(RESULT_COLUMNS) + metrics].sort_values(
        ["split", "label", "context", "seed", "object"], ignore_index=True
    )


def _per_object_rows(tracker: Tracker, runs: pd.DataFrame, split: str) -> pd.DataFrame:
    out = []
    for run, table in per_object_tables(tracker, runs):
        # The metrics the cell scored: those with a card (CellRecord.row's card columns).
        scores = [
            m[len(CARD_PREFIX) :]
            for m, card in run.items()
            if m.startswith(CARD_PREFIX) and isinstance(card, str)
        ]
        rows = pd.DataFrame(
            {
                "method": run["method"],
                "label": run["_label"],
                "variant": run["variant_key"],
                "dataset": run["dataset"],
                "split": split,
                "context": int(run["context_size"]),
                "seed": int(run["seed"]),
                "object": table["object"].astype(str),
                "category": _text(table, "category"),
                "protocol": _protocol_text(run),
                "frame": run["_frame"],
                "failed": table["status"] != "ok",
                "reason": _text(table, "error"),
                "run_id": run["run_id"],
            }
        )
        for name in scores:
            rows[name] = table[name].astype(float) if name in table else np.nan
        out.append(rows)
    return pd.concat(out, ignore_index=True)


def _protocol_text(run: dict) -> str:
    """``points`` or ``points+normals``, after the context protocol when it is not the paper's
    (``crop-0.5: points``)."""
    carried = "points+normals" if run.get("context_normals") else "points"
    context = run.get("context_protocol")
    return f"{context}: {carried}" if isinstance(context, str) and context else carried


def _text(table: pd.DataFrame, column: str) -> pd.Series:
    """A text column of a per-object table, "" where empty or missing (not NaN)."""
    if column not in table:
        return pd.Series("", index=table.index)
    values = table[column].astype(object)
    return values.where(values.notna(), "")


def load_leaderboard(
    dataset: str,
    split: str,
    *,
    reference: str = "msc-noopt",
    metric: str | None = None,
    frame: str = DEFAULT_FRAME,
    data_version: str | None = None,
    workspace: str | Path | None = None,
    tracking_uri: str | None = None,
    protocol: str = DEFAULT_CONTEXT,
    floors: list[str] | None = None,
    tail: float | None = None,
) -> pd.DataFrame:
    """The table ``shapebench leaderboard`` writes as ``<dataset>-<split>.csv``: one row per
    (kind, row label, context size), ``kind`` ``raw`` (mean, std and median in the table's
    scale, x1000 for Chamfer, and ``tail_share``: the share of samples worse than
    ``tail_threshold``) or ``normalised`` (per object divided by ``reference``), with the
    significance columns (``best``, ``tied``, ``p_vs_best``, ``p_holm``), the floor columns
    (``floor``, ``p_vs_floor``, ``p_floor_holm``, ``below_floor``; ``floors`` as
    ``--floor``, None for the defaults) and the training cost. ``tail``: the tail threshold
    (default: the metric card's)."""
    tracker = _tracker(workspace, tracking_uri)
    query = BoardQuery(
        dataset,
        reference,
        metric,
        frame,
        data_version,
        floors=None if floors is None else tuple(floors),
        tail=tail,
    )
    board = build_board(tracker, query, split, protocol)
    if board is None:
        raise _no_runs(dataset, split, tracker.uri)
    return tidy_csv(board)
