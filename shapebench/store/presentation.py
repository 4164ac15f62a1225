"""How evaluations read in the MLflow UI: parent runs, their colours and charts, notes, inputs.

The runner computes cells; everything that makes them legible in the UI happens here, from plain
data: a :class:`RunHeading` says whose runs these are, and a finished cell is anything with the
attributes of :class:`CellOutcome` (:class:`shapebench.evaluation.results.CellResult` is one).

* A **parent run** per method variant and split holds the metrics of its cells with
  ``step = context size``, so the chart view draws one line per variant; its colour is the one
  the variant's earlier parents have (MLflow's own choice hashes the run id, and two variants of
  one chart often got the same colour).
* Every run gets a **note** (``mlflow.note.content``): the cell's or the split's summary table,
  and a link to the training run of its checkpoint.
* The evaluated objects are the run's **dataset input** (the UI's Dataset column).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Protocol

import numpy as np

from shapebench.store import records as rec
from shapebench.store.tracking import Tracker

#: Chart colours of the variants of one experiment, in the order they first appear.
RUN_COLORS = (
    "#1f77b4",
    "#ff7f0e",
    "#2ca02c",
    "#d62728",
    "#9467bd",
    "#8c564b",
    "#e377c2",
    "#7f7f7f",
    "#bcbd22",
    "#17becf",
)


@dataclass(frozen=True)
class RunHeading:
    """Whose runs these are: one method variant evaluated on one dataset split."""

    label: str
    method: str
    dataset: str
    split: str
    #: The leaderboard row's key ("" for runs without a variant).
    variant_key: str
    frame: str
    #: The metric the notes summarise (the dataset's primary metric).
    metric: str
    #: The training run of the checkpoint ("" when the method does not train).
    training_run_id: str = ""
    #: A ``--force`` recomputation: its run names say so.
    force: bool = False

    def run_name(self, what: str) -> str:
        """A run's name: the variant's label (``gauss[sigma=0.05]``) and what the run holds; a
        ``--force`` recomputation says so, so it is not taken for the run it replaces."""
        return f"{self.label} {what}" + (" (forced rerun)" if self.force else "")


class CellOutcome(Protocol):
    """What the notes read of a computed (or reused) cell."""

    context_size: int
    seed: int
    run_id: str
    experiment_id: str
    skipped: bool
    metrics: dict[str, float]
    cards: dict[str, str]

    @property
    def n_objects(self) -> int: ...

    @property
    def n_ok(self) -> int: ...

    def scale(self, metric: str) -> float: ...


def note(lines: list[str], limit: int = 7900) -> str:
    """A run description from markdown lines, within MLflow's 8000 characters for a tag."""
    text = "\n".join(lines)
    if len(text) <= limit:
        return text
    return text[: text.rfind("\n", 0, limit - 80)] + "\n\n(truncated: `shapebench runs` lists all)"


def pm_text(metrics: dict[str, float], metric: str, scale: float) -> str:
    """``mean ± std`` of ``metric`` in a cell's summary, at the card's scale."""
    mean = metrics.get(f"{metric}.mean")
    if mean is None:
        return "-"
    return f"{mean * scale:.3f} ± {metrics.get(f'{metric}.std', 0.0) * scale:.3f}"


def start_parent(
    tracker: Tracker, exp_id: str, heading: RunHeading, parent_key: str, columns: Sequence[str]
) -> str:
    """Start the parent run of ``heading``'s new cells; ``columns`` are the metrics the
    experiment's runs table shows."""
    parent = tracker.start_run(
        exp_id,
        heading.run_name(f"on {heading.dataset}/{heading.split}"),
        {
            rec.PARENT_KEY_TAG: parent_key,
            rec.KIND_TAG: rec.PARENT_KIND,
            rec.METHOD_TAG: heading.method,
            rec.DATASET_TAG: heading.dataset,
            rec.SPLIT_TAG: heading.split,
            rec.VARIANT_KEY_TAG: heading.variant_key,
            rec.VARIANT_LABEL_TAG: heading.label,
            rec.FRAME_TAG: heading.frame,
            rec.RUN_COLOR_TAG: variant_color(tracker, exp_id, heading.label),
        },
    )
    tracker.describe_experiment(
        exp_id,
        f"shapebench evaluations on {heading.dataset}/{heading.split}: a parent run per method "
        "variant (its metrics are logged with step = context size, so the chart view "
        "draws one line per variant), a child run per context size and seed.",
        list(columns),
    )
    return parent


def abandon_stale_parents(tracker: Tracker, exp_id: str, parent_key: str) -> int:
    """Mark RUNNING parents of ``parent_key`` (left by a killed process) KILLED."""
    return tracker.abandon_stale(exp_id, parent_key, tag=rec.PARENT_KEY_TAG)


def variant_color(tracker: Tracker, exp_id: str, label: str) -> str:
    """The chart colour of a variant's parent runs: the one its earlier parents have, else the
    next of :data:`RUN_COLORS`."""
    labels: list[str] = []
    for _, tags in tracker.runs_of_kind(exp_id, rec.PARENT_KIND):
        seen = tags.get(rec.VARIANT_LABEL_TAG)
        if seen == label and tags.get(rec.RUN_COLOR_TAG):
            return tags[rec.RUN_COLOR_TAG]
        if seen and seen not in labels:
            labels.append(seen)
    return RUN_COLORS[len(labels) % len(RUN_COLORS)]


