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


def tail_threshold(metric: str, card: str) -> float | None:
    """The tail threshold of a table's metric, in the table's displayed units and frame: the
    installed metric's card states it (:attr:`MetricCard.tail_threshold`, x scale, unit-radius
    frame; a run's tag never carries it), converted to the table's frame by the frame's factor
    to the card's power (squared distances in the unit-diameter frame: a quarter). None when the
    metric states none or is not installed here."""
    from shapebench.api.protocol import DEFAULT_FRAME, FRAMES
    from shapebench.registry.discovery import get_registry

    try:
        board_card = MetricCard.from_tag(card)
    except ValueError:
        return None
    try:
        installed = get_registry().load("metric", metric)().card(board_card.eval_points)
    except Exception:  # an uninstalled or broken plugin: the table goes without a tail column
        return None
    threshold = installed.tail_threshold
    if threshold is None:
        return None
    if board_card.power > 0 and board_card.reduction != "fraction":
        factor = FRAMES[board_card.frame][0] / FRAMES[DEFAULT_FRAME][0]
        threshold *= factor**board_card.power
    return float(threshold)


def worse_word(higher: bool) -> str:
    """How a value worse than the tail threshold lies: above it, or below it."""
    return "below" if higher else "above"
