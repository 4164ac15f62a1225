"""One mesh in, the cached arrays of one object out."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import trimesh

from shapebench.geometry.sampling import sample_surface
from shapebench.preprocess.normalize import normalize
from shapebench.preprocess.visibility import visible_points

#: Bump whenever the arrays produced from the same mesh change: it is part of every mesh
#: dataset's fingerprint, so old caches and old contexts are never mixed with new ones.
PREPROCESS_VERSION = "2"


class PreprocessError(ValueError):
    """The mesh cannot be turned into benchmark data (empty, degenerate, never visible...)."""


@dataclass(frozen=True)
class PreprocessParams:
    """Sizes of the arrays produced per object.

    The paper uses 200k surface candidates and 30k ground-truth points with 100 viewpoints;
    ``surface_candidates`` is smaller by default because contexts draw at most 1000 points.
    """

    surface_candidates: int = 20_000
    gt_points: int = 30_000
    viewpoints: int = 100
    min_visible: int = 1


def _check_mesh(mesh: trimesh.Trimesh) -> None:
    if len(mesh.faces) == 0 or len(mesh.vertices) < 3:
        raise PreprocessError("mesh has no faces")
    if not np.all(np.isfinite(mesh.vertices)):
        raise PreprocessError("mesh has NaN or infinite vertex coordinates")
    if not mesh.area > 0:
        raise PreprocessError("mesh has zero surface area (every triangle is degenerate)")


def _normalised_ground_truth(
    mesh: trimesh.Trimesh, params: PreprocessParams, rng: np.random.Generator
) -> tuple[trimesh.Trimesh, np.ndarray, float, np.ndarray]:
    """The first draws of :func:`prepare_mesh`: the normalised mesh, its normalisation and the
    ground-truth points, which ``rng`` gives before any visible point is drawn."""
    _check_mesh(mesh)
    try:
        unit, center, scale = normalize(mesh)
        gt, _ = sample_surface(unit.vertices, unit.faces, params.gt_points, rng)
    except ValueError as exc:
        raise PreprocessError(str(exc)) from exc
    return unit, center, scale, gt


def prepare_ground_truth(
    mesh: trimesh.Trimesh, params: PreprocessParams, rng: np.random.Generator
) -> np.ndarray:
    """The ``gt_points`` :func:`prepare_mesh` returns for the same mesh, parameters and generator
    state, bit for bit, without the visible points: their ray casting is most of an object's
    preprocessing (about 70 % for a synthetic shape), and a user of the ground truth alone (the
    retrieval index of the training shapes) does not need it."""
    return _normalised_ground_truth(mesh, params, rng)[3].astype(np.float32)


def prepare_mesh(
    mesh: trimesh.Trimesh, params: PreprocessParams, rng: np.random.Generator
) -> dict[str, np.ndarray]:
    """Normalise ``mesh`` and sample its visible surface points and ground truth.

    Returns float32 arrays ``surface_points``, ``surface_normals``, ``gt_points`` and the
    normalisation (``center``, ``scale``) that maps the source mesh into the benchmark frame.
    """
    unit, center, scale, gt = _normalised_ground_truth(mesh, params, rng)
    pts, nrm = visible_points(unit, params.surface_candidates, params.viewpoints, rng)
    if len(pts) < params.min_visible:
        raise PreprocessError(
            f"only {len(pts)} of {params.surface_candidates} surface samples are visible from "
            f"{params.viewpoints} viewpoints (need {params.min_visible})"
        )
    return {
        "surface_points": pts.astype(np.float32),
        "surface_normals": nrm.astype(np.float32),
        "gt_points": gt.astype(np.float32),
        "center": center.astype(np.float64),
        "scale": np.array(scale, dtype=np.float64),
    }
