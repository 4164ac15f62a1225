"""The paper's preprocessing: normalisation, visible (disemboweled) points, ground truth."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from shapebench.geometry.sampling import sample_surface
from shapebench.preprocess import PreprocessParams, prepare_ground_truth, prepare_mesh, visibility
from shapebench.preprocess.normalize import normalize
from shapebench.preprocess.visibility import fibonacci_viewpoints, visible_points


def test_normalise_puts_centre_of_mass_at_origin_and_max_vertex_distance_to_one():
    mesh = trimesh.creation.box((3.0, 1.0, 2.0))
    mesh.apply_translation((10.0, -4.0, 2.5))
    unit, center, scale = normalize(mesh)
    assert np.allclose(center, (10.0, -4.0, 2.5))
    assert np.isclose(np.linalg.norm(unit.vertices, axis=1).max(), 1.0)
    assert np.allclose(unit.center_mass, 0.0, atol=1e-9)
    assert np.isclose(scale, np.linalg.norm((1.5, 0.5, 1.0)))


def test_area_weighted_sampling_is_uniform_over_the_surface():
    # A 1x1x10 box: the four long sides hold 40 of its 42 area units.
    box = trimesh.creation.box((1.0, 1.0, 10.0))
    pts, _ = sample_surface(box.vertices, box.faces, 42_000, np.random.default_rng(0))
    on_caps = np.isclose(np.abs(pts[:, 2]), 5.0).mean()
    assert abs(on_caps - 2 / 42) < 0.005


def test_points_inside_a_closed_shell_are_never_visible():
    # A small sphere hidden inside a closed box: a sensor outside sees only the box.
    outer = trimesh.creation.box((1.4, 1.4, 1.4))
    inner = trimesh.creation.icosphere(subdivisions=3, radius=0.3)
    scene = trimesh.util.concatenate([outer, inner])
    scene.apply_scale(1 / np.linalg.norm(scene.vertices, axis=1).max())
    pts, normals = visible_points(scene, 20_000, 100, np.random.default_rng(1))
    radius = np.linalg.norm(pts, axis=1)
    inner_radius = 0.3 / np.linalg.norm((0.7, 0.7, 0.7))
    assert len(pts) > 10_000
    assert (radius < inner_radius + 1e-6).sum() == 0


def test_visible_normals_point_outwards_even_with_flipped_faces():
    sphere = trimesh.creation.icosphere(subdivisions=3)
    flipped = trimesh.Trimesh(sphere.vertices, sphere.faces[:, ::-1], process=False)
    for mesh in (sphere, flipped):
        pts, nrm = visible_points(mesh, 5000, 100, np.random.default_rng(2))
        assert len(pts) == 5000  # a convex object is visible everywhere
        assert (np.einsum("ij,ij->i", pts, nrm) > 0).all()


def test_the_inside_of_an_open_cup_is_visible_and_viewpoints_surround_the_object():
    outer = trimesh.creation.box((1.0, 1.0, 1.0))
    hole = trimesh.creation.box((0.8, 0.8, 1.0))
    hole.apply_translation((0, 0, 0.2))  # open at the top, 0.1 thick bottom
    cup = trimesh.boolean.difference([outer, hole], engine="manifold")
    unit, _, _ = normalize(cup)
    pts, _ = visible_points(unit, 20_000, 100, np.random.default_rng(3))
    inner = unit.vertices[:, :2].max() * 0.8 * 0.95  # well inside the inner walls
    inside = (np.abs(pts[:, 0]) < inner) & (np.abs(pts[:, 1]) < inner)
    levels = np.unique(np.round(unit.vertices[:, 2], 9))  # base, inner floor, rim
    assert len(levels) == 3
    on_floor = np.isclose(pts[inside][:, 2], levels[1], atol=1e-6)
    assert on_floor.sum() > 300  # the inner floor is seen from above, through the opening
    wall_x = np.unique(np.round(np.abs(unit.vertices[:, 0]), 9))[0]  # inner wall, not outer
    inner_wall = np.isclose(np.abs(pts[:, 0]), wall_x, atol=1e-6) & (pts[:, 2] > levels[1])
    assert inner_wall.sum() > 100  # and so are the inner walls

    views = fibonacci_viewpoints(100, 3.0)
    assert np.allclose(np.linalg.norm(views, axis=1), 3.0)
    assert np.abs(views.mean(axis=0)).max() < 0.05  # spread evenly around the object


def test_ray_casting_without_embree_warns_once_naming_the_fix(monkeypatch):
    # A lent GPU machine without embreex spent its whole time box preparing 101 of ~20k files.
    monkeypatch.setattr(trimesh.ray, "has_embree", False)
    visibility._warn_without_embree.cache_clear()
    sphere = trimesh.creation.icosphere(subdivisions=1)
    with pytest.warns(visibility.SlowRayCastingWarning, match="pip install embreex") as seen:
        visible_points(sphere, 50, 4, np.random.default_rng(0))
        visible_points(sphere, 50, 4, np.random.default_rng(0))
    assert len(seen) == 1
    visibility._warn_without_embree.cache_clear()


def test_prepare_mesh_sizes_and_determinism():
    mesh = trimesh.creation.capsule(height=1.0, radius=0.4)
    params = PreprocessParams(surface_candidates=4000, gt_points=3000, viewpoints=50)
    a = prepare_mesh(mesh, params, np.random.default_rng(7))
    b = prepare_mesh(mesh, params, np.random.default_rng(7))
    assert a["gt_points"].shape == (3000, 3) and a["gt_points"].dtype == np.float32
    assert a["surface_points"].shape == a["surface_normals"].shape
    assert 0 < len(a["surface_points"]) <= 4000
    for k in a:
        np.testing.assert_array_equal(a[k], b[k])
    assert np.linalg.norm(a["gt_points"], axis=1).max() <= 1.0 + 1e-5


def test_the_ground_truth_alone_equals_prepare_meshs_for_the_same_generator():
    mesh = trimesh.creation.capsule(height=1.0, radius=0.4)
    params = PreprocessParams(surface_candidates=4000, gt_points=3000, viewpoints=50)
    whole = prepare_mesh(mesh, params, np.random.default_rng(7))
    alone = prepare_ground_truth(mesh, params, np.random.default_rng(7))
    assert alone.dtype == np.float32
    np.testing.assert_array_equal(alone, whole["gt_points"])


def test_sdf_samples_match_a_sphere_with_and_without_a_closed_mesh():
    from shapebench.preprocess.samples import sdf_samples

    sphere = trimesh.creation.icosphere(subdivisions=4, radius=0.8)
    holed = trimesh.Trimesh(sphere.vertices, sphere.faces[:-3], process=False)
    for mesh, expected_kept in ((sphere, 1.0), (holed, 0.98)):
        s = sdf_samples(mesh, 20_000, np.random.default_rng(0))
        assert len(s) >= expected_kept * 20_000
        truth = np.linalg.norm(s[:, :3], axis=1) - 0.8
        near = np.abs(truth) < 0.05
        # Facets of the icosphere deviate from the true sphere by < 0.004.
        assert np.abs(s[near, 3] - truth[near]).max() < 0.006
        clear = np.abs(truth) > 0.005  # beyond the facets' deviation the sign is unambiguous
        assert (np.sign(s[clear, 3]) == np.sign(truth[clear])).mean() > 0.999
