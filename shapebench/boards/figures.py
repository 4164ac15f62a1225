"""Figures of a leaderboard, drawn headless with matplotlib (Agg, no pyplot state).

* :func:`context_curve`: the metric against context size (log x axis), one line per leaderboard
  row, with a 95% bootstrap confidence band of the mean over the per-object values (the same
  values, failure rule included, that the table's mean ± std summarise).
* :func:`pareto`: the metric at one context size (50 points when the table has it) against
  test-time seconds per object, marker area by training device-hours (hollow: no training).
* :func:`scaling_curve`: the metric at the smallest and the largest context size against the
  number of training shapes (log x axis), one line per method and step budget, with the same
  bootstrap band; drawn when some method was trained at two or more training-set sizes (the
  data-scaling sweep, ``configs/sweeps/data-scaling.yaml``).

:func:`write_board_figures` writes both beside the leaderboard as PNG and SVG; they are logged to
the table's MLflow run by :func:`log_board_artifacts`.
"""

from __future__ import annotations

import io
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import pandas as pd

if TYPE_CHECKING:
    from shapebench.boards.board import Board

#: Bootstrap resamples behind a confidence band, and the band's level.
BOOTSTRAP = 2000
LEVEL = 0.95
#: The context size the Pareto figure compares at, when the table has it.
PARETO_CONTEXT = 50


def bootstrap_band(values: np.ndarray, seed: int = 0) -> tuple[float, float]:
    """The ``LEVEL`` percentile interval of the mean of ``values`` over ``BOOTSTRAP`` resamples;
    seeded, so a leaderboard rebuilt from the same runs draws the same band."""
    v = np.asarray(values, dtype=float)
    v = v[np.isfinite(v)]
    if len(v) < 2:
        m = float(v.mean()) if len(v) else np.nan
        return m, m
    rng = np.random.default_rng(seed)
    means = v[rng.integers(0, len(v), (BOOTSTRAP, len(v)))].mean(axis=1)
    tail = (1 - LEVEL) / 2 * 100
    return float(np.percentile(means, tail)), float(np.percentile(means, 100 - tail))


def curve_table(scored: pd.DataFrame, scale: float = 1.0) -> pd.DataFrame:
    """Per (label, context): mean, band low/high and n of ``scored`` (times ``scale``)."""
    rows = []
    for (label, ctx), g in scored.groupby(["label", "context"], sort=True):
        v = g["scored"].to_numpy(dtype=float) * scale
        lo, hi = bootstrap_band(v)
        rows.append(
            {
                "label": label,
                "context": int(ctx),
                "mean": float(np.nanmean(v)),
                "low": lo,
                "high": hi,
                "n": int(np.isfinite(v).sum()),
            }
        )
    return pd.DataFrame(rows, columns=["label", "context", "mean", "low", "high", "n"])


def _new_figure(width: float, height: float):
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(width, height), dpi=100)
    FigureCanvasAgg(fig)
    return fig


def context_curve(
    scored: pd.DataFrame, labels: Sequence[str], ylabel: str, title: str, scale: float = 1.0
):
    """One line per label in ``labels`` (table order) over the context sizes, log x axis, with
    its confidence band; a row that ran one context size only is a point with an error bar."""
    table = curve_table(scored, scale)
    contexts = sorted(table["context"].unique().tolist())
    fig = _new_figure(7.5, 4.5)
    ax = fig.add_subplot()
    cmap = _colours(len(labels))
    for i, label in enumerate(labels):
        t = table[table["label"] == label].sort_values("context")
        if t.empty:
            continue
        ax.plot(t["context"], t["mean"], marker="o", ms=4, color=cmap[i], label=_wrap(label))
        ax.fill_between(t["context"], t["low"], t["high"], color=cmap[i], alpha=0.18, lw=0)
    ax.set_xscale("log")
    ax.set_xticks(contexts)
    ax.set_xticklabels([str(c) for c in contexts])
    ax.minorticks_off()
    ax.set_xlabel("context points (log scale)")
    ax.set_ylabel(ylabel)
    ax.set_title(title, fontsize=10)
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.01, 1.0), frameon=False)
    fig.text(
        0.01,
        0.01,
        f"band: {LEVEL:.0%} bootstrap interval of the mean over objects",
        fontsize=7,
        color="#666666",
    )
    fig.subplots_adjust(left=0.1, right=0.72, bottom=0.14, top=0.92)
    return fig


