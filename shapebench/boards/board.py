"""The model of a leaderboard: its rows and the tables built for one dataset split (no MLflow,
no drawing): what :mod:`~shapebench.boards.leaderboard` builds and the figures and the report
read."""

from __future__ import annotations

from dataclasses import dataclass, field

import pandas as pd

from shapebench.api.protocol import DEFAULT_FRAME


@dataclass
class Row:
    """One leaderboard row: a variant and how to print it."""

    variant: str
    label: str
    method: str
    display: str
    overrides: dict
    code: str = ""
    checkpoint: str = ""
    #: The run seeds whose cells the row pools (every (object, seed) pair is one sample).
    seeds: tuple[int, ...] = ()
    #: (seed, checkpoint key) of each seed's training, in seed order (the seed is part of the
    #: key); seeds whose runs name no checkpoint are left out.
    checkpoints: tuple[tuple[int, str], ...] = ()


@dataclass
class Board:
    """One leaderboard: a dataset split, one metric card and frame, a row per variant."""

    dataset: str
    split: str
    metric: str
    card: str
    reference: str  # the reference row's label
    contexts: list[int]
    rows: list[Row]
    raw: pd.DataFrame  # board_stats.raw_table, one row per (variant, context)
    normalized: pd.DataFrame | None
    significance: pd.DataFrame
    note: str
    paper: pd.DataFrame
    experiment_id: str
    fingerprint: str
    data_root: str = ""
    frame: str = DEFAULT_FRAME
    protocol: str = ""
    left_out: list[str] = field(default_factory=list)
    #: Per (variant, context, seed, object): the value under the failure rule (``scored``, at
    #: the metric's own scale: multiply by ``scale``) and test-time ``seconds``.
    scored: pd.DataFrame | None = None
    scale: float = 1.0
    #: Per variant: training and evaluation cost (:func:`shapebench.boards.cost.row_costs`).
    costs: pd.DataFrame | None = None
    #: The table's cell runs (one row per run, tags as columns), for provenance.
    runs: pd.DataFrame | None = None
    #: The context protocol's name (``sparse``, ``crop-0.5``...): one table per protocol.
    context: str = "sparse"
    #: Variant key -> why the metric does not apply to it (a points-only method under a mesh
    #: metric): its cells show ``n/a`` and the reason is printed under the table.
    not_applicable: dict[str, str] = field(default_factory=dict)
    #: The floor rows' variant keys present in the table (rows labelled or run as a
    #: ``--floor``: by default ``given-points`` and the method ``retrieval``); empty: no marks.
    floor_rows: list[str] = field(default_factory=list)
    #: :func:`shapebench.boards.stats.floor_test`: per (variant, context) the floor used, the
    #: p-values against it and ``below_floor``; None without floor rows.
    floors: pd.DataFrame | None = None
    #: The tail threshold in the table's displayed units and frame (the raw table's
    #: ``tail_share`` counts the samples worse than it); None: no tail column.
    tail_threshold: float | None = None
    #: Per (variant, context, category): mean, median and n under the failure rule, displayed
    #: units (:func:`shapebench.boards.stats.category_table`); empty without categories.
    categories: pd.DataFrame | None = None
    #: Per (variant, context): the worst sample (object, seed, ``scored`` in displayed units).
    worst: pd.DataFrame | None = None


def table_id(board: Board) -> str:
    """The table's id in pages and file names: its split, and its context protocol unless it is
    the paper's (``trained-crop-0_5``)."""
    if board.context == "sparse":
        return board.split
    return f"{board.split}-{board.context.replace('.', '_')}"


def table_title(board: Board) -> str:
    """The table's split, and its context protocol unless it is the paper's."""
    return board.split if board.context == "sparse" else f"{board.split}, {board.context}"


def floor_labels(board: Board) -> list[str]:
    """The labels of the table's floor rows, in row order."""
    return [r.label for r in board.rows if r.variant in board.floor_rows]


def below_floor(board: Board, variant: str, ctx: int) -> pd.Series | None:
    """The floor test of one cell (:attr:`Board.floors`), None where it was not tested."""
    if board.floors is None or board.floors.empty:
        return None
    hit = board.floors[(board.floors.variant == variant) & (board.floors.context == ctx)]
    return None if hit.empty else hit.iloc[0]
