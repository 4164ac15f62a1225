"""Scoring a method's output: one object's row of the per-object table (:func:`score`: every
metric in the protocol's frame, a crash or NaN of one metric costing that value only), and a
cell's summary of the table (:func:`summarize`)."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pandas as pd

from shapebench.api.metric import Metric, NotApplicable
from shapebench.api.types import Completion, Context, GroundTruthArray, ObjectData
from shapebench.evaluation.failures import (
    METRIC_ERROR,
    NOT_APPLICABLE,
    not_applicable,
    traceback_text,
)


def _valid_points(completion: Any) -> str | None:
    """Why a completion cannot be scored, or None if it can."""
    if not isinstance(completion, Completion):
        return f"complete() returned {type(completion).__name__}, not a Completion"
    pts = np.asarray(completion.points)
    if pts.ndim != 2 or pts.shape[1] != 3:
        return f"completion points have shape {pts.shape}, expected (n, 3)"
    if len(pts) == 0:
        return "completion has no points"
    if not np.all(np.isfinite(pts)):
        return f"completion has {int((~np.isfinite(pts)).any(axis=1).sum())} NaN/inf points"
    return None


def scaled(data: ObjectData, ctx: Context, completion: Completion, factor: float):
    """Copies of what metrics read, with every coordinate multiplied by ``factor`` (the
    protocol's evaluation frame); the originals, and the caches built on them, are untouched."""
    from dataclasses import replace

    if factor == 1.0:
        return data, ctx, completion
    sdata = replace(
        data,
        gt_points=data.gt_points * factor,
        surface_points=data.surface_points * factor,
        extra={k: _scaled_extra(k, v, factor) for k, v in data.extra.items()},
        cache={},
    )
    sctx = replace(ctx, points=ctx.points * factor)
    mesh = completion.mesh
    if mesh is not None:
        mesh = mesh.copy()
        mesh.apply_scale(factor)
    scomp = Completion(
        points=(completion.points * factor).astype(np.float32),
        mesh=mesh,
        samples=[s * factor for s in completion.samples] if completion.samples else None,
        info=completion.info,
    )
    return sdata, sctx, scomp


def _scaled_extra(name: str, array: np.ndarray, factor: float) -> np.ndarray:
    """A ground-truth array in the evaluation frame: its first three columns are coordinates;
    normals and occupancy labels do not scale."""
    if name not in {k.value for k in GroundTruthArray}:
        return array
    out = np.array(array, copy=True)
    out[:, :3] *= factor
    return out


def score(
    outcome: Completion | Exception,
    data: ObjectData,
    ctx: Context,
    metrics: list[Metric],
    frame_scale: float = 1.0,
) -> tuple[dict[str, Any], Completion | None]:
    """The per-object row for one method output: scores (in the protocol's frame, scaled by
    ``frame_scale``), or the reason it failed."""
    row: dict[str, Any] = {"status": "ok", "error": ""}
    if isinstance(outcome, Exception):  # the method's failure must not lose the other objects
        row.update(
            status="failed",
            error=f"{type(outcome).__name__}: {outcome}",
            traceback=traceback_text(outcome),
        )
        return row, None
    problem = _valid_points(outcome)
    if problem:
        row.update(status="failed", error=problem)
        return row, None
    outcome.points = np.asarray(outcome.points, dtype=np.float32)
    row["n_points"] = len(outcome.points)
    sdata, sctx, scomp = scaled(data, ctx, outcome, frame_scale)
    for metric in metrics:
        # A metric that crashes costs its own value only: the other metrics of the object stand,
        # and the object's status (the method's success) is unchanged.
        try:
            value = float(metric.compute(scomp, sdata, sctx))
            if not math.isfinite(value):
                raise ValueError(f"the metric returned {value}")
        except NotApplicable as exc:  # no value, and no error: the reason is recorded
            row[metric.name] = math.nan
            row[f"{NOT_APPLICABLE}{metric.name}"] = str(exc) or "not applicable"
            continue
        except Exception as exc:
            row[metric.name] = math.nan
            row[f"{METRIC_ERROR}{metric.name}"] = f"{type(exc).__name__}: {exc}"
            row.setdefault("traceback", traceback_text(exc))
            continue
        row[metric.name] = value
    for key, value in (outcome.info or {}).items():
        row[f"info.{key}"] = value
    if outcome.samples:
        spread = posterior_spread(outcome.points, outcome.samples)
        outcome.cache["spread"] = spread
        row["posterior_spread"] = float(spread.mean()) * frame_scale
    return row, outcome


def posterior_spread(points: np.ndarray, samples: list[np.ndarray]) -> np.ndarray:
    """Per point of the completion, the RMS over posterior samples of the distance to the nearest
    point of each sample: how uncertain the completion is there."""
    from shapebench.geometry.nearest import nearest_distances

    d = np.stack([nearest_distances(points, s) for s in samples if len(s)])
    return np.sqrt((d**2).mean(axis=0)).astype(np.float32)


def summarize(table: pd.DataFrame, metrics: list[Metric]) -> dict[str, float]:
    """A cell's metrics from its per-object table: objects, failures, seconds per object, and per
    metric the mean, std and median over the objects it scored, with how many it raised on or did
    not apply to."""
    ok = table[table["status"] == "ok"]
    out: dict[str, float] = {
        "n_objects": float(len(table)),
        "failures": float(len(table) - len(ok)),
    }
    for m in metrics:
        values = ok[m.name].to_numpy(dtype=float) if m.name in ok else np.array([])
        values = values[np.isfinite(values)]  # NaN: the metric raised or did not apply
        na = not_applicable(ok, m.name)
        if na.any():
            out[f"{m.name}.not_applicable"] = float(na.sum())
        if f"{METRIC_ERROR}{m.name}" in ok:
            out[f"{m.name}.errors"] = float(len(ok) - len(values) - int(na.sum()))
        if len(values):
            out[f"{m.name}.mean"] = float(values.mean())
            out[f"{m.name}.std"] = float(values.std(ddof=1)) if len(values) > 1 else 0.0
            out[f"{m.name}.median"] = float(np.median(values))
    out["seconds_per_object"] = float(table["seconds"].mean()) if len(table) else 0.0
    return out