def pareto(points: pd.DataFrame, xlabel: str, ylabel: str, title: str):
    """``points``: one row per leaderboard row with ``label``, ``value`` (the metric),
    ``seconds_per_object`` and ``train_device_hours`` (NaN: no training)."""
    fig = _new_figure(7.5, 4.5)
    ax = fig.add_subplot()
    pts = points[np.isfinite(points["value"]) & np.isfinite(points["seconds_per_object"])]
    hours = pts["train_device_hours"].to_numpy(dtype=float)
    top = np.nanmax(hours) if np.isfinite(hours).any() else 1.0
    cmap = _colours(len(points))
    for i, (_, p) in enumerate(points.iterrows()):
        if p.name not in pts.index:
            continue
        h = p["train_device_hours"]
        trained = bool(np.isfinite(h))
        size = 40 + 900 * np.sqrt(h / top) if trained and top > 0 else 40
        ax.scatter(
            [p["seconds_per_object"]],
            [p["value"]],
            s=size,
            color=cmap[i],
            alpha=0.75,
            edgecolors=cmap[i],
            linewidths=1.5,
            facecolors=cmap[i] if trained else "none",
            label=p["label"],
        )
        name = _wrap(p["label"])
        note = f"{name}\n{h:.2g} device-h" if trained else f"{name}\nno training"
        ax.annotate(
            note,
            (p["seconds_per_object"], p["value"]),
            fontsize=7,
            xytext=(6, 6),
            textcoords="offset points",
        )
    ax.set_xscale("log")
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    ax.set_title(title, fontsize=10)
    ax.grid(True, alpha=0.3)
    ax.margins(0.2)
    fig.text(
        0.01,
        0.01,
        "marker area: training device-hours (hollow: trains nothing); lower left is better",
        fontsize=7,
        color="#666666",
    )
    fig.subplots_adjust(left=0.1, right=0.97, bottom=0.14, top=0.92)
    return fig


def scaling_points(board: Board) -> pd.DataFrame:
    """Per trained row: its method's display name, its training shapes and optimiser steps (from
    its training runs) and its label; rows whose trainings did not record both are left out."""
    if board.costs is None or "train_shapes" not in board.costs:
        return pd.DataFrame(columns=["variant", "label", "display", "shapes", "steps"])
    costs = board.costs.set_index("variant")
    rows = []
    for row in board.rows:
        if row.variant not in costs.index:
            continue
        shapes, steps = costs.loc[row.variant, ["train_shapes", "train_steps"]]
        if np.isfinite(shapes) and np.isfinite(steps):
            rows.append(
                {
                    "variant": row.variant,
                    "label": row.label,
                    "display": row.display,
                    "shapes": int(round(shapes)),
                    "steps": int(round(steps)),
                }
            )
    return pd.DataFrame(rows, columns=["variant", "label", "display", "shapes", "steps"])


def scaling_curve(board: Board, ylabel: str, title: str, scale: float = 1.0):
    """The metric against training shapes at the board's smallest and largest context sizes
    (two panels), one line per (method, step budget), with its bootstrap band; a budget trained
    at one size only (the data-scaling sweep's 4x and 16x) is a point with an error bar. None
    when no method was trained at two sizes or more."""
    points = scaling_points(board)
    if points.empty or points.groupby("display")["shapes"].nunique().max() < 2:
        return None
    scored = board.scored[board.scored["variant"].isin(points["variant"])]
    table = curve_table(scored, scale).merge(
        points[["label", "display", "shapes", "steps"]], on="label"
    )
    contexts = sorted({min(board.contexts), max(board.contexts)})
    displays = list(dict.fromkeys(points["display"]))
    cmap = _colours(len(displays))
    fig = _new_figure(11, 4.5)
    axes = [fig.add_subplot(1, len(contexts), i + 1) for i in range(len(contexts))]
    for ax, ctx in zip(axes, contexts, strict=True):
        at = table[table["context"] == ctx]
        for i, display in enumerate(displays):
            mine = at[at["display"] == display]
            # The budget trained at the most sizes is the line; the others are points.
            budgets = mine.groupby("steps")["shapes"].nunique().sort_values(ascending=False)
            for rank, steps in enumerate(budgets.index):
                t = mine[mine["steps"] == steps].sort_values("shapes")
                name = display if rank == 0 else f"{display}, {steps} steps"
                style = dict(color=cmap[i], marker="os^dv"[rank % 5], ms=5)
                if len(t) > 1:
                    ax.plot(t["shapes"], t["mean"], label=name, **style)
                    ax.fill_between(t["shapes"], t["low"], t["high"], color=cmap[i], alpha=0.15)
                else:
                    err = [t["mean"] - t["low"], t["high"] - t["mean"]]
                    ax.errorbar(t["shapes"], t["mean"], yerr=err, ls="none", label=name, **style)
        ax.set_xscale("log")
        sizes = sorted(table["shapes"].unique().tolist())
        ax.set_xticks(sizes)
        ax.set_xticklabels([str(s) for s in sizes])
        ax.minorticks_off()
        ax.set_xlabel("training shapes (log scale)")
        ax.set_ylabel(ylabel)
        ax.set_title(f"{ctx} context points", fontsize=10)
        ax.grid(True, alpha=0.3)
    axes[-1].legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1.0), frameon=False)
    fig.suptitle(title, fontsize=10)
    fig.text(
        0.01,
        0.01,
        f"band / bar: {LEVEL:.0%} bootstrap interval of the mean over objects; "
        "lines: one step budget at every size",
        fontsize=7,
        color="#666666",
    )
    fig.subplots_adjust(left=0.06, right=0.8, bottom=0.14, top=0.88, wspace=0.25)
    return fig


