"""The checks of a metric: its card is valid, and its value is zero on identical clouds and positive
otherwise (for a higher-is-better metric: better on identical clouds than on different ones)."""

from __future__ import annotations

import math
from collections.abc import Iterator
from typing import Any

from shapebench.api.errors import ShapebenchError
from shapebench.conformance.framework import (
    CONTEXT_SIZE,
    CheckEnv,
    CheckFailed,
    CheckResult,
    CheckSkipped,
    Component,
    run_check,
    skip_rest,
)

_METRIC_CHECKS = ("card", "identical", "different")


def metric_checks(
    comp: Component, env: CheckEnv, overrides: dict[str, Any], data_root: Any
) -> Iterator[CheckResult]:
    """The checks of a metric after ``imports``, one result at a time (a metric has no options
    and reads no data: ``overrides`` and ``data_root`` are unused)."""
    res, metric = run_check("card", lambda: _card(comp))
    yield res
    if metric is None:
        yield from skip_rest(_METRIC_CHECKS[1:], "no valid card")
        return
    res, best = run_check("identical", lambda: _identical(metric, env))
    yield res
    yield run_check("different", lambda: _different(metric, env, best))[0]


def _card(comp: Component) -> tuple[str, Any]:
    from shapebench.api.metric import check_metric

    if comp.registration is not None and comp.registration.error is not None:
        raise CheckFailed(comp.registration.reason or comp.registration.error.message)
    try:
        cls = comp.load()
    except ShapebenchError as exc:
        raise CheckFailed(comp.registration.reason if comp.registration else exc.message) from exc
    try:
        card = check_metric(cls)
    except ValueError as exc:
        raise CheckFailed(str(exc)) from exc
    return card.describe(), cls()


def _metric_object(env: CheckEnv) -> Any:
    """An object of the tiny dataset, or points on a sphere without it."""
    import numpy as np

    from shapebench.api.types import ObjectData, ObjectRef

    try:
        contexts, _ = env.contexts()
        return env.tiny_dataset().load(contexts[0].ref)
    except CheckSkipped:
        rng = np.random.default_rng(0)
        v = rng.normal(size=(2000, 3))
        v = (v / np.linalg.norm(v, axis=1, keepdims=True)).astype(np.float32)
        return ObjectData(ObjectRef("sphere/0", "sphere"), v, v, v.copy())


def _surface_object(metric: Any) -> Any:
    """For a metric that reads ground-truth arrays (``needs``): a sphere's mesh, with those
    arrays built by the code datasets use, and the mesh itself (``ObjectData.cache["mesh"]``)."""
    import numpy as np
    import trimesh

    from shapebench.api.types import GroundTruthArray, ObjectData, ObjectRef
    from shapebench.preprocess.samples import IOU_POINTS, occupancy_samples, oriented_points

    mesh = trimesh.creation.icosphere(subdivisions=3, radius=0.8)
    rng = np.random.default_rng(0)
    gt = oriented_points(mesh, 4000, rng)
    extra = {GroundTruthArray.ORIENTED_POINTS.value: gt}
    if GroundTruthArray.OCCUPANCY in metric.needs:
        extra[GroundTruthArray.OCCUPANCY.value] = occupancy_samples(mesh, IOU_POINTS // 10, rng)
    data = ObjectData(ObjectRef("sphere/0", "sphere"), gt[:, :3], gt[:, 3:], gt[:, :3], extra)
    data.cache["check.mesh"] = mesh
    return data


def _score(metric: Any, data: Any, points: Any, mesh: Any = None) -> float:
    from shapebench.api.types import Completion, Context

    context = Context(data.ref, data.surface_points[:CONTEXT_SIZE], None, 0)
    value = metric.compute(Completion(points, mesh=mesh), data, context)
    try:
        value = float(value)
    except (TypeError, ValueError) as exc:
        raise CheckFailed(f"compute() returned {value!r}, not a float") from exc
    if not math.isfinite(value):
        raise CheckFailed(f"compute() returned {value}")
    return value


def _identical(metric: Any, env: CheckEnv) -> tuple[str, float]:
    import numpy as np

    mesh = None
    if getattr(metric, "needs", None):  # a surface metric: a mesh and its ground-truth arrays
        data = _surface_object(metric)
        mesh = data.cache["check.mesh"]
    else:
        data = _metric_object(env)
    prediction, what = data.gt_points.copy(), "identical to the ground truth"
    if not getattr(metric, "needs_ground_truth", True):  # input-referenced (fidelity)
        prediction = np.concatenate([prediction, data.surface_points[:CONTEXT_SIZE]])
        what = "holding its context points (the metric reads the input, not the ground truth)"
    value = _score(metric, data, prediction, mesh)
    if not metric.higher_is_better and abs(value) > 1e-9:
        raise CheckFailed(f"{value:.3g} on a prediction {what}: expected 0")
    return f"{value:g} on a prediction {what}", (value, data)


def _different(metric: Any, env: CheckEnv, best: tuple[float, Any] | None) -> str:
    if best is None:
        raise CheckSkipped("no value on identical clouds")
    identical, data = best
    # Shrunk and shifted: every point moves, in both directions of a Chamfer distance. The same
    # ObjectData as above, as in a run, where its cache serves every completion of the object.
    moved = (data.gt_points * 0.7 + 0.05).astype("float32")
    mesh = data.cache.get("check.mesh")
    if mesh is not None:
        mesh = mesh.copy()
        mesh.apply_scale(0.7)
        mesh.apply_translation([0.05, 0.05, 0.05])
    value = _score(metric, data, moved, mesh)
    if metric.higher_is_better and not value < identical:
        raise CheckFailed(
            f"{value:.3g} on a different prediction, not below the {identical:g} "
            "of an identical one (higher is better)"
        )
    if not metric.higher_is_better and not value > 0:
        raise CheckFailed(f"{value:.3g} on a prediction unlike the ground truth: expected > 0")
    return f"{value:.4g} on a shrunk and shifted prediction"
