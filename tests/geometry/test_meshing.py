"""Marching cubes with multiresolution refinement, checked on analytic implicit surfaces.

Analytic SDFs have known surfaces, so every claim of ``shapebench.geometry.meshing`` is checked
against geometry rather than against another implementation: vertex positions and volume of a
sphere, axis order and world coordinates on an off-centre box, outward winding, agreement of the
refined and dense meshes at a fraction of the evaluations, and thin parts that a sign-change-only
coarse pass would lose.
"""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from shapebench.geometry.meshing import (
    ExtractionStats,
    MeshingError,
    NoSurfaceError,
    extract_mesh,
    sample_mesh_points,
)
from shapebench.geometry.nearest import nearest_distances

BOUND = 1.05


def voxel(resolution: int) -> float:
    return 2 * BOUND / resolution


def sphere(radius: float = 0.5, center=(0.0, 0.0, 0.0)):
    c = np.asarray(center, dtype=np.float32)
    return lambda p: np.linalg.norm(p - c, axis=1) - radius


BOX_CENTER = np.array([0.1, -0.2, 0.05])
BOX_HALF = np.array([0.5, 0.3, 0.2])  # different extents: a swapped axis would show


def box_sdf(p: np.ndarray) -> np.ndarray:
    q = np.abs(p - BOX_CENTER) - BOX_HALF
    outside = np.linalg.norm(np.maximum(q, 0.0), axis=1)
    return outside + np.minimum(q.max(axis=1), 0.0)


def bumpy(p: np.ndarray) -> np.ndarray:
    """A sphere with bumps: not an exact distance (Lipschitz ~1.4), like a learned SDF."""
    bumps = 0.05 * np.sin(5 * p[:, 0]) * np.sin(5 * p[:, 1]) * np.sin(5 * p[:, 2])
    return np.linalg.norm(p, axis=1) - 0.5 - bumps


def torus(p: np.ndarray, major: float = 0.5, minor: float = 0.025) -> np.ndarray:
    q = np.stack([np.linalg.norm(p[:, :2], axis=1) - major, p[:, 2]], axis=1)
    return np.linalg.norm(q, axis=1) - minor


def assert_outward(mesh: trimesh.Trimesh, center=(0.0, 0.0, 0.0)) -> None:
    """Every face normal of a star-shaped closed mesh points away from its centre."""
    radial = mesh.triangles_center - np.asarray(center)
    assert (np.einsum("ij,ij->i", mesh.face_normals, radial) > 0).all()
    assert mesh.volume > 0


def test_sphere_vertices_volume_and_normals():
    mesh, stats = extract_mesh(sphere(), resolution=64)
    radius = np.linalg.norm(mesh.vertices, axis=1)
    assert np.abs(radius - 0.5).max() < voxel(64)
    assert mesh.is_watertight and mesh.is_winding_consistent
    assert mesh.volume == pytest.approx(4 / 3 * np.pi * 0.5**3, rel=0.02)
    assert_outward(mesh)
    assert isinstance(stats, ExtractionStats) and stats.resolution == 64
    assert stats.levels == [32, 64] and stats.evaluations == sum(stats.evaluations_per_level)


def test_world_coordinates_of_an_offset_sphere():
    center = (0.3, -0.2, 0.1)
    mesh, _ = extract_mesh(sphere(0.4, center), resolution=64, coarse=16)
    radius = np.linalg.norm(mesh.vertices - center, axis=1)
    assert np.abs(radius - 0.4).max() < voxel(64)
    assert_outward(mesh, center)


def test_box_matches_exact_surface_points():
    resolution = 64
    mesh, _ = extract_mesh(box_sdf, resolution=resolution)
    exact = trimesh.creation.box(extents=2 * BOX_HALF)
    exact.apply_translation(BOX_CENTER)
    ours = sample_mesh_points(mesh, 20_000, seed=0)
    truth = sample_mesh_points(exact, 20_000, seed=1)
    to_truth, to_ours = nearest_distances(ours, truth), nearest_distances(truth, ours)
    assert to_truth.mean() + to_ours.mean() < voxel(resolution)
    assert np.abs(box_sdf(mesh.vertices)).max() < voxel(resolution)
    assert mesh.is_watertight
    assert mesh.volume == pytest.approx(np.prod(2 * BOX_HALF), rel=0.05)


def test_multires_needs_few_evaluations_and_matches_dense():
    resolution = 128
    fine, fine_stats = extract_mesh(bumpy, resolution=resolution)
    ref, ref_stats = extract_mesh(bumpy, resolution=resolution, dense=True)
    assert ref_stats.evaluations == (resolution + 1) ** 3
    assert fine_stats.evaluations < 0.25 * ref_stats.evaluations
    assert fine_stats.levels == [32, 64, 128]
    # Vertex to surface, both ways: every vertex is a crossing on a grid edge of the other mesh.
    h = voxel(resolution)
    assert nearest_distances(fine.vertices, sample_mesh_points(ref, 200_000, seed=0)).max() < h
    assert nearest_distances(ref.vertices, sample_mesh_points(fine, 200_000, seed=0)).max() < h
    assert fine.is_watertight and fine.volume == pytest.approx(ref.volume, rel=1e-3)


def test_field_is_called_in_float32_batches_inside_the_box():
    seen: list[tuple[tuple[int, ...], np.dtype, float]] = []

    def field(p: np.ndarray) -> np.ndarray:
        seen.append((p.shape, p.dtype, float(np.abs(p).max())))
        return np.linalg.norm(p, axis=1) - 0.5

    _, stats = extract_mesh(field, resolution=64, batch_size=1000)
    assert all(len(s) == 2 and s[1] == 3 and 0 < s[0] <= 1000 for s, _, _ in seen)
    assert all(dtype == np.float32 for _, dtype, _ in seen)
    assert max(m for _, _, m in seen) <= BOUND + 1e-6
    assert sum(s[0] for s, _, _ in seen) == stats.evaluations


