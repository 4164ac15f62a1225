"""Which points of a cloud a camera sees: hidden point removal (Katz, Tal and Basri, "Direct
visibility of point sets", SIGGRAPH 2007), the operator Open3D exposes as
``hidden_point_removal``.

Each point is reflected through a large sphere centred on the camera ("spherical flipping": a
point at distance d moves to distance 2R - d along its ray); a point is visible when its reflection
lies on the convex hull of the reflections and the camera. It needs no mesh and no normals, so it
simulates a single depth scan of any ground-truth cloud. A larger ``R`` keeps more points (fewer
false occlusions in concave regions, more see-through); the Open3D tutorial's choice, 100 times
the cloud's extent, is the default.
"""

from __future__ import annotations

import numpy as np

#: R as a multiple of the largest camera-to-point distance.
DEFAULT_RADIUS_FACTOR = 100.0


def visible_from(
    points: np.ndarray, camera: np.ndarray, radius_factor: float = DEFAULT_RADIUS_FACTOR
) -> np.ndarray:
    """Sorted indices of ``points`` visible from ``camera`` (outside the cloud)."""
    from scipy.spatial import ConvexHull

    rel = np.asarray(points, dtype=np.float64) - np.asarray(camera, dtype=np.float64)
    norm = np.linalg.norm(rel, axis=1, keepdims=True)
    if len(rel) < 4 or not np.all(norm > 0):
        raise ValueError("hidden point removal needs 4 points or more, none at the camera")
    radius = radius_factor * float(norm.max())
    flipped = rel + 2.0 * (radius - norm) * rel / norm
    hull = ConvexHull(np.vstack([flipped, np.zeros((1, 3))]))
    vertices = hull.vertices[hull.vertices < len(rel)]  # the camera itself is a vertex
    return np.sort(vertices)
