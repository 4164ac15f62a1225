"""Normalisation to the paper's frame: centre of mass at the origin, max vertex distance 1."""

from __future__ import annotations

import numpy as np
import trimesh


def center_of_mass(mesh: trimesh.Trimesh) -> np.ndarray:
    """Volume centroid of a closed mesh; area centroid of the surface otherwise.

    The volume centroid is only meaningful for a closed, consistently wound mesh; scanned or CAD
    meshes with holes fall back to the surface's area-weighted centroid.
    """
    if mesh.is_watertight and mesh.is_winding_consistent and abs(mesh.volume) > 1e-12:
        return np.asarray(mesh.center_mass, dtype=np.float64)
    tri = mesh.triangles
    areas = mesh.area_faces
    return (tri.mean(axis=1) * areas[:, None]).sum(axis=0) / areas.sum()


def normalize(mesh: trimesh.Trimesh) -> tuple[trimesh.Trimesh, np.ndarray, float]:
    """Return a normalised copy of ``mesh`` with the translation and scale applied."""
    center = center_of_mass(mesh)
    vertices = np.asarray(mesh.vertices, dtype=np.float64) - center
    radius = float(np.linalg.norm(vertices, axis=1).max())
    if not np.isfinite(radius) or radius <= 0:
        raise ValueError("mesh is degenerate (all vertices at one point)")
    out = trimesh.Trimesh(vertices / radius, mesh.faces.copy(), process=False)
    return out, center, radius
