"""Which runs and cells a board reads: a split's finished cells as a table, the runs of one
table (frame, context protocol, data version, the newest run per variant, context size and seed,
the newest variant per label), their row labels, and the per-object tables of their
``per_object.csv`` artifacts. Used by :mod:`~shapebench.boards.leaderboard` and the notebook
frames (:mod:`~shapebench.boards.frames`)."""

from __future__ import annotations

import tempfile
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pandas as pd

from shapebench.api.errors import ShapebenchError
from shapebench.api.protocol import DEFAULT_CONTEXT, DEFAULT_FRAME
from shapebench.store.tracking import Tracker


def load_runs(tracker: Tracker, exp_id: str) -> pd.DataFrame:
    """Every finished cell of experiment ``exp_id``, a row each (``run_id``, ``start`` and the
    columns of :meth:`~shapebench.store.records.CellRecord.row`), for :func:`select_runs`."""
    # Cells are read through their record (shapebench.store.records), the same code that wrote them.
    rows = [
        {"run_id": run_id, "start": start, **record.row()}
        for run_id, start, record in tracker.finished_cells(exp_id)
    ]
    table = pd.DataFrame(rows)
    if "variant_key" in table:  # runs logged before variant keys have none (see select_runs)
        table["variant_key"] = table["variant_key"].replace("", np.nan)
    return table


def per_object_tables(tracker: Tracker, runs: pd.DataFrame) -> Iterator[tuple[dict, pd.DataFrame]]:
    """Each run of ``runs`` (as a dict) with its ``per_object.csv`` artifact, read once."""
    with tempfile.TemporaryDirectory() as tmp:
        for i, run in enumerate(runs.to_dict("records")):
            dst = Path(tmp) / str(i)
            dst.mkdir()
            path = tracker.download_artifact(run["run_id"], "per_object.csv", dst)
            yield run, pd.read_csv(path, keep_default_na=False, na_values=[""])


def metric_per_object(tracker: Tracker, runs: pd.DataFrame, metric: str) -> pd.DataFrame:
    """A row per (run, object) of ``runs``: its variant, label, context size, seed, category,
    status, ``metric``'s value, seconds and why the metric does not apply (or "")."""
    frames = []
    for run, table in per_object_tables(tracker, runs):
        table["value"] = table.get(metric, np.nan)
        # Why the metric did not apply to an object (no mesh...): such objects have no value.
        reason = table.get(f"not_applicable.{metric}", pd.Series("", index=table.index))
        table["not_applicable"] = reason.fillna("").astype(str)
        table["variant"] = run["variant_key"]
        table["label"] = run["_label"]
        table["context"] = int(run["context_size"])
        table["seed"] = int(run["seed"])
        table["object"] = table["object"].astype(str)
        if "seconds" not in table:  # cost per object, for the cost columns
            table["seconds"] = np.nan
        # The category, for the category mean: the per-object table's (older tables: the
        # object id's first part, the layout of every built-in dataset).
        if "category" not in table:
            table["category"] = table["object"].str.split("/").str[0]
        table["category"] = table["category"].astype(str)
        cols = [
            "variant",
            "label",
            "context",
            "seed",
            "object",
            "category",
            "status",
            "value",
            "seconds",
            "not_applicable",
        ]
        frames.append(table[cols])
    return pd.concat(frames, ignore_index=True)


def run_column(runs: pd.DataFrame, name: str, default: str) -> pd.Series:
    """Column ``name`` of ``runs``, ``default`` where a run has none (or lacks the column)."""
    if name not in runs:
        return pd.Series(default, index=runs.index)
    return runs[name].fillna(default).replace("", default)


