"""The Metric interface and the metric *card* that makes numbers comparable.

Chamfer distances in the literature differ by squaring, reduction, a factor 1/2, display scale,
the frame shapes are normalised in and the number of points sampled. A :class:`MetricCard` states
all of these; every logged value carries its card, and leaderboards refuse to put values with
different cards in one table.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import asdict, dataclass, fields, replace
from typing import ClassVar, Literal

from shapebench.protocol import DEFAULT_FRAME, frame_description
from shapebench.types import Completion, Context, ObjectData

#: The frame metrics are defined in; the runner sets the card's frame to the run's protocol frame
#: (see :mod:`shapebench.protocol`), since it scales shapes into that frame before scoring.
UNIT_SPHERE_FRAME = DEFAULT_FRAME


@dataclass(frozen=True)
class MetricCard:
    """The convention a metric value follows.

    power:        1 for Euclidean distances, 2 for squared distances (0 when not a distance).
    reduction:    how per-point distances are reduced within each set ("mean" or "sum").
    direction:    "symmetric" (both directions summed) or "gt->pred" (asymmetric: completeness,
                  how well the prediction covers the ground truth).
    halved:       whether the symmetric sum is multiplied by 1/2.
    scale:        the factor values are *displayed* with (1000 means "x1000"); logged raw.
    frame:        the normalisation of shapes the distances are measured in: ``unit-radius``
                  or ``unit-diameter`` (set by the runner from the protocol's ``--frame``).
    eval_points:  number of ground-truth points (and points sampled from predicted meshes).
    """

    metric: str
    power: int
    reduction: Literal["mean", "sum", "none"]
    direction: Literal["symmetric", "gt->pred", "pred->gt", "none"]
    halved: bool
    scale: float
    frame: str
    eval_points: int

    def describe(self) -> str:
        if self.power == 0:
            body = f"{self.reduction}, {self.direction}"
        else:
            dist = "squared Euclidean" if self.power == 2 else "Euclidean"
            both = (
                "summed over both directions" if self.direction == "symmetric" else self.direction
            )
            half = ", halved" if self.halved else ""
            body = f"{dist} NN distances, {self.reduction} per set, {both}{half}"
        scale = f"x{self.scale:g}" if self.scale != 1 else "x1"
        frame = frame_description(self.frame)
        return f"{self.metric}: {body}; shown {scale}; {frame}; {self.eval_points} eval points"

    def as_tag(self) -> str:
        """A stable string form for MLflow tags and equality checks."""
        return ";".join(f"{k}={v}" for k, v in asdict(self).items())

    @classmethod
    def from_tag(cls, tag: str) -> MetricCard:
        """The card :meth:`as_tag` wrote; ``ValueError`` if the tag is not one."""
        try:
            values = dict(item.split("=", 1) for item in tag.split(";"))
            types = {f.name: f.type for f in fields(cls)}
            parsed = {}
            for name, value in values.items():
                kind = types[name]
                if kind == "int":
                    parsed[name] = int(value)
                elif kind == "float":
                    parsed[name] = float(value)
                elif kind == "bool":
                    parsed[name] = value == "True"
                else:
                    parsed[name] = value
            return cls(**parsed)
        except (KeyError, ValueError, TypeError) as exc:
            raise ValueError(f"not a metric card tag: {tag!r}") from exc

    def in_frame(self, frame: str) -> MetricCard:
        return replace(self, frame=frame)


class Metric(ABC):
    """A score of one completion against the ground truth.

    ``name`` is the public name; ``higher_is_better`` the direction; ``card(eval_points)`` the
    convention (see :class:`MetricCard`). ``compute`` returns one float per object; the leaderboard
    aggregates.
    """

    name: ClassVar[str] = ""
    description: ClassVar[str] = ""
    higher_is_better: ClassVar[bool] = False

    @abstractmethod
    def card(self, eval_points: int) -> MetricCard:
        """The convention this metric's values follow when ``eval_points`` GT points are used."""

    @abstractmethod
    def compute(self, prediction: Completion, ground_truth: ObjectData, context: Context) -> float:
        """Score ``prediction`` against ``ground_truth.gt_points``."""
