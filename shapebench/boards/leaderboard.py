"""Leaderboards built from the runs in MLflow, laid out like the paper's Tables 1-3.

A table covers one dataset, split, data version (fingerprint) and evaluation frame, with one
metric card. A **row is one variant** (see :mod:`shapebench.registry.variant`): a method with one
set of
resolved options, code, training and protocol, labelled ``gauss[sigma=0.05]`` or by the user's
``--label``; a context size the variant lacks shows "–". The newest finished run of each
(variant, context size, seed) counts (a ``--force`` rerun replaces the older one).

For each run the per-object table (the run's ``per_object.csv`` artifact) is read back from MLflow
and the arithmetic of :mod:`shapebench.boards.stats` applies: failures score as the worst success of
their cell, the normalised table is the paper's equation 8, and the best variant of each context
size is marked with those statistically tied with it (paired Wilcoxon, Holm-corrected).
"""

from __future__ import annotations

import json
import shlex
import sys
import tempfile
from collections.abc import Iterator
from datetime import datetime, timezone
from pathlib import Path

import numpy as np
import pandas as pd

from shapebench.api.errors import ShapebenchError
from shapebench.api.metric import MetricCard
from shapebench.api.protocol import (
    DEFAULT_CONTEXT,
    DEFAULT_FRAME,
    FRAMES,
    PAPER_FRAME,
    describe_context,
)
from shapebench.api.types import EVAL_SPLITS
from shapebench.boards import stats as board_stats
from shapebench.boards.board import Board, Row
from shapebench.boards.paper import PAPER_METHOD_ORDER, paper_table
from shapebench.config import Settings
from shapebench.store.records import card_column
from shapebench.store.tracking import Tracker, experiment_name


def _card_text(tag: str) -> str:
    try:
        return MetricCard.from_tag(tag).describe()
    except ValueError:
        return tag


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


def _per_object(tracker: Tracker, runs: pd.DataFrame, metric: str) -> pd.DataFrame:
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


def _column(runs: pd.DataFrame, name: str, default: str) -> pd.Series:
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
    runs["_frame"] = _column(runs, "frame", DEFAULT_FRAME)
    other_frame = runs[runs["_frame"] != frame]
    if len(other_frame):
        frames = ", ".join(sorted(other_frame["_frame"].unique()))
        left_out.append(f"{len(other_frame)} runs in another frame ({frames}; --frame)")
    runs = runs[runs["_frame"] == frame]
    runs["_protocol"] = _column(runs, "context_protocol", DEFAULT_CONTEXT)
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
    runs["_frame"] = _column(runs, "frame", DEFAULT_FRAME)
    runs["_label"] = _column(runs, "variant_label", "")
    runs.loc[runs["_label"] == "", "_label"] = runs["method"]
    return runs


#: The row-label overrides a context protocol adds (registry/variant.py).
_PROTOCOL_OVERRIDES = {"crop", "protocol", "noise"}


def _context_words(name: str) -> str:
    """A context protocol's name (``crop-0.5+noise-0.005``) in words, for table headers."""
    base, _, noise = name.partition("+noise-")
    kind, _, fraction = base.partition("-")
    return describe_context(kind, float(fraction or 0), float(noise or 0))


def _text(value: object) -> str:
    """A tag value, or "" where the run has none (pandas gives NaN for a missing tag)."""
    return "" if value is None or (isinstance(value, float) and np.isnan(value)) else str(value)


def _seeds_and_checkpoints(
    runs: pd.DataFrame,
) -> tuple[tuple[int, ...], tuple[tuple[int, str], ...]]:
    """One variant's seeds, and (seed, checkpoint key) of each seed's newest run (none for a
    method that does not train)."""
    if "seed" not in runs:
        return (), ()
    newest = runs.sort_values("start").groupby(runs["seed"].astype(int)).tail(1)
    by_seed = {int(r["seed"]): _text(r.get("checkpoint_key")) for _, r in newest.iterrows()}
    seeds = tuple(sorted(by_seed))
    checkpoints = tuple((s, by_seed[s]) for s in seeds if by_seed[s])
    return seeds, checkpoints


def _seeds_text(seeds: tuple[int, ...]) -> str:
    return ("seed " if len(seeds) == 1 else "seeds ") + ", ".join(map(str, seeds))


