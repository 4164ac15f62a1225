"""Marching-cubes meshes of implicit surfaces without evaluating the dense grid.

IGR, DeepSDF, MSC and OccNet complete a shape as an implicit function (a signed distance or an
occupancy) and need a triangle mesh of its level set. An 8x512 MLP evaluates about 30k points/s on
a 2-core CPU, so the dense 257^3 grid costs about 9 minutes per mesh while marching cubes on it
takes 0.2 s: the decoder is the whole cost. :func:`extract_mesh` therefore refines hierarchically,
like OccNet's MISE (``im2mesh/utils/libmise``): it evaluates a coarse grid, keeps only the cells
that can contain the surface, subdivides those, evaluates only the new points, and repeats until
the target resolution. The evaluations grow with the surface area (~resolution^2), not with the
volume (~resolution^3).

Grid convention: ``resolution`` is the number of **cells** per axis, so the grid has
``resolution + 1`` points per axis, at ``-bound + i * 2 * bound / resolution``; both box faces
are sampled and the voxel size is ``2 * bound / resolution``. With ``resolution + 1`` points the
grids of all levels nest exactly (every coarse point is a fine point), which is what lets the
refinement reuse values. ``resolution / coarse`` must be a power of two.

Which cells are refined: all values are first turned into ``g = value - level`` (inside-negative
fields) or ``g = level - value`` (occupancies, logits: larger is inside), so that inside is always
``g < 0``. A cell is kept when the range of ``g`` over its 8 corners meets
``[-band, band]`` with ``band = safety * cell diagonal``: either the corners change sign, or one of
them is close enough to the surface for a crossing inside the cell. For a field with Lipschitz
constant ``L`` a cell holds surface only if some corner has ``|g| <= L * diagonal / 2`` (no point
of a cube is farther than half its diagonal from every corner), so ``safety = 1.5`` is safe for
``L <= 3``: learned SDFs are only roughly distances. For occupancies and logits the band is in
value units and rarely matters; refinement then rests on sign changes, as in MISE, and features
thinner than a coarse cell can be missed (raise ``coarse``).

How unevaluated points are filled: level by level, the volume is upsampled by trilinear
interpolation and the evaluated values of the next level are written over it. A point that was
never evaluated lies in a cell that was not refined, whose 8 corners all have the same sign and are
at least ``band`` away from zero; trilinear interpolation is a convex combination of those corners,
so the filled value has the same sign and stays at least ``band`` away from zero. Marching cubes
therefore sees no crossing that the evaluated values do not imply, and needs no clamping.
(Evaluated points on the face of an unrefined cell, from a refined neighbour, have the same sign
too when the field is Lipschitz; when it is not, marching cubes still gets a complete volume and
the mesh stays closed.)

Output: a :class:`trimesh.Trimesh` in world coordinates with outward-facing faces (normals point
toward increasing ``g``, i.e. outside). It is watertight where the surface is closed inside the
box; a surface that leaves the box is cut open there.

Memory: the evaluated values and the filled volume are ``(resolution + 1)^3`` float32 arrays
(68 MB each at 256, 540 MB at 512); the bookkeeping around them is about 1 s at 256.

Points per field call (``batch_size``): by default :data:`CPU_BATCH` (4,096) unless CUDA is
initialised in the process, then :data:`GPU_BATCH` (65,536). A decoder evaluates each point alone,
so the values do not depend on it. On a CPU, 4,096 points keep a decoder's activations (4,096 x
width floats) in the caches, where 65,536 streamed them from memory: the standard rows' field
evaluations 1.3x to 1.7x faster (benchmarks/README.md, "Points per field call"). A GPU wants few,
large calls; its meshing is as it was.
"""

from __future__ import annotations

import math
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass
from dataclasses import field as dataclass_field

import numpy as np
import trimesh

from shapebench.geometry.sampling import sample_surface

Field = Callable[[np.ndarray], np.ndarray]

#: The 8 corners of a unit cell, as integer offsets.
_CORNERS = np.array([[i, j, k] for i in (0, 1) for j in (0, 1) for k in (0, 1)], dtype=np.int64)
#: The 3x3x3 points of a cell subdivided once, in units of the child spacing.
_SUBGRID = np.array(
    [[i, j, k] for i in (0, 1, 2) for j in (0, 1, 2) for k in (0, 1, 2)], dtype=np.int64
)


#: Points per field call on a CPU: a decoder's activations stay in the CPU's caches.
CPU_BATCH = 4096
#: Points per field call when CUDA is initialised in the process: few, large kernel launches.
GPU_BATCH = 65536


