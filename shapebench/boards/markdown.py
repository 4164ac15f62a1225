"""A board as Markdown (``<dataset>-<split>.md``): the header (provenance, metric card, protocol,
choices, what a cell is), the table of raw and normalised cells with the best and tied marks, the
row list, the cost note, the figures' links and the paper's figures beside a table on their
frame."""

from __future__ import annotations

from datetime import datetime, timezone
from pathlib import Path

import numpy as np
import pandas as pd

from shapebench.api.metric import MetricCard
from shapebench.api.protocol import FRAMES, PAPER_FRAME
from shapebench.boards import stats as board_stats
from shapebench.boards.board import Board, Row, below_floor, floor_labels
from shapebench.boards.cards import card_text, higher_is_better, worse_word
from shapebench.boards.paper import PAPER_METHOD_ORDER
from shapebench.boards.splits import choices_text
from shapebench.store.tracking import experiment_name


def _seeds_text(seeds: tuple[int, ...]) -> str:
    return ("seed " if len(seeds) == 1 else "seeds ") + ", ".join(map(str, seeds))


#: The mark of a cell that is not significantly better than the table's floor.
FLOOR_MARK = "†"


def tail_text(board: Board, r: pd.Series) -> str:
    """The median and (with a tail threshold) the share of samples worse than it, of one raw
    cell: ``med. 1.07; 18% > 10``."""
    if "median" not in r or not np.isfinite(r["median"]):
        return ""
    text = f"med. {r['median']:.2f}"
    share = r.get("tail_share", np.nan)
    if board.tail_threshold is not None and share is not None and np.isfinite(share):
        sign = "<" if higher_is_better(board.metric, board.card) else ">"
        text += f"; {100 * share:.0f}% {sign} {board.tail_threshold:g}"
    return text


def cell_marks(board: Board, r: pd.Series, below: bool) -> str:
    """What follows a raw cell's mean in both table formats: the floor mark (``below``: not
    better than the floor), the median and tail share, the objects that did not fail."""
    text = f" {FLOOR_MARK}" if below else ""
    tail = tail_text(board, r)
    if tail:
        text += f" ({tail})"
    if r["failures"]:
        text += f" ({int(r['n_ok'])}/{int(r['n'])} ok)"
    return text


def card_line(board: Board) -> str:
    """The metric card in words, with the tail threshold the table reads it at."""
    text = card_text(board.card)
    if board.tail_threshold is not None:
        text += f"; tail threshold {board.tail_threshold:g}" + (
            f" (x{board.scale:g})" if board.scale != 1 else ""
        )
    return text


def floor_legend(board: Board) -> str:
    """What the floor mark means, naming the table's floor rows ("" without floor rows)."""
    names = floor_labels(board)
    if not names:
        return ""
    which = (
        f"the floor row `{names[0]}`"
        if len(names) == 1
        else "the better (by mean, at that size) of the floor rows "
        + ", ".join(f"`{n}`" for n in names)
    )
    return (
        f"{FLOOR_MARK}: not significantly better than {which} ({board_stats.TEST_NAME} across "
        f"the rows at that size, α = {board_stats.ALPHA}; a row is better only with a better "
        "mean and a corrected p below α; the floor rows themselves are not marked); the floor "
        "used and the p-values are in the CSV (`floor`, `p_vs_floor`, `p_floor_holm`, "
        "`below_floor`)."
    )


def _cell(board: Board, row: Row, ctx: int) -> str:
    r = board.raw[(board.raw.variant == row.variant) & (board.raw.context == ctx)]
    if r.empty:
        return "n/a" if row.variant in board.not_applicable else "–"
    r = r.iloc[0]
    if r["n_ok"] == 0:
        return f"failed (0/{int(r['n'])})"
    text = f"{r['mean']:.2f} ± {r['std']:.2f}"
    sig = board.significance[
        (board.significance.variant == row.variant) & (board.significance.context == ctx)
    ]
    if not sig.empty and bool(sig.iloc[0]["best"]):
        text = f"**{text}**"
    elif not sig.empty and bool(sig.iloc[0]["tied"]):
        text += " ≈"
    floor = below_floor(board, row.variant, ctx)
    return text + cell_marks(board, r, floor is not None and bool(floor["below_floor"]))


