"""A board as a tidy CSV (``<dataset>-<split>.csv``): a line per row, context size and kind (raw,
normalised, not applicable), with the significance columns, the row's cost and, beside a table
on the paper's frame, the paper's figures."""

from __future__ import annotations

import numpy as np
import pandas as pd

from shapebench.api.protocol import PAPER_FRAME
from shapebench.boards.board import Board


def tidy_csv(board: Board) -> pd.DataFrame:
    labels = {r.variant: r for r in board.rows}
    frames = []
    raw = board.raw.merge(board.significance, on=["variant", "context"], how="left")
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
