"""Links into the MLflow UI, and shapebench's view of an experiment there.

:meth:`shapebench.store.tracking.Tracker.describe_experiment` stores the view (:func:`view_state`,
under :data:`VIEW_KEY`) on every evaluation experiment; ``shapebench ui``
(:mod:`~shapebench.store.ui`) and ``shapebench runs/show`` (:mod:`~shapebench.store.listing`)
print the links that open it (:func:`experiment_url`, :func:`run_url`).
"""

from __future__ import annotations

from typing import Any

#: shapebench's view of an evaluation experiment: the metric columns shown in the runs table.
VIEW_KEY = "shapebench"

#: The chart section shapebench's view opens with (before MLflow's own "Model metrics").
CHART_SECTION = "shapebench-context"


def view_state(metrics: list[str]) -> dict[str, Any]:
    """The MLflow UI's view state for an experiment (the JSON its "Share" button stores): the
    runs table shows these metrics (and the dataset) as columns instead of hiding every metric
    behind "Show more columns", and the chart view opens on a line chart per metric against
    the step, which is the context size on parent runs (log axis, as the paper's plots)."""
    columns = [f"metrics.`{m}`" for m in metrics] + ["attributes.`Dataset`"]
    charts = [
        {
            "type": "LINE",
            "uuid": f"shapebench-{i}",
            "metricSectionId": CHART_SECTION,
            "isGenerated": False,
            "deleted": False,
            "runsCountToCompare": 10,
            "displayName": f"{metric} against context size",
            "metricKey": metric,
            "selectedMetricKeys": [metric],
            "lineSmoothness": 0,
            "xAxisKey": "step",
            "xAxisScaleType": "log",
            "scaleType": "linear",
            "selectedXAxisMetricKey": "",
            "displayPoints": True,
            "yAxisKey": "metric",
            "yAxisExpressions": [],
            "ignoreOutliers": False,
            "useGlobalXaxisKey": False,
            "useGlobalLineSmoothing": False,
            "range": {"xMin": None, "xMax": None, "yMin": None, "yMax": None},
        }
        for i, metric in enumerate(metrics)
    ]
    section = {
        "uuid": CHART_SECTION,
        "name": "Against context size (step = context points)",
        "display": True,
        "isReordered": False,
        "deleted": False,
        "isGenerated": False,
    }
    return {"selectedColumns": columns, "compareRunCharts": charts, "compareRunSections": [section]}


def experiment_url(base: str, exp_id: str, charts: bool = False, view: bool = True) -> str:
    """The link to an experiment's runs page in the MLflow UI at ``base`` (``#/experiments/<id>
    /runs``), opening shapebench's view of it and, with ``charts``, its chart view."""
    query = [f"viewStateShareKey={VIEW_KEY}"] if view else []
    if charts:
        query.append("compareRunsMode=CHART")
    return f"{base.rstrip('/')}/#/experiments/{exp_id}/runs" + (
        "?" + "&".join(query) if query else ""
    )


def run_url(base: str, exp_id: str, run_id: str) -> str:
    """The link to one run's page in the MLflow UI at ``base``."""
    return f"{base.rstrip('/')}/#/experiments/{exp_id}/runs/{run_id}"