def default_batch_size() -> int:
    """:data:`GPU_BATCH` when CUDA is initialised in this process (a GPU decoder), else
    :data:`CPU_BATCH`. torch is not imported here: a process that has not imported it meshes a
    numpy field, on the CPU."""
    torch = sys.modules.get("torch")
    cuda = getattr(torch, "cuda", None) if torch is not None else None
    initialised = getattr(cuda, "is_initialized", None)
    return GPU_BATCH if callable(initialised) and initialised() else CPU_BATCH


class NoSurfaceError(ValueError):
    """The field has no crossing of ``level`` inside the box: there is nothing to mesh."""


class MeshingError(ValueError):
    """The field returned NaN/inf or malformed values, or the mesh has more than ``max_faces``."""


@dataclass
class ExtractionStats:
    """What one extraction cost; ``evaluations`` is the number the decoder's time scales with."""

    #: points passed to ``field`` in total
    evaluations: int
    #: cells per axis of the final grid
    resolution: int
    #: wall time of the whole extraction (evaluation, filling, marching cubes)
    seconds: float
    #: cells per axis of each level, coarse first (``[resolution]`` when dense)
    levels: list[int]
    #: points evaluated at each level, aligned with ``levels``
    evaluations_per_level: list[int] = dataclass_field(default_factory=list)
    #: cells kept for refinement at each level but the last, aligned with ``levels``
    active_cells: list[int] = dataclass_field(default_factory=list)


@dataclass(frozen=True)
class _Grid:
    """The final grid and how field values become ``g`` (inside negative, surface at 0)."""

    resolution: int
    bound: float
    level: float
    sign: float
    batch_size: int

    @property
    def points_per_axis(self) -> int:
        return self.resolution + 1

    @property
    def voxel(self) -> float:
        return 2.0 * self.bound / self.resolution


def extract_mesh(
    field: Field,
    resolution: int = 256,
    bound: float = 1.05,
    level: float = 0.0,
    inside_is_negative: bool = True,
    coarse: int = 32,
    batch_size: int | None = None,
    max_faces: int = 2_000_000,
    safety: float = 1.5,
    dense: bool = False,
) -> tuple[trimesh.Trimesh, ExtractionStats]:
    """Mesh the ``level`` set of ``field`` inside ``[-bound, bound]^3``.

    ``field`` maps an ``(n, 3)`` float32 array of points to ``n`` values and is called with at
    most ``batch_size`` points at a time (default: :func:`default_batch_size`; wrap a torch
    decoder in ``torch.no_grad`` outside this module). ``inside_is_negative=True`` for signed
    distances; ``False`` for occupancies or logits, where values above ``level`` (e.g. the
    threshold tau) are inside. ``resolution`` is the number of cells per axis (see the module
    docstring); ``coarse`` is that of the first level and must divide it by a power of two.
    ``safety`` scales the band, in cell diagonals, in which a cell is refined although its
    corners do not change sign (0: sign changes only). ``dense=True`` evaluates every grid point
    instead: the reference the refinement must match.

    Raises :class:`NoSurfaceError` when nothing crosses ``level`` and :class:`MeshingError` on
    non-finite values or a mesh with more than ``max_faces`` faces.
    """
    start = time.perf_counter()
    batch_size = default_batch_size() if batch_size is None else batch_size
    _check_arguments(resolution, bound, coarse, batch_size, safety, dense)
    grid = _Grid(
        resolution, float(bound), float(level), 1.0 if inside_is_negative else -1.0, int(batch_size)
    )
    if dense:
        volume = _evaluate_dense(field, grid)
        stats = ExtractionStats(volume.size, resolution, 0.0, [resolution], [volume.size], [])
    else:
        volume, stats = _evaluate_multires(field, grid, coarse, safety)
    mesh = _marching_cubes(volume, grid, max_faces)
    stats.seconds = time.perf_counter() - start
    return mesh, stats


def sample_mesh_points(mesh: trimesh.Trimesh, n: int, seed: int) -> np.ndarray:
    """``n`` float32 points drawn area-weighted on ``mesh``: how a completion is scored."""
    rng = np.random.default_rng(seed)
    points, _ = sample_surface(np.asarray(mesh.vertices), np.asarray(mesh.faces), n, rng)
    return points.astype(np.float32)


