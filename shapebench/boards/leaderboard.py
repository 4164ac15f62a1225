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

This module assembles the :class:`~shapebench.boards.board.Board` (:func:`build_board`) and writes
a dataset's tables (:func:`build_leaderboards`); the runs a board reads are chosen in
:mod:`~shapebench.boards.selection`, the metric's card is read in :mod:`~shapebench.boards.cards`,
the splits are found in :mod:`~shapebench.boards.splits`, and a board is written out by
:mod:`~shapebench.boards.markdown` and :mod:`~shapebench.boards.tidy` (the CSV).
"""

from __future__ import annotations

import json
import shlex
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from shapebench.api.errors import ShapebenchError
from shapebench.api.protocol import DEFAULT_CONTEXT, DEFAULT_FRAME, describe_context
from shapebench.boards import stats as board_stats
from shapebench.boards.board import Board, Row
from shapebench.boards.cards import (
    card_scale,
    card_text,
    default_metric,
    higher_is_better,
    normalised_card,
    tail_threshold,
)
from shapebench.boards.markdown import render_markdown
from shapebench.boards.paper import PAPER_METHOD_ORDER, paper_table
from shapebench.boards.selection import load_runs, metric_per_object, select_runs
from shapebench.boards.splits import (
    declared_splits,  # noqa: F401 (0.1's shapebench.leaderboard named it; see shapebench/_moved.py)
    protocols_with_runs,
    splits_with_runs,
)
from shapebench.boards.tidy import category_csv, category_csv_path, tidy_csv
from shapebench.config import Settings
from shapebench.store.records import card_column
from shapebench.store.tracking import Tracker, experiment_name

#: The row-label overrides every row of one table carries alike (registry/variant.py): its
#: context protocol's, and the profile of a sweep run at another than the default profile
#: (``configs/sweeps/crop-50.yaml`` runs at ``quick``: ``retrieval[crop=0.5,profile=quick]``).
#: A floor or reference named by its method is the method's row that differs from its defaults
#: by these alone.
_TABLE_WIDE_OVERRIDES = {"crop", "protocol", "noise", "profile"}

#: The rows a table's others must beat without ``--floor``: handing back the context unchanged
#: (gauss with sigma 0, labelled ``given-points`` in the sweeps) and retrieving the nearest
#: training shape (the method ``retrieval``).
DEFAULT_FLOORS = ("given-points", "retrieval")


def _is_plain_row(row: Row, method: str) -> bool:
    """Whether ``row`` is ``method``'s row that differs from its defaults only by what every row
    of its table carries (:data:`_TABLE_WIDE_OVERRIDES`)."""
    return row.method == method and set(row.overrides) <= _TABLE_WIDE_OVERRIDES


def _floor_rows(rows: list[Row], names: list[str] | tuple[str, ...]) -> list[str]:
    """The variant keys of the floor rows: per name, the rows labelled so, else the plain rows
    of the method of that name (as the reference)."""
    found: list[str] = []
    for name in names:
        hits = [r for r in rows if r.label == name] or [r for r in rows if _is_plain_row(r, name)]
        found += [r.variant for r in hits if r.variant not in found]
    return found


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


@dataclass(frozen=True)
class BoardQuery:
    """What a dataset's tables are asked for, the same for each of its splits and context
    protocols: the options ``shapebench leaderboard`` and ``shapebench report`` share.

    ``reference``: the row every other is normalised by (its label or method name); ``metric``:
    None for the dataset's default; ``data_version``: a fingerprint prefix (None: the newest
    version with runs); ``all_variants``: keep older variants that share a label with a newer
    one; ``floors``: the labels (or method names) of the rows every other row is tested against
    (None: :data:`DEFAULT_FLOORS`; those without rows are ignored); ``tail``: the threshold of
    the tail column in displayed units (None: the metric card's)."""

    dataset: str
    reference: str
    metric: str | None = None
    frame: str = DEFAULT_FRAME
    data_version: str | None = None
    all_variants: bool = False
    floors: tuple[str, ...] | None = None
    tail: float | None = None


def build_board(
    tracker: Tracker, query: BoardQuery, split: str, protocol: str = DEFAULT_CONTEXT
) -> Board | None:
    """The table of one split and context protocol of ``query``'s dataset, or None without
    runs."""
    dataset, reference, metric = query.dataset, query.reference, query.metric
    frame, floors, tail = query.frame, query.floors, query.tail
    exp_id = tracker.experiment_id(experiment_name(dataset, split), create=False)
    if exp_id is None:
        return None
    runs = load_runs(tracker, exp_id)
    if runs.empty:
        return None
    runs, fingerprint, left_out = select_runs(
        runs, frame, query.data_version, query.all_variants, protocol
    )
    if runs.empty:
        return None
    if metric is None:
        metric = default_metric(runs)
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
    runs[card_col] = runs[card_col].map(normalised_card)
    cards = runs.groupby(card_col)["_label"].agg(lambda s: sorted(set(s)))
    if len(cards) > 1:
        listing = "; ".join(f"[{card_text(c)}] used by {', '.join(m)}" for c, m in cards.items())
        raise ShapebenchError(
            f"runs of {dataset}-{split} computed {metric} with different cards, which cannot share "
            f"a table: {listing}",
            "rerun the odd ones with the same dataset options (shapebench run ... --force)",
        )
    card = cards.index[0]
    higher = higher_is_better(metric, card)
    per_obj = metric_per_object(tracker, runs, metric)
    # Objects the metric does not apply to leave the statistics (neither a failure nor a value).
    skipped = per_obj["not_applicable"] != ""
    not_applicable = {
        str(v): "; ".join(sorted(set(g)))
        for v, g in per_obj[skipped].groupby("variant")["not_applicable"]
    }
    per_obj = per_obj[~skipped].drop(columns="not_applicable")
    scored = board_stats.with_failure_rule(per_obj, higher)
    scale = card_scale(card)
    threshold = tail if tail is not None else tail_threshold(metric, card)
    raw = board_stats.raw_table(scored, None if threshold is None else threshold / scale, higher)
    for col in ("mean", "std", "median", "mean_ok", "std_ok", "category_mean"):
        if col in raw:
            raw[col] = raw[col] * scale
    categories = board_stats.category_table(scored)
    categories[["mean", "median"]] = categories[["mean", "median"]] * scale
    worst = board_stats.worst_samples(scored, higher)
    worst["scored"] = worst["scored"] * scale
    rows = _rows(runs)
    floor_rows = _floor_rows(rows, DEFAULT_FLOORS if floors is None else tuple(floors))
    floor_table = board_stats.floor_test(scored, floor_rows, higher) if floor_rows else None
    ref_row = next((r for r in rows if r.label == reference), None)
    protocol_name = runs["_protocol"].iloc[0] if "_protocol" in runs else DEFAULT_CONTEXT
    if ref_row is None:
        # In a table of one context protocol, or of a sweep at another profile, every row
        # carries it ([crop=0.5,profile=quick]): the reference is the row whose only differences
        # from its method's defaults are those.
        ref_row = next((r for r in rows if _is_plain_row(r, reference)), None)
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
        floor_rows=floor_rows,
        floors=floor_table,
        tail_threshold=threshold,
        categories=categories,
        worst=worst,
    )


