"""What a cell run says about itself in MLflow: written once, read back by the same code.

A cell (one method variant x dataset x split x context size x seed) is an MLflow run whose
*tags* identify it: :class:`CellRecord` is that record. The runner writes it with
:meth:`CellRecord.to_tags`; everything that reads cells back (resuming, relabelling, the
leaderboards) goes through :meth:`CellRecord.from_tags` / :meth:`CellRecord.from_run`, which
turn the strings into typed values (``context_size`` an int, cards :class:`MetricCard`), the
way pytest pairs ``pytest_report_to_serializable`` with ``pytest_report_from_serializable``.
A new tag is added here, in both directions, or nowhere.

The tag names are part of the store's format (a store written by an older shapebench is read by
a newer one), so they do not change; :data:`FORMAT` is bumped when their meaning does.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field, fields
from typing import Any

from shapebench.api.metric import MetricCard
from shapebench.store.tracking import CELL_KIND

#: Version of the tag format below.
FORMAT = "1"

KIND_TAG = "shapebench.kind"
CELL_KEY_TAG = "shapebench.cell_key"
#: The tag of a cell naming the training run its checkpoint came from.
TRAINING_RUN_TAG = "training_run_id"
METRIC_ERRORS_TAG = "shapebench.metric_errors"
#: The device a training ran on (``cpu x1``, ``cuda x4 (NVIDIA H100)``).
TRAINING_DEVICE_TAG = "training_device"
#: The tag of a training run whose weights are a shipped reference checkpoint.
REFERENCE_TAG = "shapebench.reference"
EVAL_POINTS_ACTUAL_TAG = "eval_points.actual"
CARD_PREFIX = "card."

#: Record field -> tag name, for the plain string fields (the others are handled explicitly).
_TAGS = {
    "cell_key": CELL_KEY_TAG,
    "shapebench_version": "shapebench.version",
    "method": "method",
    "display_name": "method.display_name",
    "method_code": "method.code",
    "dataset": "dataset",
    "dataset_version": "dataset.version",
    "fingerprint": "dataset.fingerprint",
    "data_root": "dataset.data_root",
    "split": "split",
    "plugin_distribution": "plugin.distribution",
    "plugin_version": "plugin.version",
    "git_commit": "git_commit",
    "checkpoint_key": "checkpoint_key",
    "training_run_id": TRAINING_RUN_TAG,
    "frame": "protocol.frame",
    "variant_key": "variant.key",
    "variant_label": "variant.label",
}


@dataclass(frozen=True)
class CellRecord:
    """The identity of one cell run, as its tags hold it."""

    cell_key: str
    method: str
    dataset: str
    split: str
    context_size: int
    seed: int
    #: Metric name -> the card its values follow (:meth:`MetricCard.as_tag`).
    cards: dict[str, str] = field(default_factory=dict)
    display_name: str = ""
    trains: bool = False
    method_code: str = ""
    dataset_version: str = ""
    fingerprint: str = ""
    data_root: str = ""
    shapebench_version: str = ""
    plugin_distribution: str = ""
    plugin_version: str = ""
    git_commit: str = ""
    checkpoint_key: str = ""
    training_run_id: str = ""
    frame: str = ""
    context_normals: bool = False
    #: The leaderboard row (see :mod:`shapebench.registry.variant`); empty for runs logged before
    #: rows.
    variant_key: str = ""
    variant_label: str = ""
    variant_overrides: dict[str, Any] = field(default_factory=dict)
    #: Metrics that raised on some object: the cell is not finished for them.
    metric_errors: tuple[str, ...] = ()
    #: The fewest ground-truth points of an object, when fewer than the cards state (else 0).
    eval_points_actual: int = 0

    def to_tags(self) -> dict[str, str]:
        tags = {KIND_TAG: CELL_KIND, "shapebench.format": FORMAT}
        for name, tag in _TAGS.items():
            value = getattr(self, name)
            if value or name in ("data_root",):
                tags[tag] = str(value)
        tags["context_size"] = str(self.context_size)
        tags["seed"] = str(self.seed)
        tags["method.trains"] = str(self.trains)
        tags["protocol.context_normals"] = str(self.context_normals)
        if self.variant_key:
            tags["variant.overrides"] = json.dumps(
                self.variant_overrides, sort_keys=True, default=str
            )
        for metric, card in self.cards.items():
            tags[CARD_PREFIX + metric] = card
        if self.metric_errors:
            tags[METRIC_ERRORS_TAG] = ",".join(self.metric_errors)
        if self.eval_points_actual:
            tags[EVAL_POINTS_ACTUAL_TAG] = str(self.eval_points_actual)
        return tags

    @classmethod
    def from_tags(cls, tags: dict[str, str]) -> CellRecord:
        """The record of a cell run's tags; missing tags (older stores) take the defaults."""
        values: dict[str, Any] = {name: tags.get(tag, "") for name, tag in _TAGS.items()}
        values["context_size"] = int(tags.get("context_size") or 0)
        values["seed"] = int(tags.get("seed") or 0)
        values["trains"] = tags.get("method.trains") == "True"
        values["context_normals"] = tags.get("protocol.context_normals") == "True"
        try:
            values["variant_overrides"] = json.loads(tags.get("variant.overrides") or "{}")
        except ValueError:
            values["variant_overrides"] = {}
        values["cards"] = {
            k[len(CARD_PREFIX) :]: v for k, v in tags.items() if k.startswith(CARD_PREFIX)
        }
        values["eval_points_actual"] = int(tags.get(EVAL_POINTS_ACTUAL_TAG) or 0)
        crashed = tags.get(METRIC_ERRORS_TAG, "")
        values["metric_errors"] = tuple(m for m in crashed.split(",") if m)
        known = {f.name for f in fields(cls)}
        return cls(**{k: v for k, v in values.items() if k in known})

    @classmethod
    def from_run(cls, run: Any) -> CellRecord:
        """The record of an MLflow ``Run``."""
        return cls.from_tags(dict(run.data.tags))

    def card(self, metric: str) -> MetricCard | None:
        """The parsed card of ``metric``, or None when the run did not compute it."""
        tag = self.cards.get(metric)
        if not tag:
            return None
        try:
            return MetricCard.from_tag(tag)
        except ValueError:
            return None

    def row(self) -> dict[str, Any]:
        """The record as a flat dict keyed by tag name, with typed values (a leaderboard row)."""
        out: dict[str, Any] = {tag: getattr(self, name) for name, tag in _TAGS.items()}
        out.update(
            {
                "context_size": self.context_size,
                "seed": self.seed,
                "variant.overrides": json.dumps(
                    self.variant_overrides, sort_keys=True, default=str
                ),
                METRIC_ERRORS_TAG: ",".join(self.metric_errors),
            }
        )
        out.update({CARD_PREFIX + m: c for m, c in self.cards.items()})
        return out