def _check_arguments(
    resolution: int, bound: float, coarse: int, batch_size: int, safety: float, dense: bool
) -> None:
    if resolution < 2:
        raise ValueError(f"resolution must be at least 2 cells per axis, got {resolution}")
    if not bound > 0:
        raise ValueError(f"bound must be positive, got {bound}")
    if batch_size < 1:
        raise ValueError(f"batch_size must be positive, got {batch_size}")
    if dense:
        return
    if coarse < 1 or resolution % coarse:
        raise ValueError(
            f"coarse ({coarse}) must be a positive divisor of resolution ({resolution})"
        )
    ratio = resolution // coarse
    if ratio & (ratio - 1):
        raise ValueError(f"resolution / coarse must be a power of two, got {resolution}/{coarse}")
    if not safety >= 0:
        raise ValueError(f"safety must be non-negative, got {safety}")


# --- evaluation ------------------------------------------------------------------------------


def _evaluate(field: Field, grid: _Grid, flat_index: np.ndarray) -> np.ndarray:
    """``g`` at the grid points with these flat indices, in batches of ``grid.batch_size``."""
    out = np.empty(len(flat_index), dtype=np.float32)
    for s in range(0, len(flat_index), grid.batch_size):
        out[s : s + grid.batch_size] = _evaluate_batch(
            field, grid, flat_index[s : s + grid.batch_size]
        )
    return out


def _evaluate_batch(field: Field, grid: _Grid, flat_index: np.ndarray) -> np.ndarray:
    n = grid.points_per_axis
    ijk = np.stack(np.unravel_index(flat_index, (n, n, n)), axis=1)
    points = (ijk * grid.voxel - grid.bound).astype(np.float32)
    values = np.asarray(field(points), dtype=np.float32).reshape(-1)
    if values.shape[0] != len(points):
        raise MeshingError(f"field returned {values.shape[0]} values for {len(points)} points")
    bad = ~np.isfinite(values)
    if bad.any():
        first = points[np.argmax(bad)]
        raise MeshingError(
            f"field returned {int(bad.sum())} non-finite values (NaN/inf) in a "
            f"batch of {len(points)} points, e.g. at {first.tolist()}"
        )
    return grid.sign * (values - grid.level)


def _evaluate_dense(field: Field, grid: _Grid) -> np.ndarray:
    """Every grid point: the reference, and the cost multires avoids."""
    n = grid.points_per_axis
    flat = np.empty(n**3, dtype=np.float32)
    for s in range(0, n**3, grid.batch_size):
        index = np.arange(s, min(s + grid.batch_size, n**3))
        flat[s : s + len(index)] = _evaluate_batch(field, grid, index)
    volume = flat.reshape(n, n, n)
    if not _crosses(volume):
        raise NoSurfaceError(_no_surface_message(volume, grid))
    return volume


# --- multiresolution -------------------------------------------------------------------------