def training_link(tracker: Tracker, run_id: str) -> str:
    """A markdown link to the training run of a checkpoint ("" when none)."""
    if not run_id:
        return ""
    exp = tracker.experiment_of(run_id)
    if exp is None:  # a checkpoint trained in another store: name the run, no link
        return f"training run `{run_id}` (not in this store)"
    return f"[training run {run_id[:8]}](#/experiments/{exp}/runs/{run_id})"


def describe_cell(tracker: Tracker, heading: RunHeading, cell: CellOutcome) -> None:
    """The cell's summary as its note (shown on the run's page)."""
    metric = heading.metric
    scale = cell.scale(metric)
    lines = [
        f"**{heading.label}** on {heading.dataset}/{heading.split}, "
        f"{cell.context_size} context points, seed {cell.seed}",
        "",
        f"| metric | mean ± std (x{scale:g}) | objects | failed |",
        "|---|---|---|---|",
        f"| {metric} | {pm_text(cell.metrics, metric, scale)} | {cell.n_objects} "
        f"| {cell.n_objects - cell.n_ok} |",
    ]
    link = training_link(tracker, heading.training_run_id)
    if link:
        lines += ["", f"Checkpoint: {link}."]
    tracker.set_note(cell.run_id, note(lines))


def finish_parent(
    tracker: Tracker, parent: str, heading: RunHeading, cells: Sequence[CellOutcome]
) -> None:
    """The parent's metrics: each cell's, averaged over seeds, logged with step = context size
    (one line per variant in the chart view); its note, the summary table; the cells' cards, so
    the parent's values are read at the right scale."""
    by_size: dict[int, list[CellOutcome]] = {}
    for cell in cells:
        by_size.setdefault(cell.context_size, []).append(cell)
    for size in sorted(by_size):
        keys = set().union(*(c.metrics for c in by_size[size]))
        mean = {
            k: float(np.mean([c.metrics[k] for c in by_size[size] if k in c.metrics])) for k in keys
        }
        tracker.log_metrics(parent, mean, step=size)
    metric = heading.metric
    scale = cells[0].scale(metric) if cells else 1.0
    lines = [
        f"**{heading.label}** on {heading.dataset}/{heading.split}: {metric} x{scale:g}, "
        "mean ± std over objects",
        "",
        "| context | seed | objects | failed | mean ± std | run |",
        "|---|---|---|---|---|---|",
    ]
    for c in sorted(cells, key=lambda c: (c.context_size, c.seed)):
        lines.append(
            f"| {c.context_size} | {c.seed} | {c.n_objects} | "
            f"{c.n_objects - c.n_ok} | {pm_text(c.metrics, metric, scale)} | "
            f"[{c.run_id[:8]}](#/experiments/{c.experiment_id}/runs/{c.run_id})"
            f"{' (cached)' if c.skipped else ''} |"
        )
    link = training_link(tracker, heading.training_run_id)
    if link:
        lines += ["", f"Checkpoint: {link}."]
    cards = {rec.CARD_PREFIX + m: card for c in cells for m, card in c.cards.items()}
    tracker.set_tags(parent, {**cards, rec.NOTE_TAG: note(lines)})


def relabel(tracker: Tracker, run_id: str, label: str) -> None:
    """A finished cell reused under a new ``--label`` takes that label (results are equal)."""
    if rec.CellRecord.from_tags(tracker.tags(run_id)).variant_label != label:
        tracker.set_tags(run_id, {rec.VARIANT_LABEL_TAG: label})


def record_outcome(
    tracker: Tracker,
    run_id: str,
    contexts_digest: str,
    metric_errors: Sequence[str] = (),
    eval_points_actual: int = 0,
) -> None:
    """What a computed cell found out: the digest of its contexts, the metrics that raised on
    some object (the cell is computed again for them) and, when some object had fewer
    ground-truth points than the card states, the fewest."""
    tags = {rec.CONTEXTS_DIGEST_TAG: contexts_digest}
    if metric_errors:
        tags[rec.METRIC_ERRORS_TAG] = ",".join(metric_errors)
    if eval_points_actual:
        tags[rec.EVAL_POINTS_ACTUAL_TAG] = str(eval_points_actual)
    tracker.set_tags(run_id, tags)


def log_board_figures(
    tracker: Tracker,
    exp_id: str,
    heading: tuple[str, str, str, str],
    fingerprint: str,
    paths: Sequence[Path],
) -> str:
    """Log a leaderboard's files (table, figures, report) to its run in ``exp_id``: one per
    experiment, frame and metric, created once; rebuilt tables overwrite its artifacts.
    ``heading`` is (dataset, split, frame, metric). Returns the run id."""
    dataset, split, frame, metric = heading
    found = tracker.runs_of_kind(
        exp_id, rec.BOARD_KIND, {rec.BOARD_FRAME_TAG: frame, rec.BOARD_METRIC_TAG: metric}
    )
    if found:
        run_id = found[-1][0]
    else:
        run_id = tracker.start_run(
            exp_id,
            f"leaderboard {dataset}/{split} ({frame}, {metric})",
            {
                rec.KIND_TAG: rec.BOARD_KIND,
                rec.DATASET_TAG: dataset,
                rec.SPLIT_TAG: split,
                rec.BOARD_FRAME_TAG: frame,
                rec.BOARD_METRIC_TAG: metric,
            },
        )
        tracker.end(run_id)
    for path in paths:
        tracker.log_artifact(run_id, path)
    tracker.set_tags(run_id, {rec.BOARD_FINGERPRINT_TAG: fingerprint})
    return run_id