def _rows(runs: pd.DataFrame) -> list[Row]:
    rows = []
    for key, g in runs.groupby("variant_key"):
        first = g.sort_values("start").iloc[-1]
        overrides = json.loads(first.get("variant_overrides") or "{}")
        display = first.get("display_name") or first["method"]
        if overrides.get("+normals"):  # never under the paper's row name
            display = f"{display} + test-time normals"
        seeds, checkpoints = _seeds_and_checkpoints(g)
        rows.append(
            Row(
                str(key),
                first["_label"],
                first["method"],
                display,
                overrides,
                _text(first.get("method_code")),
                _text(first.get("checkpoint_key")),
                seeds,
                checkpoints,
            )
        )

    def rank(row: Row) -> tuple[int, str]:
        base = row.display
        return (PAPER_METHOD_ORDER.index(base) if base in PAPER_METHOD_ORDER else 99, row.label)

    return sorted(rows, key=rank)


class MetricNotRecorded(ShapebenchError):
    """No run of a table computed the metric asked for."""


def build_board(
    tracker: Tracker,
    dataset: str,
    split: str,
    reference: str,
    metric: str | None,
    frame: str = DEFAULT_FRAME,
    data_version: str | None = None,
    all_variants: bool = False,
    protocol: str = DEFAULT_CONTEXT,
) -> Board | None:
    exp_id = tracker.experiment_id(experiment_name(dataset, split), create=False)
    if exp_id is None:
        return None
    runs = load_runs(tracker, exp_id)
    if runs.empty:
        return None
    runs, fingerprint, left_out = select_runs(runs, frame, data_version, all_variants, protocol)
    if runs.empty:
        return None
    if metric is None:
        metric = _default_metric(runs)
    if "metric_errors" in runs:
        crashed = runs["metric_errors"].fillna("").map(lambda t: metric in t.split(","))
        if crashed.any():
            left_out.append(
                f"{int(crashed.sum())} runs in which {metric} raised on some object (fix the "
                "metric and rerun: those cells are computed again)"
            )
            runs = runs[~crashed]
            if (
                runs.empty
                or card_column(metric) not in runs
                or runs[card_column(metric)].isna().all()
            ):
                raise ShapebenchError(
                    f"{metric} raised on some object in every run of {dataset}-{split} that "
                    "computed it",
                    "see the reasons under the run's summary (shapebench --debug run ... shows "
                    "tracebacks); fix the metric and rerun: those cells are computed again",
                )
    card_col = card_column(metric)
    if card_col not in runs or runs[card_col].isna().all():
        where = "" if protocol == DEFAULT_CONTEXT else f" with {protocol} contexts"
        raise MetricNotRecorded(
            f"no run of {dataset}-{split}{where} recorded metric {metric!r}",
            "pick another with --metric",
        )
    # Cards are compared in their current tag form: a tag written by an older shapebench (the
    # same card in the old spelling) groups with today's.
    runs[card_col] = runs[card_col].map(_normalised_card)
    cards = runs.groupby(card_col)["_label"].agg(lambda s: sorted(set(s)))
    if len(cards) > 1:
        listing = "; ".join(f"[{_card_text(c)}] used by {', '.join(m)}" for c, m in cards.items())
        raise ShapebenchError(
            f"runs of {dataset}-{split} computed {metric} with different cards, which cannot share "
            f"a table: {listing}",
            "rerun the odd ones with the same dataset options (shapebench run ... --force)",
        )
    card = cards.index[0]
    higher = _higher_is_better(metric, card)
    per_obj = _per_object(tracker, runs, metric)
    # Objects the metric does not apply to leave the statistics (neither a failure nor a value).
    skipped = per_obj["not_applicable"] != ""
    not_applicable = {
        str(v): "; ".join(sorted(set(g)))
        for v, g in per_obj[skipped].groupby("variant")["not_applicable"]
    }
    per_obj = per_obj[~skipped].drop(columns="not_applicable")
    scored = board_stats.with_failure_rule(per_obj, higher)
    raw = board_stats.raw_table(scored)
    scale = _scale(card)
    for col in ("mean", "std", "mean_ok", "std_ok", "category_mean"):
        if col in raw:
            raw[col] = raw[col] * scale
    rows = _rows(runs)
    ref_row = next((r for r in rows if r.label == reference), None)
    protocol_name = runs["_protocol"].iloc[0] if "_protocol" in runs else DEFAULT_CONTEXT
    if ref_row is None and protocol_name != DEFAULT_CONTEXT:
        # In a table of one context protocol every row carries it ([crop=0.5]): the reference
        # is the row whose only differences from its method's defaults are the protocol's.
        ref_row = next(
            (r for r in rows if r.method == reference and set(r.overrides) <= _PROTOCOL_OVERRIDES),
            None,
        )
    normalized, note = None, ""
    if ref_row is None:
        note = (
            f"No runs of the reference {reference!r} in this table, so there is no normalised "
            f"table. Run it, or choose another reference with --reference (rows: "
            f"{', '.join(r.label for r in rows)})."
        )
    else:
        normalized = board_stats.normalized_table(scored, ref_row.variant)
    root = runs["data_root"].dropna().iloc[0] if "data_root" in runs else ""
    carried = (
        "contexts carry points only"
        if not any(r.overrides.get("+normals") for r in rows)
        else "contexts carry points only, except rows marked +normals (points and normals)"
    )
    protocol = (
        carried
        if protocol_name == DEFAULT_CONTEXT
        else f"{_context_words(protocol_name)}; {carried}"
    )
    from shapebench.boards.cost import row_costs

    return Board(
        dataset,
        split,
        metric,
        card,
        reference,
        sorted(int(c) for c in runs["context_size"].unique()),
        rows,
        raw,
        normalized,
        board_stats.significance(scored, higher),
        note,
        paper_table(dataset, split),
        exp_id,
        fingerprint,
        str(root or ""),
        frame,
        protocol,
        left_out,
        scored,
        scale,
        row_costs(tracker, runs, scored),
        runs,
        context=protocol_name,
        not_applicable=not_applicable,
    )


