"""What a cell run says about itself in MLflow: written once, read back by the same code.

A cell (one method variant x dataset x split x context size x seed) is an MLflow run whose
*tags* identify it: :class:`CellRecord` is that record. The runner writes it with
:meth:`CellRecord.to_tags`; everything that reads cells back (resuming, relabelling, the
leaderboards) goes through :meth:`CellRecord.from_tags` / :meth:`CellRecord.from_run`, which
turn the strings into typed values (``context_size`` an int, cards :class:`MetricCard`), the
way pytest pairs ``pytest_report_to_serializable`` with ``pytest_report_from_serializable``.
A new tag is added here, in both directions, or nowhere.

The tag names are part of the store's format (a store written by an older shapebench is read by
a newer one), so they do not change; :data:`FORMAT` is bumped when their meaning does. Every tag
and run kind shapebench writes or reads is named in this module and nowhere else (a test reads
the other modules for tag strings): the rest of the store imports these constants, and the rooms
above the store never see a tag.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field, fields
from typing import Any

from shapebench.api.metric import MetricCard

#: Version of the tag format below.
FORMAT = "1"
FORMAT_TAG = "shapebench.format"

# -- run kinds: every run shapebench starts says which it is --------------------------------------
KIND_TAG = "shapebench.kind"
#: One method variant x dataset x split x context size x seed.
CELL_KIND = "cell"
#: A variant's new cells on one split, their metrics logged with step = context size.
PARENT_KIND = "parent"
#: A training of a checkpoint key.
TRAINING_KIND = "training"
#: The figures of one leaderboard (dataset, split, frame, metric).
BOARD_KIND = "leaderboard"

# -- identities -------------------------------------------------------------------------------
CELL_KEY_TAG = "shapebench.cell_key"
PARENT_KEY_TAG = "shapebench.parent_key"
CHECKPOINT_KEY_TAG = "checkpoint_key"
#: Where a merged run came from: ``<source store>#<run id>``.
MERGED_FROM_TAG = "shapebench.merged_from"
METHOD_TAG = "method"
DATASET_TAG = "dataset"
SPLIT_TAG = "split"
CONTEXT_SIZE_TAG = "context_size"
SEED_TAG = "seed"
FRAME_TAG = "protocol.frame"
VARIANT_KEY_TAG = "variant.key"
VARIANT_LABEL_TAG = "variant.label"
#: The context protocol of a cell other than the paper's (``crop-0.5``, ``sparse+noise-0.005``,
#: :attr:`shapebench.api.protocol.Protocol.name`); absent on sparse cells.
CONTEXT_PROTOCOL_TAG = "protocol.context"
#: The digest of the context points a cell gave its method (same for every method).
CONTEXTS_DIGEST_TAG = "contexts.sha256"
#: A training that continued from a checkpoint.
RESUMED_TAG = "resumed"
BOARD_FRAME_TAG = "board.frame"
BOARD_METRIC_TAG = "board.metric"
BOARD_FINGERPRINT_TAG = "board.fingerprint"

# -- MLflow's own tags, which its UI reads ------------------------------------------------------
PARENT_RUN_TAG = "mlflow.parentRunId"
NOTE_TAG = "mlflow.note.content"
RUN_COLOR_TAG = "mlflow.runColor"
EXPERIMENT_KIND_TAG = "mlflow.experimentKind"
#: The experiment tag the MLflow UI reads a shared view from (``?viewStateShareKey=...``).
VIEW_TAG_PREFIX = "mlflow.sharedViewState."
USER_TAG = "mlflow.user"
SOURCE_TYPE_TAG = "mlflow.source.type"
SOURCE_NAME_TAG = "mlflow.source.name"
GIT_COMMIT_TAG = "mlflow.source.git.commit"
#: The context of a dataset input (an input tag, not a run tag).
DATASET_CONTEXT_TAG = "mlflow.data.context"

# -- provenance: where and with what a run ran ---------------------------------------------------
SHAPEBENCH_VERSION_TAG = "shapebench.version"
GIT_DIRTY_TAG = "git.dirty"
VERSIONS_PREFIX = "versions."
HOST_PLATFORM_TAG = "host.platform"
HOST_CPUS_TAG = "host.cpus"
HOST_CPU_TAG = "host.cpu"
HOST_MEMORY_TAG = "host.memory_gb"
HOST_GPUS_TAG = "host.gpus"
#: Torch's intra-op threads when the run started (``sweep --threads``, a worker's share).
HOST_TORCH_THREADS_TAG = "host.torch_threads"
#: The SIMD kernels torch dispatches to on this CPU (``AVX2``, ``AVX512``, ``DEFAULT``): two
#: machines with different ones round differently (docs: api/protocol.py, MESHED_RTOL).
HOST_TORCH_CPU_CAPABILITY_TAG = "host.torch_cpu_capability"
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
    "shapebench_version": SHAPEBENCH_VERSION_TAG,
    "method": METHOD_TAG,
    "display_name": "method.display_name",
    "method_code": "method.code",
    "dataset": DATASET_TAG,
    "dataset_version": "dataset.version",
    "fingerprint": "dataset.fingerprint",
    "data_root": "dataset.data_root",
    "split": SPLIT_TAG,
    "plugin_distribution": "plugin.distribution",
    "plugin_version": "plugin.version",
    "git_commit": "git_commit",
    "checkpoint_key": CHECKPOINT_KEY_TAG,
    "training_run_id": TRAINING_RUN_TAG,
    "frame": FRAME_TAG,
    "context_protocol": CONTEXT_PROTOCOL_TAG,
    "variant_key": VARIANT_KEY_TAG,
    "variant_label": VARIANT_LABEL_TAG,
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
    #: The context protocol's name; "" for the paper's sparse contexts without noise.
    context_protocol: str = ""
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
        tags = {KIND_TAG: CELL_KIND, FORMAT_TAG: FORMAT}
        for name, tag in _TAGS.items():
            value = getattr(self, name)
            if value or name in ("data_root",):
                tags[tag] = str(value)
        tags[CONTEXT_SIZE_TAG] = str(self.context_size)
        tags[SEED_TAG] = str(self.seed)
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
        values["context_size"] = int(tags.get(CONTEXT_SIZE_TAG) or 0)
        values["seed"] = int(tags.get(SEED_TAG) or 0)
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
        """The record as a flat dict keyed by field name, with typed values (a leaderboard row):
        the overrides as JSON text, the crashed metrics comma-separated, and each card in a
        column of its own (:func:`card_column`)."""
        out: dict[str, Any] = {name: getattr(self, name) for name in _TAGS}
        out.update(
            {
                "context_size": self.context_size,
                "seed": self.seed,
                "trains": self.trains,
                "context_normals": self.context_normals,
                "variant_overrides": json.dumps(
                    self.variant_overrides, sort_keys=True, default=str
                ),
                "metric_errors": ",".join(self.metric_errors),
                "eval_points_actual": self.eval_points_actual,
            }
        )
        out.update({card_column(m): c for m, c in self.cards.items()})
        return out


def card_column(metric: str) -> str:
    """The column of :meth:`CellRecord.row` that holds ``metric``'s card."""
    return CARD_PREFIX + metric


def training_tags(
    method: str,
    dataset: str,
    key: str,
    resumed: bool = False,
    reference: str = "",
    device: str = "",
) -> dict[str, str]:
    """The tags of a training run: of checkpoint ``key``, resumed from a checkpoint or not; a
    shipped reference checkpoint names its origin and the device it was trained on."""
    tags = {
        KIND_TAG: TRAINING_KIND,
        METHOD_TAG: method,
        DATASET_TAG: dataset,
        CHECKPOINT_KEY_TAG: key,
    }
    if resumed:
        tags[RESUMED_TAG] = "true"
    if reference:
        tags[REFERENCE_TAG] = reference
        tags[TRAINING_DEVICE_TAG] = device
    return tags
