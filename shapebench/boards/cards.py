"""The metric of a table: its card in words and scale, the direction it ranks in, and the
dataset's default metric. Read by the board (:mod:`~shapebench.boards.leaderboard`), its Markdown
(:mod:`~shapebench.boards.markdown`) and the HTML report."""

from __future__ import annotations

import pandas as pd

from shapebench.api.errors import ShapebenchError
from shapebench.api.metric import MetricCard


def card_text(tag: str) -> str:
    """A card tag in words (the tag itself where it does not parse)."""
    try:
        return MetricCard.from_tag(tag).describe()
    except ValueError:
        return tag


def card_scale(card: str) -> float:
    """The factor a card's values are shown at (chamfer-l2: x1000); 1 where it does not parse."""
    try:
        return MetricCard.from_tag(card).scale
    except ValueError:
        return 1.0


def normalised_card(tag: object) -> object:
    """A card tag in today's spelling, so that an older tag of the same card groups with it."""
    if not isinstance(tag, str) or "=" not in tag:
        return tag
    try:
        return MetricCard.from_tag(tag).as_tag()
    except ValueError:
        return tag


def higher_is_better(metric: str, card: str = "") -> bool:
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


def default_metric(runs: pd.DataFrame) -> str:
    """The metric a table of ``runs`` ranks by without --metric: its dataset's default."""
    from shapebench.registry.discovery import get_registry

    dataset = runs.iloc[0]["dataset"]
    try:
        return get_registry().load("dataset", dataset).default_metric
    except ShapebenchError:
        return "chamfer-l2"