def select_runs(
    runs: pd.DataFrame,
    frame: str,
    data_version: str | None,
    all_variants: bool,
    protocol: str = DEFAULT_CONTEXT,
) -> tuple[pd.DataFrame, str, list[str]]:
    """The runs of one table: one frame, one context protocol (its name: ``sparse``,
    ``crop-0.5``...), one data version, the newest run per (variant, context, seed), and (unless
    ``all_variants``) the newest variant per label. Returns them, the chosen fingerprint and what
    was left out, in words."""
    left_out: list[str] = []
    legacy = runs["variant_key"].isna() if "variant_key" in runs else pd.Series(True, runs.index)
    if legacy.any():
        left_out.append(
            f"{int(legacy.sum())} runs logged before variant keys were recorded (rerun them)"
        )
    runs = runs[~legacy].copy()
    runs["_frame"] = run_column(runs, "frame", DEFAULT_FRAME)
    other_frame = runs[runs["_frame"] != frame]
    if len(other_frame):
        frames = ", ".join(sorted(other_frame["_frame"].unique()))
        left_out.append(f"{len(other_frame)} runs in another frame ({frames}; --frame)")
    runs = runs[runs["_frame"] == frame]
    runs["_protocol"] = run_column(runs, "context_protocol", DEFAULT_CONTEXT)
    other_protocol = runs[runs["_protocol"] != protocol]
    if len(other_protocol):
        names = ", ".join(sorted(other_protocol["_protocol"].unique()))
        left_out.append(
            f"{len(other_protocol)} runs with other contexts ({names}; --protocol, "
            "--crop-fraction, --context-noise)"
        )
    runs = runs[runs["_protocol"] == protocol]
    if runs.empty:
        return runs, "", left_out
    versions = runs.groupby("fingerprint")["start"].max().sort_values(ascending=False)
    if data_version:
        matches = [v for v in versions.index if str(v).startswith(data_version)]
        if len(matches) != 1:
            listing = ", ".join(str(v) for v in versions.index)
            raise ShapebenchError(
                f"--data-version {data_version!r} matches {len(matches)} of the data versions "
                f"with runs: {listing}",
                "give a prefix of exactly one fingerprint",
            )
        fingerprint = matches[0]
    else:
        fingerprint = versions.index[0]
    others = runs[runs["fingerprint"] != fingerprint]
    if len(others):
        counts = others.groupby("fingerprint").size()
        roots = (
            others.groupby("fingerprint")["data_root"].first()
            if ("data_root" in others)
            else pd.Series(dtype=str)
        )
        listed = "; ".join(
            f"{fp} ({n} runs{', ' + roots[fp] if fp in roots and roots[fp] else ''})"
            for fp, n in counts.items()
        )
        left_out.append(f"runs on other data versions: {listed} (--data-version FINGERPRINT)")
    runs = runs[runs["fingerprint"] == fingerprint]
    runs = label_runs(runs.drop_duplicates(subset=["variant_key", "context_size", "seed"]))
    newest = runs.groupby("_label")["start"].transform("max")
    variant_newest = runs.groupby("variant_key")["start"].transform("max")
    older = variant_newest < newest  # an older variant under a label a newer one uses
    if older.any():
        if all_variants:
            runs.loc[older, "_label"] = (
                runs.loc[older, "_label"] + "#" + runs.loc[older, "variant_key"].str[:6]
            )
        else:
            n_var = runs.loc[older, "variant_key"].nunique()
            left_out.append(
                f"{n_var} older variant(s) sharing a label with a newer one (code, checkpoint "
                "or version changed; --all-variants shows them)"
            )
            runs = runs[~older]
    return runs, str(fingerprint), left_out


def label_runs(runs: pd.DataFrame) -> pd.DataFrame:
    """``runs`` with the columns the tables read: ``_frame`` (the cell's frame) and ``_label``
    (its row label: the variant's label, or the method's name where it has none)."""
    runs = runs.copy()
    runs["_frame"] = run_column(runs, "frame", DEFAULT_FRAME)
    runs["_label"] = run_column(runs, "variant_label", "")
    runs.loc[runs["_label"] == "", "_label"] = runs["method"]
    return runs