def _norm_cell(board: Board, row: Row, ctx: int) -> str:
    if row.label == board.reference:
        return "1"
    df = board.normalized
    if df is None or df.empty:
        return "–"
    r = df[(df.variant == row.variant) & (df.context == ctx)]
    if r.empty or np.isnan(r.iloc[0]["mean"]):
        return "–"
    return f"{r.iloc[0]['mean']:.2f} ± {r.iloc[0]['std']:.2f}"


def _fmt_overrides(overrides: dict) -> str:
    if not overrides:
        return "the profile's defaults"
    return ", ".join(f"{k}={v}" if v is not True else k for k, v in sorted(overrides.items()))


def _cost_cells(board: Board, row: Row) -> list[str]:
    """The row's test time per object and training cost, when the board has costs."""
    from shapebench.boards.cost import describe_seconds, describe_training

    if board.costs is None:
        return []
    cost = board.costs[board.costs["variant"] == row.variant]
    if cost.empty:
        return ["–", "–"]
    c = cost.iloc[0]
    return [describe_seconds(c["seconds_per_object"]), describe_training(c)]


def render_markdown(
    board: Board, command: str, uri: str, figures: dict[str, Path] | None = None
) -> str:
    ctxs = board.contexts
    card = MetricCard.from_tag(board.card) if "=" in board.card else None
    scale_txt = f"x{card.scale:g}" if card and card.scale != 1 else ""
    pooled = len({seed for row in board.rows for seed in row.seeds}) > 1
    # With several seeds in the table a sample is an (object, seed) pair, and rows may differ in
    # their seeds: the row list says which each one pools.
    samples = "(object, seed) pairs (each row's seeds are listed below)" if pooled else "objects"
    same_seed = ", seed" if pooled else ""
    version = f"dataset fingerprint `{board.fingerprint}`"
    if board.data_root:
        version += f", data root `{board.data_root}`"
    lines = [
        f"# {board.dataset} / {board.split}: {board.metric} ({board.frame} frame)",
        "",
        f"Generated {datetime.now(timezone.utc):%Y-%m-%d %H:%M UTC} by `{command}` from the "
        f"MLflow runs of experiment `{experiment_name(board.dataset, board.split)}` "
        f"(id {board.experiment_id}) in `{uri}`; {version}.",
        "",
        f"**Metric card**: {card_line(board)}.",
        "",
        f"**Protocol**: {board.protocol}; distances in the {FRAMES[board.frame][1]}.",
        "",
        f"**Choices**: {choices_text(board.dataset, board.split)}",
        "",
        f"Raw: mean ± std over {samples} of {board.metric}{' ' + scale_txt if scale_txt else ''}"
        " (every object weighs the same; the mean of the per-category means, PCN's 'overall', "
        "is the CSV's `category_mean`; each category's mean and median are in the "
        "`-categories.csv` beside this table). "
        + _tail_sentence(board, samples)
        + "Normalised: per object "
        f"divided by `{board.reference}` on the same object{same_seed} and context size, then "
        "mean ± std (the paper's eq. 8).",
        "",
    ]
    for item in board.left_out:
        lines += [f"Left out: {item}.", ""]
    header = (
        ["Method"]
        + [f"raw {c}" for c in ctxs]
        + [f"norm. {c}" for c in ctxs]
        + ["objects", "failed (per context)"]
        + (["test time / object", "training"] if board.costs is not None else [])
    )
    lines += ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    for row in board.rows:
        raw = board.raw[board.raw.variant == row.variant]
        n = str(int(raw["n"].max())) if len(raw) else "–"
        fails = "/".join(
            str(int(raw[raw.context == c]["failures"].sum())) if c in set(raw.context) else "–"
            for c in ctxs
        )
        cells = [_cell(board, row, c) for c in ctxs] + [_norm_cell(board, row, c) for c in ctxs]
        name = f"{row.display} (`{row.label}`)"
        cells += [n, fails] + _cost_cells(board, row)
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    direction = "highest" if higher_is_better(board.metric, board.card) else "lowest"
    lines += [
        "",
        f"**Bold**: the {direction} mean at that context size; ≈: not significantly different "
        f"from it ({board_stats.TEST_NAME} across the rows at that size, α = "
        f"{board_stats.ALPHA}); p-values are in the CSV (`p_vs_best`, `p_holm`). A failed object "
        "scores as the worst successful score of its cell, (n_ok/n ok) says how many succeeded, "
        "and the success-only mean is in the CSV (`mean_ok`).",
        *([""] + [floor_legend(board)] if floor_legend(board) else []),
        *_not_applicable_lines(board),
        "",
        "Rows (options that differ from the profile's defaults):",
        "",
    ]
    for row in board.rows:
        extra = f"; code `{row.code}`" if row.code else ""
        if len({key for _, key in row.checkpoints}) > 1:
            keys = ", ".join(f"seed {seed} `{key[:16]}`" for seed, key in row.checkpoints)
            extra += f"; checkpoints {keys}"
        elif row.checkpoint:
            extra += f"; checkpoint `{row.checkpoint[:16]}`"
        if row.seeds:
            extra += f"; {_seeds_text(row.seeds)}"
        lines.append(f"* `{row.label}`: {row.method}, {_fmt_overrides(row.overrides)}{extra}")
    if board.costs is not None:
        lines += [
            "",
            "**Cost**: test time is the method's wall time per successfully completed object "
            "(mean over the row's cells); training is per training run (mean over the row's "
            "seeds): device-hours = devices x wall time, with the device, the optimiser steps "
            "(and the epochs they made) and the final loss. "
            '"reference weights": the row used the checkpoint shipped with shapebench for its '
            "key (trained once, elsewhere; the cost is that training's), not a local training.",
        ]
    if figures:
        lines += ["", *(f"![{name}]({path.name})" for name, path in figures.items())]
    lines += _paper_section(board, header[: len(header) - (2 if board.costs is not None else 0)])
    if board.note:
        lines += ["", f"> {board.note}"]
    return "\n".join(lines) + "\n"


