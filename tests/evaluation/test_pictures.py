"""Pictures of completions: fixed views, every panel drawn, the same objects for every method,
posterior spread as colour, and cheap enough to draw for every cell."""

from __future__ import annotations

import io

import numpy as np
import pytest
import trimesh
from matplotlib.collections import PathCollection
from matplotlib.image import imread

from shapebench.evaluation import pictures
from shapebench.evaluation.pictures import (
    VIEWS,
    is_blank,
    object_figure,
    picture_arrays,
    picture_objects,
    picture_png,
    png_bytes,
    project,
    qualitative_grid,
)


def _mug() -> np.ndarray:
    """Ground truth of a real shape: a cylinder with a handle, sampled on its surface."""
    body = trimesh.creation.cylinder(radius=0.5, height=1.0)
    body.apply_transform(trimesh.transformations.rotation_matrix(np.pi / 2, [1, 0, 0]))  # y-up
    handle = trimesh.creation.torus(0.3, 0.06)
    handle.apply_translation([0.6, 0, 0])
    mesh = trimesh.util.concatenate([body, handle])
    return np.asarray(mesh.sample(20000, seed=0), dtype=np.float32)


def _pixels(png: bytes) -> np.ndarray:
    return imread(io.BytesIO(png), format="png")


def _panel_pixels(fig, ax, png: bytes) -> np.ndarray:
    """The pixels of one axes of a figure rendered to ``png`` (same dpi)."""
    img = _pixels(png)
    box = ax.get_window_extent()
    h = img.shape[0]
    return img[int(h - box.y1) : int(h - box.y0), int(box.x0) : int(box.x1)]


def test_picture_objects_depend_on_the_object_list_only():
    ids = [f"cat{i}/obj" for i in range(10)]
    chosen = picture_objects(ids)
    assert chosen == ["cat0/obj", "cat4/obj", "cat9/obj"]  # spread over the list, ends included
    assert picture_objects(list(ids)) == chosen  # deterministic
    assert picture_objects(ids[:2]) == ids[:2]  # fewer objects than pictures
    assert picture_objects([]) == []


def test_projection_puts_the_front_towards_the_camera():
    # y-up, front towards +z: from the fixed three-quarter view the front is nearer than the
    # back, the top is above the bottom, and a point on the right (+x) is right of one on -x.
    pts = np.array([[0, 0, 1], [0, 0, -1], [0, 1, 0], [0, -1, 0], [1, 0, 0], [-1, 0, 0.0]])
    xy, depth = project(pts, *VIEWS[0])
    assert depth[0] > depth[1]
    assert xy[2, 1] > xy[3, 1]
    assert xy[4, 0] > xy[5, 0]
    # Orthographic and rigid: distances in the view plane never exceed those in space.
    assert np.allclose(np.linalg.norm(np.c_[xy, depth], axis=1), 1.0)


def test_object_picture_draws_context_completion_and_ground_truth_from_each_view():
    gt = _mug()
    ctx = gt[:100]
    completion = gt[::3] + np.random.default_rng(0).normal(0, 0.01, (len(gt[::3]), 3))
    fig = object_figure(ctx, completion, gt, title="mug")
    png = png_bytes(fig)
    assert not is_blank(png)
    assert len(fig.axes) == len(VIEWS) * 3
    titles = [ax.get_title() for ax in fig.axes[:3]]
    assert titles == ["context (100 pts)", "completion", "ground truth"]
    drawn = [
        sum(len(c.get_offsets()) for c in ax.collections if isinstance(c, PathCollection))
        for ax in fig.axes
    ]
    # Each panel holds its cloud (large ones subsampled to MAX_POINTS), in every view.
    assert drawn == [100, pictures.MAX_POINTS, pictures.MAX_POINTS] * len(VIEWS)
    for ax in fig.axes:  # nothing blank: every panel has more than one colour
        assert not is_blank_array(_panel_pixels(fig, ax, png))


def is_blank_array(pixels: np.ndarray) -> bool:
    flat = pixels.reshape(-1, pixels.shape[-1])
    return bool(np.all(flat == flat[0]))


def test_spread_panel_colours_the_completion_by_its_spread():
    gt = _mug()
    completion = gt[::5]  # fewer than MAX_POINTS: every point is drawn
    spread = np.abs(completion[:, 0])  # larger on the sides: a known pattern
    fig = object_figure(gt[:50], completion, gt, spread=spread)
    png = png_bytes(fig)
    assert [ax.get_title() for ax in fig.axes[:4]][-1] == "posterior spread"
    panel = fig.axes[3]
    scatter = next(c for c in panel.collections if isinstance(c, PathCollection))
    # The colours are the spread values (depth-sorted), on a colour bar from their range.
    assert sorted(scatter.get_array().tolist()) == pytest.approx(sorted(spread.tolist()))
    assert scatter.get_clim() == pytest.approx((spread.min(), spread.max()))
    colours = _panel_pixels(fig, panel, png)[..., :3].reshape(-1, 3)
    assert len(np.unique(np.round(colours, 2), axis=0)) > 20  # a colour map, not one colour


def test_picture_arrays_keep_what_the_grid_needs_at_bounded_size():
    gt = _mug()
    completion = np.repeat(gt, 2, axis=0)
    arrays = picture_arrays(gt[:300], completion, gt, spread=np.ones(len(completion)))
    assert arrays["context"].shape == (300, 3)
    assert len(arrays["completion"]) == len(arrays["spread"]) == pictures.MAX_POINTS
    assert len(arrays["ground_truth"]) == pictures.MAX_POINTS
    assert all(a.dtype == np.float32 for a in arrays.values())


def test_a_picture_with_a_spread_panel_is_drawn():
    """What it costs: benchmarks/bench_pictures.py (no timing is asserted here)."""
    gt = _mug()
    arrays = picture_arrays(gt[:1000], gt[::2], gt, spread=np.abs(gt[::2, 1]))
    png = picture_png(arrays, "with spread")
    assert not is_blank(png)
    assert (
        _pixels(png).shape[1]
        > _pixels(picture_png(picture_arrays(gt[:1000], gt[::2], gt))).shape[1]
    )


def test_qualitative_grid_is_methods_by_context_sizes():
    gt = _mug()
    rows, contexts = ["gauss", "msc"], [50, 100, 300]
    completions = {("gauss", 50): gt[::10], ("gauss", 100): gt[::4], ("msc", 300): gt[::3]}
    fig = qualitative_grid(rows, contexts, completions, {k: gt[:k] for k in contexts}, gt, "mug")
    png = png_bytes(fig)
    assert not is_blank(png)
    grid = np.array(fig.axes).reshape(len(rows) + 1, len(contexts) + 1)
    assert [ax.get_title() for ax in grid[0]] == [
        "50 points",
        "100 points",
        "300 points",
        "ground truth",
    ]
    assert [grid[r, 0].get_ylabel() for r in range(3)] == ["context", "gauss", "msc"]

    def points(ax) -> int:
        return sum(len(c.get_offsets()) for c in ax.collections if isinstance(c, PathCollection))

    assert [points(ax) for ax in grid[0, :3]] == contexts
    assert points(grid[1, 0]) == len(gt[::10]) and points(grid[2, 2]) == pictures.GRID_POINTS
    # A cell that was not run is an empty panel that says so.
    assert points(grid[2, 0]) == 0
    assert [t.get_text() for t in grid[2, 0].texts] == ["no completion"]