def board_path(
    out_dir: Path, dataset: str, split: str, frame: str, protocol: str = DEFAULT_CONTEXT
) -> Path:
    """``<dataset>-<split>.md``, with the context protocol and the frame in the name unless they
    are the defaults (``synthetic-trained-crop-0_5.md``: no dot but the suffix's, which the
    figures' names rely on)."""
    suffix = "" if protocol == DEFAULT_CONTEXT else "-" + protocol.replace(".", "_")
    suffix += "" if frame == DEFAULT_FRAME else f"-{frame}"
    return out_dir / f"{dataset}-{split}{suffix}.md"


def build_leaderboards(
    settings: Settings,
    query: BoardQuery,
    splits: list[str] | None,
    out_dir: Path,
    protocol: str | None = DEFAULT_CONTEXT,
) -> list[Path]:
    """Write the tables of ``query``'s dataset: one per split (``splits``, or every split with
    runs) and context protocol (``protocol``, or every protocol with runs when None), each as
    Markdown, CSV, per-category CSV (``<table>-categories.csv``) and figures."""
    dataset, frame = query.dataset, query.frame
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
            board = build_board(tracker, query, split, one)
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
        per_category = category_csv_path(md)
        category_csv(board).to_csv(per_category, index=False)
        log_board_artifacts(tracker, board, [md, csv, per_category, *figures])
        written += [md, csv, per_category, *figures]
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