@pytest.mark.parametrize("dense", [False, True])
@pytest.mark.parametrize("offset", [0.3, 0.01])  # far from the level, and within the band
def test_no_surface_raises(dense, offset):
    with pytest.raises(NoSurfaceError, match="no crossing"):
        extract_mesh(lambda p: np.abs(p[:, 0]) * 0 + offset, resolution=64, dense=dense)


@pytest.mark.parametrize("bad", [np.nan, np.inf])
def test_non_finite_values_raise(bad):
    def field(p: np.ndarray) -> np.ndarray:
        d = np.linalg.norm(p, axis=1) - 0.5
        d[p[:, 0] > 0.9] = bad
        return d

    with pytest.raises(MeshingError, match=r"\d+ non-finite values"):
        extract_mesh(field, resolution=64)


def test_too_many_faces_raise():
    with pytest.raises(MeshingError, match="max_faces"):
        extract_mesh(sphere(), resolution=64, max_faces=100)


def test_bad_grid_arguments_raise():
    with pytest.raises(ValueError, match="power of two"):
        extract_mesh(sphere(), resolution=96, coarse=32)
    with pytest.raises(ValueError, match="divisor"):
        extract_mesh(sphere(), resolution=64, coarse=48)


@pytest.mark.parametrize("sharp", [True, False])
def test_occupancy_field_gives_the_sphere(sharp):
    """OccNet convention: larger is inside, surface at the threshold tau (0.5 here)."""

    def occupancy(p: np.ndarray) -> np.ndarray:
        d = np.linalg.norm(p, axis=1) - 0.5
        return (d < 0).astype(np.float32) if sharp else 1 / (1 + np.exp(d / 0.02))

    mesh, _ = extract_mesh(occupancy, resolution=64, level=0.5, inside_is_negative=False)
    assert np.abs(np.linalg.norm(mesh.vertices, axis=1) - 0.5).max() < voxel(64)
    assert mesh.volume == pytest.approx(4 / 3 * np.pi * 0.5**3, rel=0.05)
    assert mesh.is_watertight
    assert_outward(mesh)


def test_small_part_survives_the_coarse_pass_thanks_to_the_band():
    """A sphere smaller than half a coarse cell, centred in a coarse cell: no coarse corner is
    inside it, so refining on sign changes only (safety=0) loses it; the band keeps it."""
    coarse_cell = 2 * BOUND / 32
    center = np.full(3, -BOUND + 20.5 * coarse_cell)
    big, small = sphere(0.3, (-0.3, -0.3, -0.3)), sphere(0.025, center)

    def two_spheres(p: np.ndarray) -> np.ndarray:
        return np.minimum(big(p), small(p))

    kept, _ = extract_mesh(two_spheres, resolution=128)
    lost, _ = extract_mesh(two_spheres, resolution=128, safety=0.0)
    assert len(kept.split(only_watertight=True)) == 2
    assert len(lost.split(only_watertight=True)) == 1
    near_small = np.linalg.norm(kept.vertices - center, axis=1) < 0.1
    assert np.abs(np.linalg.norm(kept.vertices[near_small] - center, axis=1) - 0.025).max() < 0.01


def test_thin_torus_matches_dense():
    """A tube thinner than a coarse cell (0.05 vs 0.066) comes out whole."""
    mesh, stats = extract_mesh(torus, resolution=128)
    ref, _ = extract_mesh(torus, resolution=128, dense=True)
    assert len(mesh.faces) == len(ref.faces)
    assert mesh.volume == pytest.approx(ref.volume, rel=1e-6)
    assert mesh.is_watertight and mesh.volume > 0
    assert stats.evaluations < 0.1 * (128 + 1) ** 3


def test_sample_mesh_points_is_seeded_and_on_the_surface():
    mesh, _ = extract_mesh(sphere(), resolution=32, coarse=16)
    a, b = sample_mesh_points(mesh, 5000, seed=3), sample_mesh_points(mesh, 5000, seed=3)
    assert a.dtype == np.float32 and a.shape == (5000, 3)
    np.testing.assert_array_equal(a, b)
    assert not np.array_equal(a, sample_mesh_points(mesh, 5000, seed=4))
    assert np.abs(np.linalg.norm(a, axis=1) - 0.5).max() < voxel(32)


def test_a_decoder_meshes_to_the_same_mesh_whatever_the_points_per_call():
    """The default points per call on a CPU (4,096) is a speed choice: an MLP decoder evaluates
    each point alone, so its values, and the mesh, are those of 65,536-point calls bit for bit."""
    torch = pytest.importorskip("torch")
    from shapebench.geometry.meshing import CPU_BATCH, GPU_BATCH, default_batch_size
    from shapebench.implicit.networks import IGRDecoder

    torch.manual_seed(0)
    decoder = IGRDecoder(64, 128, 4, radius_init=0.5).eval()
    z = torch.randn(1, 64) * 0.01

    @torch.no_grad()
    def field(p: np.ndarray) -> np.ndarray:
        return decoder.forward_shared(z, torch.from_numpy(p)[None])[0].numpy()

    if not torch.cuda.is_initialized():  # a CPU process: the small calls are the default
        assert default_batch_size() == CPU_BATCH
    small, small_stats = extract_mesh(field, resolution=64, batch_size=CPU_BATCH)
    large, large_stats = extract_mesh(field, resolution=64, batch_size=GPU_BATCH)
    assert small_stats.evaluations == large_stats.evaluations > CPU_BATCH
    np.testing.assert_array_equal(small.vertices, large.vertices)
    np.testing.assert_array_equal(small.faces, large.faces)