def _scale(card: str) -> float:
    try:
        return MetricCard.from_tag(card).scale
    except ValueError:
        return 1.0


def _normalised_card(tag: object) -> object:
    if not isinstance(tag, str) or "=" not in tag:
        return tag
    try:
        return MetricCard.from_tag(tag).as_tag()
    except ValueError:
        return tag


def _higher_is_better(metric: str, card: str = "") -> bool:
    """The ranking direction: the card's when it states it (so a table of an uninstalled
    metric plugin still ranks right), else the installed metric's."""
    from shapebench.registry.discovery import get_registry

    if "higher_is_better=" in card:
        try:
            return MetricCard.from_tag(card).higher_is_better
        except ValueError:
            pass
    try:
        return bool(get_registry().load("metric", metric).higher_is_better)
    except ShapebenchError:
        return False


def _default_metric(runs: pd.DataFrame) -> str:
    from shapebench.registry.discovery import get_registry

    dataset = runs.iloc[0]["dataset"]
    try:
        return get_registry().load("dataset", dataset).default_metric
    except ShapebenchError:
        return "chamfer-l2"


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
    if r["failures"]:
        text += f" ({int(r['n_ok'])}/{int(r['n'])} ok)"
    return text


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
        f"**Metric card**: {_card_text(board.card)}.",
        "",
        f"**Protocol**: {board.protocol}; distances in the {FRAMES[board.frame][1]}.",
        "",
        f"**Choices**: {choices_text(board.dataset, board.split)}",
        "",
        f"Raw: mean ± std over {samples} of {board.metric}{' ' + scale_txt if scale_txt else ''}"
        " (every object weighs the same; the mean of the per-category means, PCN's 'overall', "
        "is the CSV's `category_mean`). Normalised: per object "
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
    direction = "highest" if _higher_is_better(board.metric, board.card) else "lowest"
    lines += [
        "",
        f"**Bold**: the {direction} mean at that context size; ≈: not significantly different "
        f"from it ({board_stats.TEST_NAME} across the rows at that size, α = "
        f"{board_stats.ALPHA}); p-values are in the CSV (`p_vs_best`, `p_holm`). A failed object "
        "scores as the worst successful score of its cell, (n_ok/n ok) says how many succeeded, "
        "and the success-only mean is in the CSV (`mean_ok`).",
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


def board_path(
    out_dir: Path, dataset: str, split: str, frame: str, protocol: str = DEFAULT_CONTEXT
) -> Path:
    """``<dataset>-<split>.md``, with the context protocol and the frame in the name unless they
    are the defaults (``synthetic-trained-crop-0_5.md``: no dot but the suffix's, which the
    figures' names rely on)."""
    suffix = "" if protocol == DEFAULT_CONTEXT else "-" + protocol.replace(".", "_")
    suffix += "" if frame == DEFAULT_FRAME else f"-{frame}"
    return out_dir / f"{dataset}-{split}{suffix}.md"


def choices_text(dataset: str, split: str) -> str:
    """Which split options are chosen on (the leaderboard header's "Choices" line): the
    dataset's validation split, disjoint from the test objects a table reports."""
    from shapebench.registry.discovery import get_registry

    try:
        validation = get_registry().load("dataset", dataset).validation_splits
    except Exception:  # not installed here (a merged store): say what the table cannot know
        return f"dataset {dataset!r} is not installed here, so its validation split is unknown."
    if split in validation:
        return (
            f"this is `{dataset}`'s validation split, kept apart from the test objects for "
            "choosing options (profiles, method defaults, the ladder): for choices, not reports."
        )
    if not validation:
        return (
            f"`{dataset}` has no validation split; options (profiles, method defaults) are the "
            "ones chosen elsewhere, never on these test objects."
        )
    names = ", ".join(f"`{v}`" for v in validation)
    return (
        f"options (profiles, method defaults, the ladder) are chosen on the {names} split of "
        f"`{dataset}`, disjoint from these test objects, which are never used to choose."
    )


def declared_splits(dataset: str) -> tuple[str, ...]:
    """The evaluation splits in the order ``dataset`` declares them (trained before novel, as
    the paper's Table 1 comes before Table 2); the built-in order when the dataset is not
    installed here (a store merged from elsewhere)."""
    from shapebench.registry.discovery import get_registry

    try:
        cls = get_registry().load("dataset", dataset)
        return (*cls.eval_splits, *cls.validation_splits)
    except Exception:  # not installed, or a plugin that fails to load: the store still reads
        return EVAL_SPLITS


def splits_with_runs(tracker: Tracker, dataset: str) -> list[str]:
    """The splits of ``dataset`` that have an experiment (the leaderboard's and the report's
    default), in the order the dataset declares them, undeclared ones after, by name."""
    prefix = f"{dataset}-"
    names = tracker.experiment_names(prefix)
    found = {n[len(prefix) :] for n in names} - {"train"}
    order = declared_splits(dataset)
    return sorted(found, key=lambda s: (order.index(s) if s in order else len(order), s))


def protocols_with_runs(tracker: Tracker, dataset: str, split: str) -> list[str]:
    """The context protocols (names) of the finished cells of ``dataset``/``split``, the paper's
    sparse one first."""
    exp_id = tracker.experiment_id(experiment_name(dataset, split), create=False)
    runs = load_runs(tracker, exp_id) if exp_id is not None else pd.DataFrame()
    if runs.empty:
        return []
    names = set(_column(runs, "context_protocol", DEFAULT_CONTEXT))
    return sorted(names, key=lambda n: (n != DEFAULT_CONTEXT, n))


def build_leaderboards(
    settings: Settings,
    dataset: str,
    splits: list[str] | None,
    reference: str,
    metric: str | None,
    out_dir: Path,
    frame: str = DEFAULT_FRAME,
    data_version: str | None = None,
    all_variants: bool = False,
    protocol: str | None = DEFAULT_CONTEXT,
) -> list[Path]:
    """Write the tables of ``dataset``: one per split (``splits``, or every split with runs)
    and context protocol (``protocol``, or every protocol with runs when None)."""
    tracker = Tracker(settings)
    if splits is None:
        splits = splits_with_runs(tracker, dataset)
    command = "shapebench " + " ".join(shlex.quote(a) for a in sys.argv[1:])
    written = []
    tables = [
        (split, one)
        for split in splits
        for one in (
            [protocol] if protocol is not None else protocols_with_runs(tracker, dataset, split)
        )
    ]
    skipped: list[MetricNotRecorded] = []
    for split, one in tables:
        try:
            board = build_board(
                tracker, dataset, split, reference, metric, frame, data_version, all_variants, one
            )
        except MetricNotRecorded as exc:
            # Among several tables, one whose runs never computed the metric is skipped (said
            # in one line): --metric iou should not fail because crop runs computed Chamfer only.
            if len(tables) == 1:
                raise
            skipped.append(exc)
            print(f"skipped: {exc.message}", file=sys.stderr)
            continue
        if board is None:
            continue
        out_dir.mkdir(parents=True, exist_ok=True)
        md = board_path(out_dir, dataset, split, frame, one)
        # Figures beside the table (PNG and SVG), linked from it, and all of it in MLflow.
        from shapebench.boards.figures import log_board_artifacts, write_board_figures

        figures = write_board_figures(board, md)
        svgs = {p.stem[len(md.stem) + 1 :]: p for p in figures if p.suffix == ".svg"}
        md.write_text(render_markdown(board, command, settings.tracking_uri, svgs))
        csv = md.with_suffix(".csv")
        tidy_csv(board).to_csv(csv, index=False)
        log_board_artifacts(tracker, board, [md, csv, *figures])
        written += [md, csv, *figures]
    if not written and skipped:
        raise skipped[0]
    if not written:
        raise ShapebenchError(
            f"no finished runs of dataset {dataset!r}"
            + (f" (splits {', '.join(splits)})" if splits else "")
            + f" in the {frame} frame"
            + (f" with {protocol} contexts" if protocol not in (None, DEFAULT_CONTEXT) else "")
            + f" in {settings.tracking_uri}",
            f"run one first: shapebench run --method gauss --dataset {dataset}"
            + (f" --frame {frame}" if frame != DEFAULT_FRAME else "")
            + (
                " (with the same --protocol options)"
                if protocol not in (None, DEFAULT_CONTEXT)
                else ""
            ),
        )
    return written
