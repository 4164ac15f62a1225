"""A dataset's splits: the ones it declares (in its order), the ones with runs in the store, the
context protocols each has runs of, and the split its options are chosen on (the "Choices" line of
a table's header)."""

from __future__ import annotations

import pandas as pd

from shapebench.api.protocol import DEFAULT_CONTEXT
from shapebench.api.types import EVAL_SPLITS
from shapebench.boards.selection import load_runs, run_column
from shapebench.store.tracking import Tracker, experiment_name


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
    names = set(run_column(runs, "context_protocol", DEFAULT_CONTEXT))
    return sorted(names, key=lambda n: (n != DEFAULT_CONTEXT, n))