def _tail_sentence(board: Board, samples: str) -> str:
    """What the parenthesis beside each mean says."""
    pooled = samples.split(" (")[0]
    text = "Beside each mean (med. ...): the median"
    if board.tail_threshold is not None:
        worse = worse_word(higher_is_better(board.metric, board.card))
        text += (
            f" and the share of {pooled} {worse} {board.tail_threshold:g}, the tail threshold "
            "of the metric card (`--tail-threshold` sets another)"
        )
    return text + ", under the same failure rule as the mean. "


def _not_applicable_lines(board: Board) -> list[str]:
    """Why some rows show n/a: the metric does not apply to them (never a failure or a 0)."""
    labels = {r.variant: r.label for r in board.rows}
    return (
        [
            "",
            *(
                f"n/a: {board.metric} does not apply to `{labels.get(v, v)}`: {reason} (those "
                "objects are neither failures nor values)."
                for v, reason in sorted(
                    board.not_applicable.items(), key=lambda kv: labels.get(kv[0], kv[0])
                )
            ),
        ]
        if board.not_applicable
        else []
    )


def _paper_section(board: Board, header: list[str]) -> list[str]:
    if board.paper.empty:
        return []
    if board.frame != PAPER_FRAME:
        return [
            "",
            f"> The paper's figures are on the {PAPER_FRAME} scale (see docs/metrics.md), not "
            f"this table's: run with `--frame {PAPER_FRAME}` and build this leaderboard with "
            f"`--frame {PAPER_FRAME}` to see them beside ours.",
        ]
    ctxs = board.contexts
    lines = [
        "",
        "**The paper's figures** (as published, not rerun here; comparable with the table above "
        "in magnitude, on the same frame and card):",
        "",
        "| " + " | ".join(header[:-2]) + " |",
        "|" + "---|" * (len(header) - 2),
    ]
    for display in PAPER_METHOD_ORDER:
        rows = board.paper[board.paper.method == display]
        if rows.empty:
            continue
        cells = []
        for kind in ("raw_x1000", "normalized"):
            for c in ctxs:
                r = rows[(rows.kind == kind) & (rows.context == c)]
                if r.empty:
                    cells.append("–")
                elif np.isnan(r.iloc[0]["std"]):
                    cells.append(f"{r.iloc[0]['mean']:.2f}")
                else:
                    cells.append(f"{r.iloc[0]['mean']:.2f} ± {r.iloc[0]['std']:.2f}")
        lines.append(f"| {display} (paper) | " + " | ".join(cells) + " |")
    return lines