def _wrap(label: str, width: int = 28) -> str:
    """A variant label over several lines (``msc[epochs=1,...]`` can be very long)."""
    import textwrap

    return textwrap.fill(label.replace(",", ", "), width, break_long_words=True)


def _colours(n: int) -> list:
    from matplotlib import colormaps

    cmap = colormaps["tab10" if n <= 10 else "tab20"]
    return [cmap(i % cmap.N) for i in range(max(n, 1))]


def line_count(fig: Any) -> int:
    """Data lines drawn on the figure's axes (matplotlib ``Line2D`` with more than 0 points)."""
    return sum(1 for ax in fig.axes for line in ax.get_lines() if len(line.get_xdata()))


def save(fig: Any, stem: Path) -> list[Path]:
    """``stem``.png and ``stem``.svg; refuses to write a figure with nothing drawn."""
    from shapebench.evaluation.pictures import is_blank

    buf = io.BytesIO()
    fig.savefig(buf, format="png")
    png = buf.getvalue()
    if is_blank(png):
        raise RuntimeError(f"figure {stem.name} came out blank")
    stem.parent.mkdir(parents=True, exist_ok=True)
    paths = [stem.with_suffix(".png"), stem.with_suffix(".svg")]
    paths[0].write_bytes(png)
    fig.savefig(paths[1], format="svg")
    return paths


def pareto_points(board: Board) -> tuple[pd.DataFrame, int]:
    """The Pareto figure's rows (table order) and the context size they compare at."""
    ctx = PARETO_CONTEXT if PARETO_CONTEXT in board.contexts else min(board.contexts)
    raw = board.raw[board.raw["context"] == ctx].set_index("variant")["mean"]
    costs = board.costs.set_index("variant") if board.costs is not None else pd.DataFrame()
    rows = []
    for row in board.rows:
        cost = costs.loc[row.variant] if row.variant in costs.index else {}
        rows.append(
            {
                "label": row.label,
                "value": float(raw.get(row.variant, np.nan)),
                "seconds_per_object": float(cost.get("seconds_per_object", np.nan)),
                "train_device_hours": float(cost.get("train_device_hours", np.nan)),
            }
        )
    return pd.DataFrame(rows), ctx


def board_figures(board: Board) -> dict[str, Any]:
    """``{"chamfer": Figure, "pareto": Figure}`` of a built leaderboard (the first named for the
    dataset's primary metric, Chamfer on every built-in dataset), and ``"scaling"`` when some
    method was trained at two training-set sizes or more."""
    from shapebench.api.metric import MetricCard

    scale = board.scale
    unit = f" x{scale:g}" if scale != 1 else ""
    where = f"{board.dataset} / {board.split}"
    ylabel = f"{board.metric}{unit} (mean over objects)"
    curve = context_curve(
        board.scored,
        [r.label for r in board.rows],
        ylabel,
        f"{where}: {board.metric} vs context size",
        scale,
    )
    points, ctx = pareto_points(board)
    try:
        frame = MetricCard.from_tag(board.card).frame
    except ValueError:
        frame = board.frame
    front = pareto(
        points,
        "test-time seconds per object (log scale)",
        f"{board.metric}{unit} at {ctx} points",
        f"{where}: accuracy vs cost ({frame} frame)",
    )
    figures = {"chamfer": curve, "pareto": front}
    scaling = scaling_curve(
        board, ylabel, f"{where}: {board.metric} vs training shapes (data scaling)", scale
    )
    if scaling is not None:
        figures["scaling"] = scaling
    return figures


def figure_stem(md: Path, name: str) -> Path:
    """``leaderboards/synthetic-novel.md`` -> ``leaderboards/synthetic-novel-<name>``."""
    return md.with_name(f"{md.stem}-{name}")


def write_board_figures(board: Board, md: Path) -> list[Path]:
    """Write the board's figures beside its markdown file; return the files."""
    written = []
    for name, fig in board_figures(board).items():
        written += save(fig, figure_stem(md, name))
    return written


def log_board_artifacts(tracker: Any, board: Board, paths: Sequence[Path]) -> str:
    """Log ``paths`` (leaderboard, figures, report) to the table's run; return its id."""
    from shapebench.store.presentation import log_board_figures

    heading = (board.dataset, board.split, board.frame, board.metric)
    return log_board_figures(tracker, board.experiment_id, heading, board.fingerprint, paths)
