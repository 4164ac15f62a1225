"""A board as a tidy CSV (``<dataset>-<split>.csv``): a line per row, context size and kind (raw,
normalised, not applicable), with the significance and floor columns, the median and tail, the
row's cost and, beside a table on the paper's frame, the paper's figures; and its per-category
means as a long CSV beside it (``<dataset>-<split>-categories.csv``)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from shapebench.api.protocol import PAPER_FRAME
from shapebench.boards.board import Board


def tidy_csv(board: Board) -> pd.DataFrame:
    labels = {r.variant: r for r in board.rows}
    frames = []
    raw = board.raw.merge(board.significance, on=["variant", "context"], how="left")
    if board.floors is not None and not board.floors.empty:
        raw = raw.merge(_floor_columns(board), on=["variant", "context"], how="left")
    raw = raw.assign(tail_threshold=board.tail_threshold)
    frames.append(raw.assign(source="shapebench", kind="raw"))
    if board.normalized is not None and not board.normalized.empty:
        frames.append(board.normalized.assign(source="shapebench", kind="normalized"))
    if board.not_applicable:  # a line per context for rows the metric does not apply to
        frames.append(
            pd.DataFrame(
                [
                    {
                        "variant": v,
                        "label": labels[v].label if v in labels else "",
                        "context": c,
                        "not_applicable": reason,
                    }
                    for v, reason in board.not_applicable.items()
                    for c in board.contexts
                ]
            ).assign(source="shapebench", kind="not_applicable")
        )
    out = pd.concat(frames, ignore_index=True)
    out["method"] = out["variant"].map(lambda v: labels[v].method if v in labels else "")
    out["display"] = out["variant"].map(lambda v: labels[v].display if v in labels else "")
    show_paper = board.frame == PAPER_FRAME and not board.paper.empty
    if show_paper:
        p = board.paper.rename(columns={"method": "display"})
        p = p.assign(
            source="paper",
            method="",
            label="",
            variant="",
            kind=p.kind.map({"raw_x1000": "raw", "normalized": "normalized"}),
        )
        out = pd.concat(
            [
                out,
                p[
                    [
                        "source",
                        "display",
                        "context",
                        "kind",
                        "mean",
                        "std",
                        "method",
                        "label",
                        "variant",
                    ]
                ],
            ],
            ignore_index=True,
        )
    if board.costs is not None:  # the row's cost, on each of its lines
        from shapebench.boards.cost import COST_COLUMNS

        out = out.merge(board.costs, on="variant", how="left")
    out = out.assign(
        dataset=board.dataset,
        split=board.split,
        metric=board.metric,
        reference=board.reference,
        card=board.card,
        frame=board.frame,
        fingerprint=board.fingerprint,
    )
    cols = [
        "source",
        "dataset",
        "split",
        "metric",
        "frame",
        "fingerprint",
        "kind",
        "method",
        "label",
        "variant",
        "display",
        "context",
        "mean",
        "std",
        "median",
        "tail_threshold",
        "tail_share",
        "mean_ok",
        "std_ok",
        "n",
        "n_ok",
        "failures",
        "category_mean",
        "categories",
        "best",
        "tied",
        "p_vs_best",
        "p_holm",
        "n_pairs",
        "floor",
        "p_vs_floor",
        "p_floor_holm",
        "below_floor",
        "reference",
        "card",
    ]
    if board.costs is not None:
        cols += COST_COLUMNS
    if board.not_applicable:  # only then: the CSVs of other tables keep their columns
        cols.append("not_applicable")
    for c in cols:
        if c not in out:
            out[c] = np.nan
    return out[cols]


def _floor_columns(board: Board) -> pd.DataFrame:
    """Per (variant, context) of the raw table: ``floor`` (the floor row's label), the p-values
    against it and ``below_floor``; the floor row itself names itself and is not below."""
    columns = ["variant", "context", "floor", "p_vs_floor", "p_floor_holm", "below_floor"]
    labels = {r.variant: r.label for r in board.rows}
    tested = board.floors.copy()
    floors = tested.drop_duplicates("context")[["context", "floor"]]
    itself = floors.assign(
        variant=floors["floor"], p_vs_floor=np.nan, p_floor_holm=np.nan, below_floor=False
    )
    out = pd.concat([tested, itself[tested.columns]], ignore_index=True)
    out["floor"] = out["floor"].map(lambda v: labels.get(v, v))
    out["below_floor"] = out["below_floor"].astype(object)
    return out[columns]


def category_csv_path(md: Path) -> Path:
    """``<table>-categories.csv`` beside the table's Markdown."""
    return md.with_name(f"{md.stem}-categories.csv")


def category_csv(board: Board) -> pd.DataFrame:
    """The board's per-category means as a long table: a line per (row, context size,
    category) with the ``mean`` and ``median`` under the failure rule (displayed units) over
    ``n`` samples; the raw CSV's ``category_mean`` is the mean of these means."""
    labels = {r.variant: r for r in board.rows}
    cats = board.categories if board.categories is not None else pd.DataFrame()
    cols = [
        "dataset",
        "split",
        "metric",
        "frame",
        "fingerprint",
        "method",
        "label",
        "variant",
        "display",
        "context",
        "category",
        "mean",
        "median",
        "n",
        "card",
    ]
    if cats.empty:
        return pd.DataFrame(columns=cols)
    out = cats.assign(
        method=cats["variant"].map(lambda v: labels[v].method if v in labels else ""),
        label=cats["variant"].map(lambda v: labels[v].label if v in labels else ""),
        display=cats["variant"].map(lambda v: labels[v].display if v in labels else ""),
        dataset=board.dataset,
        split=board.split,
        metric=board.metric,
        frame=board.frame,
        fingerprint=board.fingerprint,
        card=board.card,
    )
    order = {r.variant: i for i, r in enumerate(board.rows)}
    out = out.assign(_order=out["variant"].map(order)).sort_values(
        ["_order", "context", "category"], kind="stable"
    )
    return out[cols].reset_index(drop=True)
