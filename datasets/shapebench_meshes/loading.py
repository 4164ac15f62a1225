"""Reading one mesh file into one triangle mesh, for every dataset read from users' files.

Real files are messy: OBJ files split into one geometry per material (ShapeNet's often hold
dozens, some of them empty), GLB files are scenes with transforms, PLY files may be point clouds,
and a truncated download parses into nothing at all. This module turns all of that into either a
single :class:`trimesh.Trimesh` in the file's frame or an :class:`ObjectLoadError` that names the
file and the reason, which :class:`shapebench.api.dataset.MeshDataset` records as that object's
failure while the other objects go on.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import trimesh

from shapebench.api.dataset import ObjectLoadError

#: File suffixes trimesh reads as triangle meshes (lower case, with the dot).
MESH_SUFFIXES = (".obj", ".off", ".ply", ".stl", ".glb")


def load_mesh_file(path: Path) -> trimesh.Trimesh:
    """All triangles of ``path`` as one mesh; raise :class:`ObjectLoadError` if there are none.

    The file is read as a scene so that every part is placed by its scene transform, then the
    parts that have triangles are concatenated (lines, points and empty material groups are
    dropped). Materials and textures are skipped: only geometry matters here, and loading
    ShapeNet's textures would cost more than the geometry.
    """
    path = Path(path)
    if not path.is_file():
        raise ObjectLoadError(f"mesh file {path} does not exist")
    kwargs = {"skip_materials": True} if path.suffix.lower() == ".obj" else {}
    try:
        loaded = trimesh.load(str(path), force="scene", **kwargs)
        parts = [
            g
            for g in (loaded.dump() if isinstance(loaded, trimesh.Scene) else [loaded])
            if isinstance(g, trimesh.Trimesh) and len(g.faces) > 0
        ]
    except Exception as exc:  # trimesh raises whatever its parser hits on a broken file
        raise ObjectLoadError(f"cannot read mesh file {path}: {type(exc).__name__}: {exc}") from exc
    if not parts:
        raise ObjectLoadError(
            f"mesh file {path} has no triangles (empty, truncated, or a point cloud)"
        )
    mesh = parts[0] if len(parts) == 1 else trimesh.util.concatenate(parts)
    if not (np.all(np.isfinite(mesh.vertices)) and _raw_vertices_finite(path, kwargs)):
        raise ObjectLoadError(f"mesh file {path} has NaN or infinite vertex coordinates")
    if not mesh.area > 0:  # normalisation would divide by zero and sampling find no surface
        raise ObjectLoadError(
            f"mesh file {path} has zero surface area (every triangle is degenerate)"
        )
    return mesh


def _raw_vertices_finite(path: Path, kwargs: dict) -> bool:
    """Whether every vertex the file holds is finite. trimesh's processing (merging vertices)
    silently drops NaN and infinite vertices with their faces, so a damaged file would be scored
    as another shape; the file is parsed a second time without processing to see them. The mesh
    used is still the processed one: processing changes the vertex lists of real files (merged
    duplicates), and the preprocessed data must not change."""
    raw = trimesh.load(str(path), force="scene", process=False, **kwargs)
    geometries = raw.geometry.values() if isinstance(raw, trimesh.Scene) else [raw]
    return all(
        np.all(np.isfinite(np.asarray(g.vertices))) for g in geometries if hasattr(g, "vertices")
    )
