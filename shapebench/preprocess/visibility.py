"""Surface points visible from viewpoints around an object (the paper's *disemboweled* points).

The paper renders 100 views with OpenGL and keeps the surface points seen in any of them. The
same set is found here by ray casting: candidate points are sampled area-weighted on the surface,
and a candidate is visible if the segment from it to at least one viewpoint leaves the object
without hitting the mesh. With embree (``embreex``) trimesh casts about 5 M rays/s on 2 cores;
without it, its pure-numpy caster is about 1,000 times slower (measured here: 204k rays/s against
156 on one icosphere), which turns minutes of preparation into days: the first call warns.
The normal of each visible point is oriented towards a viewpoint that sees it, which also repairs
meshes with flipped faces.
"""

from __future__ import annotations

import functools
import warnings

import numpy as np
import trimesh

from shapebench.geometry.sampling import sample_surface

# Distance from the surface at which shadow rays start, so they do not hit their own triangle.
RAY_OFFSET = 1e-4


class SlowRayCastingWarning(UserWarning):
    """trimesh casts rays without embree: preparing data will be very slow."""


@functools.cache
def _warn_without_embree() -> None:
    if not trimesh.ray.has_embree:
        warnings.warn(
            "embreex is not importable, so trimesh casts the visibility rays in numpy, about "
            "1,000 times slower: preparing each object takes minutes. Fix: pip install embreex",
            SlowRayCastingWarning,
            stacklevel=3,
        )


def fibonacci_viewpoints(n: int, radius: float) -> np.ndarray:
    """``n`` points spread evenly over a sphere of ``radius`` (a Fibonacci lattice)."""
    i = np.arange(n, dtype=np.float64) + 0.5
    z = 1.0 - 2.0 * i / n
    r = np.sqrt(1.0 - z * z)
    phi = np.pi * (1.0 + 5.0**0.5) * i
    return radius * np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=1)


def visible_points(
    mesh: trimesh.Trimesh,
    n_candidates: int,
    n_views: int,
    rng: np.random.Generator,
    view_radius: float = 3.0,
) -> tuple[np.ndarray, np.ndarray]:
    """Sample ``n_candidates`` surface points and keep those visible from any viewpoint.

    ``mesh`` must be normalised (inside the unit sphere) so that viewpoints at ``view_radius``
    are outside it. Returns ``(points, normals)`` of the visible candidates.
    """
    _warn_without_embree()
    points, face = sample_surface(mesh.vertices, mesh.faces, n_candidates, rng)
    normals = np.asarray(mesh.face_normals, dtype=np.float64)[face]
    views = fibonacci_viewpoints(n_views, view_radius)
    intersector = mesh.ray
    seen_from = np.full(n_candidates, -1, dtype=np.int64)
    pending = np.arange(n_candidates)
    for v, view in enumerate(views):
        if pending.size == 0:
            break
        direction = view - points[pending]
        direction /= np.linalg.norm(direction, axis=1, keepdims=True)
        # Start just off the surface, on the side facing the view, so the ray cannot re-hit its own
        # face; moving along the view direction too could cross into a neighbouring face at edges.
        side = np.sign(np.einsum("ij,ij->i", normals[pending], direction))[:, None]
        origin = points[pending] + RAY_OFFSET * side * normals[pending]
        blocked = intersector.intersects_any(origin, direction)
        free = pending[~blocked]
        seen_from[free] = v
        pending = pending[blocked]
    visible = seen_from >= 0
    pts, nrm, seen = points[visible], normals[visible], views[seen_from[visible]]
    facing = np.einsum("ij,ij->i", nrm, seen - pts) < 0
    nrm[facing] *= -1.0
    return pts, nrm
