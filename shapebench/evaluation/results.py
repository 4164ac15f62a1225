"""What computing (or finding) a cell hands back: :class:`CellResult`, the cell's metrics and
where its run and per-object table are, with the failure reasons ``shapebench run`` prints."""

from __future__ import annotations

from dataclasses import dataclass, field


@dataclass
class CellResult:
    split: str
    context_size: int
    seed: int
    run_id: str
    skipped: bool
    metrics: dict[str, float]
    experiment_id: str
    #: The most common failure reasons of this cell with their counts (new cells only).
    reasons: list[tuple[str, int]] = field(default_factory=list)
    #: Where the per-object table is (an artifact URI).
    table_uri: str = ""
    #: The traceback of the first object behind each reason (for ``--debug``).
    tracebacks: dict[str, str] = field(default_factory=dict)
    #: Metric name -> the card its values follow (:meth:`MetricCard.as_tag`).
    cards: dict[str, str] = field(default_factory=dict)
    #: (metric, reason, objects) for each metric that did not apply to some objects (new cells).
    not_applicable: list[tuple[str, str, int]] = field(default_factory=list)

    def scale(self, metric: str) -> float:
        """The factor ``metric``'s values are shown with (its card's), 1 when unknown."""
        from shapebench.api.metric import MetricCard

        try:
            return MetricCard.from_tag(self.cards[metric]).scale
        except (KeyError, ValueError):
            return 1.0

    @property
    def n_objects(self) -> int:
        return int(self.metrics.get("n_objects", 0))

    @property
    def n_ok(self) -> int:
        return self.n_objects - int(self.metrics.get("failures", 0))
