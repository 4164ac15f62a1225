"""Reading one completion file: point clouds (``.npy``, ``.xyz``, ``.pcd``, a ``.ply`` of
vertices) or meshes (``.obj``, ``.off``, a ``.ply`` with faces).

A mesh is scored as every built-in mesh is (:func:`shapebench.geometry.meshing.
sample_mesh_points`: ``n_points`` area-weighted points drawn with the context's seed), and the
mesh metrics see the mesh; a cloud is scored as it is, and the mesh metrics record "not
applicable" with their reason. Whatever cannot be scored (unreadable, empty, NaN or infinite
coordinates, not ``(n, 3)``) raises one line naming the file: the run records it as that
object's failure and scores the others.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from shapebench.api.errors import describe
from shapebench.api.types import Completion
from shapebench.exchange.pcd import read_pcd


class CompletionFileError(ValueError):
    """A completion file that cannot be scored; the message names it and why."""


def read_completion(path: Path, n_points: int, seed: int, shown: str = "") -> Completion:
    """The completion in ``path`` (``shown``: how messages name it)."""
    shown = shown or str(path)
    suffix = path.suffix.lower()
    try:
        if suffix == ".npy":
            with open(path, "rb") as f:
                if f.read(6) != b"\x93NUMPY":  # numpy would say "pickled data" of any garbage
                    raise CompletionFileError(f"{shown} is not a .npy file (no NUMPY header)")
            return Completion(points=_cloud(np.load(path, allow_pickle=False), shown))
        if suffix == ".xyz":
            return Completion(points=_cloud(np.loadtxt(path, ndmin=2, comments="#"), shown))
        if suffix == ".pcd":
            return Completion(points=_cloud(read_pcd(path), shown))
        loaded = _trimesh_load(path)
    except CompletionFileError:
        raise
    except Exception as exc:  # numpy's and trimesh's readers raise many kinds on garbage
        raise CompletionFileError(f"{shown} cannot be read: {describe(exc)}") from exc
    return _from_trimesh(loaded, n_points, seed, shown)


def _trimesh_load(path: Path) -> Any:
    import trimesh

    return trimesh.load(path, process=False)


def _from_trimesh(loaded: Any, n_points: int, seed: int, shown: str) -> Completion:
    import trimesh

    if isinstance(loaded, trimesh.Scene):
        parts = list(loaded.dump())
        meshes = [p for p in parts if isinstance(p, trimesh.Trimesh)]
        if meshes:
            loaded = trimesh.util.concatenate(meshes)
        elif parts:
            loaded = trimesh.PointCloud(np.concatenate([np.asarray(p.vertices) for p in parts]))
        else:
            raise CompletionFileError(f"{shown} holds no points")
    if isinstance(loaded, trimesh.Trimesh) and len(loaded.faces):
        vertices = np.asarray(loaded.vertices)
        if not len(vertices):
            raise CompletionFileError(f"{shown} holds a mesh without vertices")
        if not np.all(np.isfinite(vertices)):
            bad = int((~np.isfinite(vertices)).any(axis=1).sum())
            raise CompletionFileError(f"{shown} has {bad} NaN/inf vertices")
        from shapebench.geometry.meshing import sample_mesh_points

        try:
            points = sample_mesh_points(loaded, n_points, seed)
        except ValueError as exc:  # zero surface area
            raise CompletionFileError(f"{shown}: {exc}") from exc
        return Completion(points=_cloud(points, shown), mesh=loaded)
    vertices = getattr(loaded, "vertices", None)
    if vertices is None:
        raise CompletionFileError(f"{shown} holds a {type(loaded).__name__}, not points or a mesh")
    return Completion(points=_cloud(np.asarray(vertices), shown))


def _cloud(array: Any, shown: str) -> np.ndarray:
    """``array`` as float32 ``(n, 3)`` points (the first three columns of ``(n, >=3)``: normals
    or colours beside them are ignored), or the reason it is none."""
    points = np.asarray(array)
    if not np.issubdtype(points.dtype, np.number) or points.dtype == np.bool_:
        raise CompletionFileError(f"{shown} holds a {points.dtype} array, not coordinates")
    if points.ndim != 2 or points.shape[1] < 3:
        raise CompletionFileError(f"{shown} holds an array of shape {points.shape}, not (n, 3)")
    points = points[:, :3].astype(np.float32)
    if not len(points):
        raise CompletionFileError(f"{shown} holds no points")
    finite = np.isfinite(points).all(axis=1)
    if not finite.all():
        raise CompletionFileError(
            f"{shown} has {int((~finite).sum())} NaN/inf points of {len(points)}"
        )
    return points
