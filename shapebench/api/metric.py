"""The Metric interface and the metric *card* that makes numbers comparable.

Chamfer distances in the literature differ by squaring, reduction, a factor 1/2, display scale,
the frame shapes are normalised in and the number of points sampled; a Hausdorff distance takes a
max where Chamfer takes a mean, and an F-score counts points within a threshold. A
:class:`MetricCard` states all of these; every logged value carries its card, and leaderboards
refuse to put values with different cards in one table.

The allowed values of the card's enumerated fields are the keys of :data:`POWERS`,
:data:`REDUCTIONS`, :data:`DIRECTIONS` and :data:`COMBINES`; :meth:`MetricCard.validate` checks a
card against them, and the registry checks every metric plugin's card when it loads the metric
(see :func:`check_metric`).
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from dataclasses import dataclass, field, fields, replace
from typing import Any, ClassVar, Literal

from shapebench.api.protocol import DEFAULT_FRAME, FRAMES, frame_description
from shapebench.api.types import Completion, Context, GroundTruthArray, ObjectData

#: The frame metrics are defined in; the runner sets the card's frame to the run's protocol frame
#: (see :mod:`shapebench.api.protocol`), since it scales shapes into that frame before scoring.
UNIT_SPHERE_FRAME = DEFAULT_FRAME

#: ``power``: what each per-point value is.
POWERS: dict[int, str] = {
    0: "not a distance: the card's `quantity` says what each per-point value is",
    1: "Euclidean distances to the nearest neighbour in the other set",
    2: "squared Euclidean distances to the nearest neighbour in the other set",
}

#: ``reduction``: how the per-point values of one set become one number.
REDUCTIONS: dict[str, str] = {
    "mean": "mean over the points of the set (Chamfer, normal consistency)",
    "sum": "sum over the points of the set",
    "max": "largest value over the points of the set (Hausdorff)",
    "fraction": "fraction of the points whose value is below `threshold` (precision and "
    "recall of an F-score)",
    "none": "no per-point reduction: the metric is one number per object (volume IoU, ...)",
}

#: ``direction``: which set's points are measured against which.
DIRECTIONS: dict[str, str] = {
    "symmetric": "both directions, joined as `combine` says",
    "gt->pred": "from each ground-truth point to the prediction only (completeness, recall)",
    "pred->gt": "from each predicted point to the ground truth only (accuracy, precision)",
    "none": "not a comparison of two point sets",
    "matched": "both sets at once, each point paired with one point of the other set by a "
    "one-to-one matching (earth mover's distance)",
    "context->pred": "from each context point (the method's input) to the prediction only "
    "(fidelity: no ground truth needed)",
}

#: ``combine``: how a symmetric metric joins its two directions.
COMBINES: dict[str, str] = {
    "sum": "the two directions added (Chamfer; times 1/2 when `halved`)",
    "mean": "the mean of the two directions",
    "max": "the larger of the two directions (Hausdorff)",
    "harmonic-mean": "2ab / (a + b) of the two directions (F-score from precision and recall)",
}

#: Fields added after the first tag format; ``as_tag`` leaves them out at their defaults, so the
#: tags (and the cell keys that hold them) of cards that do not use them never change.
_LATER_FIELDS = ("combine", "threshold", "higher_is_better", "quantity")

#: Fields that say how to *read* values, not how they are computed: ``as_tag`` never writes
#: them, so they are in no run's tag and no cell key, and changing one reruns nothing.
_READING_FIELDS = ("tail_threshold",)

#: The reduction the built-in F-score wrote before ``threshold`` existed (tags of old runs).
_LEGACY_FRACTION = "fraction within tau="


@dataclass(frozen=True)
class MetricCard:
    """The convention a metric value follows.

    Build it with keywords in :meth:`Metric.card`; every field is listed below with its allowed
    values. Two values can share a leaderboard only when their cards are equal, so a card must
    state everything that changes the number. ``describe()`` turns it into the sentence
    ``shapebench metrics`` and leaderboards print.
    """

    #: The metric's public name (the same as :attr:`Metric.name`).
    metric: str
    #: 1 for Euclidean distances, 2 for squared distances, 0 when the values are not distances
    #: (then ``quantity`` says what they are); see ``POWERS``.
    power: int
    #: How per-point values are reduced within each set; see ``REDUCTIONS``.
    reduction: Literal["mean", "sum", "max", "fraction", "none"]
    #: Which set is measured against which; see ``DIRECTIONS``.
    direction: Literal["symmetric", "gt->pred", "pred->gt", "none"]
    #: Whether the symmetric sum is multiplied by 1/2 (only with ``combine="sum"``).
    halved: bool
    #: The factor values are *displayed* with (1000 means "x1000"); values are logged raw.
    scale: float
    #: The normalisation of shapes the values are measured in: ``unit-radius`` or
    #: ``unit-diameter``. Pass ``UNIT_SPHERE_FRAME``; the runner sets the run's frame.
    frame: str
    #: Number of ground-truth points (and points sampled from predicted meshes).
    eval_points: int
    #: How a symmetric metric joins its two directions; see ``COMBINES``. One-directional
    #: metrics keep the default.
    combine: Literal["sum", "mean", "max", "harmonic-mean"] = "sum"
    #: The distance a ``fraction`` counts points below (F-score's tau), in the card's frame;
    #: required by ``reduction="fraction"`` and used by nothing else.
    threshold: float | None = None
    #: Whether larger values are better (F-score, normal consistency); must equal
    #: :attr:`Metric.higher_is_better`.
    higher_is_better: bool = False
    #: What each per-point value is, when it is not a nearest-neighbour distance (required when
    #: ``power`` is 0), e.g. "|cos| between the normals of nearest neighbours".
    quantity: str = ""
    #: Where a value counts as a bad result, for the leaderboards' tail column (the share of
    #: (object, seed) pairs worse than it: above it, or below it when ``higher_is_better``). In
    #: displayed units (after ``scale``) in the unit-radius frame; leaderboards in another frame
    #: convert it by the frame's factor to the ``power``. ``None``: no tail column. A reading
    #: aid, not part of the convention: it is left out of the tag (:data:`_READING_FIELDS`) and
    #: out of equality, so it can change without rerunning a cell.
    tail_threshold: float | None = field(default=None, compare=False)

    def validate(self) -> None:
        """Raise ``ValueError`` naming every problem of this card.

        Besides the allowed values of ``power``, ``reduction``, ``direction``, ``combine`` and
        ``frame`` (tables below), a valid card has: a ``threshold`` (a positive number) exactly
        when ``reduction`` is ``"fraction"``; a ``combine`` other than ``"sum"`` only with
        ``direction="symmetric"``; ``halved=True`` only with ``direction="symmetric"`` and
        ``combine="sum"``; a ``quantity`` when ``power`` is 0; a finite ``tail_threshold`` or
        None; a positive ``scale``; an integer ``eval_points`` >= 0; boolean ``halved`` and
        ``higher_is_better``; and no ``;`` (the tag separator) in ``metric``, ``frame`` or
        ``quantity``.
        """
        problems = _problems(self)
        if problems:
            raise ValueError(f"invalid metric card for {self.metric!r}: " + "; ".join(problems))

    def describe(self) -> str:
        """One sentence: what is measured, how it is reduced, scale, frame and sample size."""
        parts = [_body(self)]
        if self.higher_is_better:
            parts.append("higher is better")
        parts.append(f"shown x{self.scale:g}")
        parts.append(frame_description(self.frame))
        parts.append(f"{self.eval_points} eval points")
        return f"{self.metric}: " + "; ".join(parts)

    def as_tag(self) -> str:
        """A stable string form for MLflow tags, cell keys and equality checks.

        ``key=value`` pairs joined by ``;``; fields added after the first format appear only when
        they differ from their default, so older cards keep their tags; the fields of reading
        (``tail_threshold``) never appear.
        """
        items = []
        for f in fields(self):
            if f.name in _READING_FIELDS:
                continue
            value = getattr(self, f.name)
            if f.name in _LATER_FIELDS and value == f.default:
                continue
            items.append(f"{f.name}={value}")
        return ";".join(items)

    @classmethod
    def from_tag(cls, tag: str) -> MetricCard:
        """The card :meth:`as_tag` wrote (any version); ``ValueError`` if the tag is not one."""
        try:
            values = dict(item.split("=", 1) for item in tag.split(";"))
            types = {f.name: str(f.type) for f in fields(cls)}
            parsed: dict[str, Any] = {name: _parse(types[name], v) for name, v in values.items()}
            if str(parsed.get("reduction", "")).startswith(_LEGACY_FRACTION):
                parsed.update(_legacy_fscore(parsed["reduction"]))
            return cls(**parsed)
        except (KeyError, ValueError, TypeError) as exc:
            raise ValueError(f"not a metric card tag: {tag!r}") from exc

    def in_frame(self, frame: str) -> MetricCard:
        """This card with its frame set to ``frame`` (the runner's evaluation frame)."""
        return replace(self, frame=frame)


def _parse(kind: str, value: str) -> Any:
    if kind == "int":
        return int(value)
    if kind == "float":
        return float(value)
    if kind == "float | None":
        return None if value == "None" else float(value)
    if kind == "bool":
        if value not in ("True", "False"):
            raise ValueError(f"not a bool: {value!r}")
        return value == "True"
    return value


def _legacy_fscore(reduction: str) -> dict[str, Any]:
    """Old F-score tags wrote the threshold into the reduction; read them as the card that the
    built-in ``fscore`` metric states today."""
    return {
        "power": 1,
        "reduction": "fraction",
        "threshold": float(reduction[len(_LEGACY_FRACTION) :]),
        "combine": "harmonic-mean",
        "higher_is_better": True,
    }


def _allowed(name: str, value: object, allowed: dict) -> list[str]:
    # type() too: True == 1 would otherwise pass as power 1
    if type(value) is type(next(iter(allowed))) and value in allowed:
        return []
    return [f"{name}={value!r} is not one of: {', '.join(repr(a) for a in allowed)}"]


def _positive_number(value: object) -> bool:
    return (
        isinstance(value, (int, float))
        and not isinstance(value, bool)
        and math.isfinite(value)
        and value > 0
    )


def _problems(card: MetricCard) -> list[str]:
    """Everything wrong with ``card``, one phrase each (empty when it is valid)."""
    out: list[str] = []
    for name in ("metric", "frame", "quantity"):
        value = getattr(card, name)
        if not isinstance(value, str) or ";" in value:
            out.append(f"{name}={value!r} must be a string without ';'")
    if isinstance(card.metric, str) and not card.metric:
        out.append("metric must be the metric's name, not empty")
    out += _allowed("power", card.power, POWERS)
    out += _allowed("reduction", card.reduction, REDUCTIONS)
    out += _allowed("direction", card.direction, DIRECTIONS)
    out += _allowed("combine", card.combine, COMBINES)
    if card.frame not in FRAMES:
        out.append(f"frame={card.frame!r} is not one of: {', '.join(repr(f) for f in FRAMES)}")
    for name in ("halved", "higher_is_better"):
        if not isinstance(getattr(card, name), bool):
            out.append(f"{name}={getattr(card, name)!r} must be True or False")
    if not _positive_number(card.scale):
        out.append(f"scale={card.scale!r} must be a positive number")
    if not isinstance(card.eval_points, int) or isinstance(card.eval_points, bool):
        out.append(f"eval_points={card.eval_points!r} must be an integer")
    elif card.eval_points < 0:
        out.append(f"eval_points={card.eval_points!r} must not be negative")
    if card.reduction == "fraction" and card.threshold is None:
        out.append("reduction='fraction' needs a threshold (the distance points are counted below)")
    if card.threshold is not None:
        if card.reduction != "fraction":
            out.append(f"threshold={card.threshold!r} is used only by reduction='fraction'")
        elif not _positive_number(card.threshold):
            out.append(f"threshold={card.threshold!r} must be a positive number")
    if card.direction != "symmetric" and card.combine != "sum":
        out.append(f"combine={card.combine!r} joins two directions: it needs direction='symmetric'")
    if card.halved is True and (card.direction != "symmetric" or card.combine != "sum"):
        out.append("halved=True needs direction='symmetric' and combine='sum'")
    tail = card.tail_threshold
    if tail is not None and (
        isinstance(tail, bool) or not isinstance(tail, (int, float)) or not math.isfinite(tail)
    ):
        out.append(f"tail_threshold={tail!r} must be a finite number or None")
    if card.power == 0 and not card.quantity:
        out.append("power=0 (not a distance) needs a quantity saying what each value is")
    return out


def _body(card: MetricCard) -> str:
    """What is measured and how it is reduced; the Chamfer wording predates the other fields."""
    if card.quantity:
        what = card.quantity
    elif card.power == 2:
        what = "squared Euclidean NN distances"
    else:
        what = "Euclidean NN distances"
    if card.reduction == "none":
        per_set = ""
    elif card.direction == "matched":
        per_set = f", {card.reduction} over the matched pairs"
    elif card.reduction == "fraction":
        per_set = f", fraction below {card.threshold:g} per set"
    else:
        per_set = f", {card.reduction} per set"
    if card.direction == "symmetric":
        joined = {
            "sum": "summed over both directions",
            "mean": "mean of both directions",
            "max": "max of both directions",
            "harmonic-mean": "harmonic mean of both directions",
        }.get(card.combine, card.combine)
        if card.halved:
            joined += ", halved"
    elif card.direction in ("none", "matched"):  # a matching pairs the sets in one go
        joined = ""
    else:
        joined = card.direction
    return what + per_set + (f", {joined}" if joined else "")


class NotApplicable(Exception):
    """Raised by :meth:`Metric.compute` when the metric does not apply to this completion or
    object: a mesh metric on a completion that is points only (PCN, Gauss), a metric needing
    ground-truth normals on a dataset of bare points. The runner records the value as *not
    applicable* with the message as its reason: not a failure of the object, never a zero, and
    leaderboards show ``n/a``. The message says why in a few words ("the completion is points
    only, with no mesh")."""


class Metric(ABC):
    """A score of one completion against the ground truth.

    Subclass it, set the class attributes, implement :meth:`card` and :meth:`compute`, and
    register the class through the ``shapebench_register_metrics`` hook. The runner builds one
    instance (``Metric()``, no options) per run and calls ``compute`` once per object and context
    size; the leaderboard aggregates the per-object values.
    """

    #: The public name (``--metric``, the ``card.<name>`` run tags); also ``card().metric``.
    name: ClassVar[str] = ""
    #: One line for ``shapebench metrics``.
    description: ClassVar[str] = ""
    #: Whether larger values are better; the card's ``higher_is_better`` must agree.
    higher_is_better: ClassVar[bool] = False
    #: Whether a run that names no metric computes this one. False for metrics computed on
    #: request only (``--metric NAME``): costly ones (EMD) and other papers' conventions. The
    #: metrics a run computes are part of its cell keys, so a new default metric would make
    #: every stored cell a different cell.
    by_default: ClassVar[bool] = True
    #: Whether the metric compares with the ground truth. Metrics that compare the completion
    #: with its input only (fidelity) say False: they are the ones that apply to datasets
    #: without ground truth, where they are computed by default.
    needs_ground_truth: ClassVar[bool] = True
    #: Ground-truth arrays beyond ``gt_points`` that ``compute`` reads from
    #: ``ground_truth.extra`` (a :class:`~shapebench.api.types.GroundTruthArray` value each). The
    #: runner asks the dataset for them; a dataset that cannot build them (bare points) leaves
    #: them out, and ``compute`` raises :class:`NotApplicable`.
    needs: ClassVar[frozenset[GroundTruthArray]] = frozenset()

    @abstractmethod
    def card(self, eval_points: int) -> MetricCard:
        """The convention this metric's values follow when ``eval_points`` GT points are used.

        Return ``MetricCard(metric=self.name, ..., frame=UNIT_SPHERE_FRAME,
        eval_points=eval_points)``; it must pass :meth:`MetricCard.validate`, or the registry
        disables the metric with a warning.
        """

    @abstractmethod
    def compute(self, prediction: Completion, ground_truth: ObjectData, context: Context) -> float:
        """Score ``prediction`` against ``ground_truth.gt_points``; return one float.

        ``prediction.points`` and ``ground_truth.gt_points`` are ``(n, 3)`` arrays already scaled
        into the run's evaluation frame, as are ``context.points``, ``prediction.mesh`` and the
        arrays of ``needs`` (when the frame scales shapes, ``prediction`` carries ``points``,
        ``mesh``, ``samples`` and ``info``, not ``sdf``). ``prediction.cache`` and
        ``ground_truth.cache`` are scratch dicts shared by the metrics of one object (nearest
        neighbour distances, KD-trees); prefix your keys with the metric's name. Raise
        :class:`NotApplicable` when the metric does not apply (no mesh, no ground-truth normals);
        raise anything else, or return NaN, when the value cannot be computed: the metric is then
        recorded as failed on that object.
        """


#: Named sets of metrics: the conventions a community reports in (``--metric pcn``). A name
#: that is also an installed metric's means the metric. docs/metrics.md has the conventions.
PRESETS: dict[str, tuple[str, ...]] = {
    # PCN / PoinTr / AdaPoinTr tables: CD-L1 (halved), CD-L2 (squared, summed), F-Score@0.01.
    "pcn": ("chamfer-l1-pointr", "chamfer-l2", "fscore"),
    # ConvONet / POCO: IoU, Chamfer-L1 = 1/2 (accuracy + completeness), normal consistency,
    # F-Score at 1 %.
    "convonet": ("iou", "chamfer-l1-pointr", "normal-consistency", "fscore"),
    # The MVP benchmark and DCD papers: CD-L2, DCD, F-Score.
    "mvp": ("chamfer-l2", "dcd", "fscore"),
    # The MSC paper's tables (with --frame unit-diameter).
    "paper": ("chamfer-l2",),
}


#: The ``eval_points`` the registry passes to ``card()`` when it checks a metric plugin.
CHECK_EVAL_POINTS = 30_000


def check_metric(cls: object, eval_points: int = CHECK_EVAL_POINTS) -> MetricCard:
    """Check a metric class the way the registry does when it first loads one; return its card.

    ``cls`` must be a :class:`Metric` subclass with a ``name``, ``cls()`` must work,
    ``cls().card(eval_points)`` must return a :class:`MetricCard` that passes
    :meth:`MetricCard.validate`, whose ``metric`` is the class's ``name`` and whose
    ``higher_is_better`` is the class's. Otherwise ``ValueError`` says what is wrong, and the
    registry disables that metric with a :class:`~shapebench.registry.discovery.PluginWarning`
    naming its
    plugin; the other metrics still run.
    """
    if not (isinstance(cls, type) and issubclass(cls, Metric)):
        raise ValueError(f"{cls!r} is not a subclass of shapebench.Metric")
    if not cls.name:
        raise ValueError(f"{cls.__name__} has no name: set the class attribute name")
    try:
        card = cls().card(eval_points)
    except Exception as exc:
        raise ValueError(f"{cls.__name__}().card({eval_points}) raised {_exc(exc)}") from exc
    if not isinstance(card, MetricCard):
        raise ValueError(f"{cls.__name__}.card() returned {card!r}, not a MetricCard")
    card.validate()
    if card.metric != cls.name:
        raise ValueError(f"the card names metric {card.metric!r} but the class is {cls.name!r}")
    if card.higher_is_better is not bool(cls.higher_is_better):
        raise ValueError(
            f"the card says higher_is_better={card.higher_is_better} but the class says "
            f"{cls.higher_is_better}"
        )
    return card


def _exc(exc: BaseException) -> str:
    return f"{type(exc).__name__}: {exc}"