def _evaluate_multires(
    field: Field, grid: _Grid, coarse: int, safety: float
) -> tuple[np.ndarray, ExtractionStats]:
    """Coarse grid, then only the subgrids of cells that can hold surface; then the fill."""
    n = grid.points_per_axis
    values = np.full((n, n, n), np.nan, dtype=np.float32)  # NaN: not evaluated
    n_levels = int(math.log2(grid.resolution // coarse)) + 1
    stride = grid.resolution // coarse
    coarse_index = np.indices((coarse + 1,) * 3).reshape(3, -1).T * stride
    per_level = [_store(field, grid, values, coarse_index)]
    cells = np.indices((coarse,) * 3).reshape(3, -1).T
    levels, active_counts = [coarse], []
    for _ in range(n_levels - 1):
        cells = cells[_may_hold_surface(values, cells, stride, safety, grid.voxel * stride)]
        active_counts.append(len(cells))
        if len(cells) == 0:
            break
        stride //= 2
        per_level.append(_store(field, grid, values, _subgrid_points(cells, stride)))
        cells = (cells[:, None, :] * 2 + _CORNERS[None]).reshape(-1, 3)
        levels.append(levels[-1] * 2)
    if active_counts and active_counts[0] == 0:
        step = grid.resolution // coarse
        raise NoSurfaceError(
            _no_surface_message(values[::step, ::step, ::step], grid)
            + f" (no cell of the {coarse}^3 coarse grid is near the level)"
        )
    volume = _fill(values, grid.resolution // coarse)
    if not _crosses(volume):
        raise NoSurfaceError(_no_surface_message(volume, grid))
    stats = ExtractionStats(sum(per_level), grid.resolution, 0.0, levels, per_level, active_counts)
    return volume, stats


def _store(field: Field, grid: _Grid, values: np.ndarray, ijk: np.ndarray) -> int:
    """Evaluate the points of ``ijk`` not evaluated yet into ``values``; return how many."""
    # A mask over the grid dedups the shared points faster than np.unique, and sorts them.
    wanted = np.zeros(values.size, dtype=bool)
    wanted[np.ravel_multi_index(ijk.T, values.shape)] = True
    flat = np.flatnonzero(wanted & np.isnan(values.reshape(-1)))
    values.reshape(-1)[flat] = _evaluate(field, grid, flat)
    return len(flat)


def _subgrid_points(cells: np.ndarray, child_stride: int) -> np.ndarray:
    """Fine-grid indices of the 3x3x3 points of each cell split in 8 (corners included)."""
    return (cells[:, None, :] * (2 * child_stride) + _SUBGRID[None] * child_stride).reshape(-1, 3)


def _may_hold_surface(
    values: np.ndarray, cells: np.ndarray, stride: int, safety: float, cell_size: float
) -> np.ndarray:
    """Cells whose corner range meets ``[-band, band]``: a sign change or a possible one."""
    band = safety * math.sqrt(3.0) * cell_size
    corners = (cells[:, None, :] + _CORNERS[None]) * stride
    g = values[corners[..., 0], corners[..., 1], corners[..., 2]]
    return (g.min(axis=1) <= band) & (g.max(axis=1) >= -band)


def _fill(values: np.ndarray, coarse_stride: int) -> np.ndarray:
    """The full volume: upsample level by level, keeping every evaluated value.

    A point never evaluated gets the trilinear interpolation of the unrefined cell that holds it,
    whose corners share one sign (see the module docstring), so it adds no crossing.
    """
    stride = coarse_stride
    volume = values[::stride, ::stride, ::stride].copy()
    while stride > 1:
        stride //= 2
        volume = _upsample(volume)
        known = values[::stride, ::stride, ::stride]
        np.copyto(volume, known, where=~np.isnan(known))
    return volume


def _upsample(a: np.ndarray) -> np.ndarray:
    """Trilinear upsampling of an ``(m+1)^3`` grid to ``(2m+1)^3``, one axis at a time."""
    m = a.shape[0] - 1
    out = np.empty((2 * m + 1,) * 3, dtype=a.dtype)
    out[::2, ::2, ::2] = a
    out[1::2, ::2, ::2] = 0.5 * (a[:-1] + a[1:])
    out[:, 1::2, ::2] = 0.5 * (out[:, :-2:2, ::2] + out[:, 2::2, ::2])
    out[:, :, 1::2] = 0.5 * (out[:, :, :-2:2] + out[:, :, 2::2])
    return out


# --- meshing ---------------------------------------------------------------------------------


def _crosses(volume: np.ndarray) -> bool:
    return bool((volume < 0).any() and (volume > 0).any())


def _no_surface_message(volume: np.ndarray, grid: _Grid) -> str:
    lo, hi = np.nanmin(volume), np.nanmax(volume)
    raw = sorted((grid.sign * lo + grid.level, grid.sign * hi + grid.level))
    return (
        f"no crossing of level {grid.level} in [-{grid.bound}, {grid.bound}]^3: field "
        f"values range over [{raw[0]:.4g}, {raw[1]:.4g}]"
    )


def _marching_cubes(volume: np.ndarray, grid: _Grid, max_faces: int) -> trimesh.Trimesh:
    """Lewiner marching cubes at ``g = 0``, in world coordinates, faces wound outward.

    skimage's default ``gradient_direction="descent"`` winds faces so that their normals point
    toward increasing values: outward, since ``g`` is negative inside (checked by the tests).
    """
    from skimage.measure import marching_cubes

    h = grid.voxel
    verts, faces, _, _ = marching_cubes(volume, level=0.0, spacing=(h, h, h), method="lewiner")
    if len(faces) > max_faces:
        raise MeshingError(f"mesh has {len(faces)} faces, more than max_faces={max_faces}")
    # Merging joins the copies of a vertex that marching cubes emits when a grid value is exactly
    # zero; the triangles this collapses are dropped, so such meshes stay watertight.
    mesh = trimesh.Trimesh(verts.astype(np.float64) - grid.bound, faces, process=True)
    f = mesh.faces
    keep = (f[:, 0] != f[:, 1]) & (f[:, 1] != f[:, 2]) & (f[:, 0] != f[:, 2])
    if not keep.all():
        mesh.update_faces(keep)
        mesh.remove_unreferenced_vertices()
    return mesh
