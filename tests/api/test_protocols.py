"""Context protocols (issue 29 §2): ShapeNet-55's crop and Gaussian context noise. The pieces
by hand (the crop, farthest-point sampling, the noise), the contexts they make (nested, seeded,
stored, the same for every method), the keys of the paper's protocol unchanged, and runs and
tables of their own from the command line."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import TINY

from shapebench.api.contexts import (
    CROP_VIEWPOINTS,
    DEPTH_VIEWPOINTS,
    ContextStore,
    crop_keep,
    crop_viewpoint,
    depth_viewpoint,
    farthest_point_order,
)
from shapebench.api.errors import ConfigError
from shapebench.api.protocol import Protocol
from shapebench.api.types import ObjectData, ObjectRef
from shapebench.geometry.hidden_points import visible_from


def _data(n: int = 4000, object_id: str = "cat/obj-1") -> ObjectData:
    rng = np.random.default_rng(0)
    surface = rng.normal(size=(1000, 3)).astype(np.float32)
    gt = rng.normal(size=(n, 3))
    gt = (gt / np.linalg.norm(gt, axis=1, keepdims=True)).astype(np.float32)  # a unit sphere
    return ObjectData(ObjectRef(object_id, "cat"), surface, surface, gt)


# -- the pieces, by hand -------------------------------------------------------------------------


def test_the_crop_removes_the_fraction_nearest_the_viewpoint() -> None:
    # Ten points on the x axis at 0..9, the viewpoint at x = 10: the 0.3 nearest are 9, 8, 7.
    points = np.stack([np.arange(10.0), np.zeros(10), np.zeros(10)], axis=1)
    kept = crop_keep(points, np.array([10.0, 0, 0]), 0.3)
    assert sorted(kept.tolist()) == list(range(7))
    assert kept[0] == 6  # nearest kept point first
    assert len(CROP_VIEWPOINTS) == 8
    assert np.allclose(np.linalg.norm(CROP_VIEWPOINTS, axis=1), 1.0)
    assert np.allclose(np.abs(CROP_VIEWPOINTS), 1 / np.sqrt(3))  # the cube's corners


def test_farthest_point_order_by_hand_and_nested() -> None:
    # A unit square's corners and its centre, from the corner (0, 0): the opposite corner
    # (squared distance 2), then the other corners (1 from both; a tie goes to the lower
    # index), the centre last (0.5 from every corner).
    points = np.array([[0.5, 0.5, 0], [0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0]])
    assert farthest_point_order(points, 5, start=1).tolist() == [1, 4, 2, 3, 0]
    cloud = np.random.default_rng(1).normal(size=(500, 3))
    long, short = farthest_point_order(cloud, 200, 7), farthest_point_order(cloud, 50, 7)
    np.testing.assert_array_equal(long[:50], short)  # the first 50 are the 50-point sample
    assert len(set(long.tolist())) == 200


def test_crop_contexts_are_nested_seeded_stored_and_cropped(tmp_path) -> None:
    data = _data()
    protocol = Protocol(context="crop", crop_fraction=0.5)
    store = ContextStore(tmp_path, "fingerprint-a")
    c64, c512 = (store.context(data, k, 0, protocol=protocol) for k in (64, 512))
    np.testing.assert_array_equal(c512.points[:64], c64.points)
    assert c512.normals is None
    # Every point lies on the far half from the object's viewpoint: the nearer half is gone.
    view = CROP_VIEWPOINTS[crop_viewpoint("fingerprint-a", data.ref.id)]
    distance = np.linalg.norm(data.gt_points - view, axis=1)
    cut = np.sort(distance)[len(distance) // 2]
    assert (np.linalg.norm(c512.points - view, axis=1) >= cut - 1e-6).all()
    # Stored, and read back by another store (another process, another method).
    assert list((tmp_path / "contexts-v1" / "crop-0.5").glob("*.npy"))
    again = ContextStore(tmp_path, "fingerprint-a").context(data, 512, 0, protocol=protocol)
    np.testing.assert_array_equal(again.points, c512.points)
    # A larger size later extends the stored order and keeps its start.
    c1024 = store.context(data, 1024, 0, protocol=protocol)
    np.testing.assert_array_equal(c1024.points[:512], c512.points)
    with pytest.raises(ValueError, match="exceeds the 2000 points left of 4000"):
        store.context(data, 2001, 0, protocol=protocol)


def test_a_camera_sees_the_near_cap_of_a_sphere() -> None:
    # From distance 3, a unit sphere's visible cap is where z > 1/3: a third of its area.
    rng = np.random.default_rng(0)
    sphere = rng.normal(size=(20000, 3))
    sphere /= np.linalg.norm(sphere, axis=1, keepdims=True)
    seen = visible_from(sphere, np.array([0.0, 0.0, 3.0]))
    assert abs(len(seen) / len(sphere) - 1 / 3) < 0.02
    assert sphere[seen, 2].min() > 0.25  # nothing from the far side
    hidden = np.setdiff1d(np.arange(len(sphere)), seen)
    assert sphere[hidden, 2].max() < 0.4


def test_a_point_behind_a_wall_is_hidden() -> None:
    # A dense wall at z = 1 between the camera (z = 3) and a point at the origin hides it; the
    # same point beside the wall is seen.
    g = np.linspace(-1, 1, 41)
    wall = np.stack(np.meshgrid(g, g), axis=-1).reshape(-1, 2)
    wall = np.concatenate([wall, np.ones((len(wall), 1))], axis=1)
    points = np.concatenate([wall, [[0.0, 0.0, 0.0], [3.0, 0.0, 0.0]]])
    seen = set(visible_from(points, np.array([0.0, 0.0, 3.0])).tolist())
    assert len(wall) not in seen and len(wall) + 1 in seen


def test_depth_contexts_are_one_seeded_view_nested_and_stored(tmp_path) -> None:
    data = _data()
    protocol = Protocol(context="depth")
    store = ContextStore(tmp_path, "fingerprint-a")
    c64, c512 = (store.context(data, k, 0, protocol=protocol) for k in (64, 512))
    np.testing.assert_array_equal(c512.points[:64], c64.points)
    view = DEPTH_VIEWPOINTS[depth_viewpoint("fingerprint-a", data.ref.id)]
    # The camera's side of the sphere: its cap (cos > 1/3 from the centre), give or take the
    # silhouette, where hidden point removal on 4,000 points is approximate.
    cos = c512.points @ view / np.linalg.norm(view)
    assert cos.min() > 0.1 and np.mean(cos > 1 / 3) > 0.9
    assert list((tmp_path / "contexts-v1" / "depth").glob("*.npy"))
    again = ContextStore(tmp_path, "fingerprint-a").context(data, 512, 0, protocol=protocol)
    np.testing.assert_array_equal(again.points, c512.points)
    with pytest.raises(ValueError, match="visible from the depth camera"):
        store.context(data, 3000, 0, protocol=protocol)
    assert len(DEPTH_VIEWPOINTS) == 16
    assert len({depth_viewpoint("fp", f"cat/obj-{i}") for i in range(60)}) >= 10


def test_the_viewpoint_varies_over_objects() -> None:
    views = {crop_viewpoint("fp", f"cat/obj-{i}") for i in range(40)}
    assert len(views) >= 6


def test_noise_is_seeded_per_point_and_the_same_at_every_size(tmp_path) -> None:
    data = _data()
    store = ContextStore(tmp_path, "fp")
    clean = store.context(data, 500, 0)
    noisy = store.context(data, 500, 0, protocol=Protocol(context_noise=0.02))
    small = store.context(data, 100, 0, protocol=Protocol(context_noise=0.02))
    np.testing.assert_array_equal(small.points, noisy.points[:100])
    delta = (noisy.points - clean.points).astype(np.float64)
    assert abs(delta.std() - 0.02) < 0.002 and abs(delta.mean()) < 0.002
    # Another run seed (another method's draw) keeps the noise: it belongs to the object.
    other = store.context(data, 500, 3, protocol=Protocol(context_noise=0.02))
    np.testing.assert_array_equal(other.points, noisy.points)


# -- the protocol itself ---------------------------------------------------------------------


def test_the_papers_protocol_keeps_its_keys() -> None:
    # The config the cell keys hash: exactly 0.1's for the sparse protocol without noise.
    assert Protocol().config() == {
        "version": "2",
        "context_normals": False,
        "frame": "unit-radius",
    }
    crop = Protocol(context="crop", crop_fraction=0.25, context_noise=0.005)
    assert crop.config()["context"] == "crop" and crop.name == "crop-0.25+noise-0.005"
    assert not crop.is_default_context and Protocol().name == "sparse"


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"context": "crop"}, "needs a crop fraction in \\(0, 1\\)"),
        ({"crop_fraction": 0.5}, "needs --protocol crop"),
        ({"context_noise": -0.1}, "must be a standard deviation >= 0"),
        ({"context": "crop", "crop_fraction": 0.5, "context_normals": True}, "has no normals"),
        ({"context": "scan"}, "unknown context protocol 'scan'"),
        ({"context": "depth", "context_normals": True}, "depth contexts .* no normals"),
        ({"context": "depth", "crop_fraction": 0.5}, "needs --protocol crop"),
    ],
)
def test_a_bad_protocol_is_one_clear_error(kwargs, message) -> None:
    with pytest.raises(ConfigError, match=message):
        Protocol(**kwargs)


# -- from the command line -----------------------------------------------------------------------


@pytest.mark.slow  # runs the CLI
def test_crop_and_noise_runs_are_rows_and_tables_of_their_own(shapebench, tmp_path) -> None:
    base = ("run", "-m", "gauss", "-d", "synthetic", "--split", "trained", *TINY, "-q")
    assert shapebench(*base, "--contexts", "50").returncode == 0
    res = shapebench(*base, "--contexts", "50,512", "--protocol", "crop", "--crop-fraction", "0.5")
    assert res.returncode == 0, res.stderr
    assert "gauss[crop=0.5] on synthetic/trained" in res.stdout
    res = shapebench(*base, "--contexts", "50", "--context-noise", "0.005")
    assert res.returncode == 0, res.stderr
    assert "gauss[noise=0.005]" in res.stdout
    # TINY samples 2,000 ground-truth points: a crop of 0.5 leaves 1,000, said before any cell.
    res = shapebench(*base, "--contexts", "1024", "--protocol", "crop", "--crop-fraction", "0.5")
    assert res.returncode == 2 and "larger than the 1000 ground-truth points a crop" in res.stderr
    res = shapebench(*base, "--contexts", "50", "--protocol", "depth")
    assert res.returncode == 0, res.stderr
    assert "gauss[protocol=depth] on synthetic/trained" in res.stdout
    res = shapebench(*base, "--contexts", "1900", "--protocol", "depth")
    assert res.returncode == 2 and "ground-truth points object" in res.stderr
    assert "shows its depth camera" in res.stderr
    # Nothing recomputed by asking again: the keys are stable.
    res = shapebench(*base, "--contexts", "50,512", "--protocol", "crop", "--crop-fraction", "0.5")
    assert res.stdout.count("cached") == 2, res.stdout

    out = tmp_path / "boards"
    res = shapebench("leaderboard", "-d", "synthetic", "--out", str(out), "--reference", "gauss")
    assert res.returncode == 0, res.stdout + res.stderr
    names = sorted(p.name for p in out.glob("*.md"))
    assert names == [
        "synthetic-trained-crop-0_5.md",
        "synthetic-trained-depth.md",
        "synthetic-trained-sparse+noise-0_005.md",
        "synthetic-trained.md",
    ]
    crop = (out / "synthetic-trained-crop-0_5.md").read_text()
    assert "**Protocol**: contexts cropped ShapeNet-55 style" in crop
    assert "`gauss[crop=0.5]`" in crop and "raw 512" in crop
    assert "No runs of the reference" not in crop  # gauss[crop=0.5] is the table's gauss
    depth = (out / "synthetic-trained-depth.md").read_text()
    assert "**Protocol**: contexts a simulated single-view depth scan" in depth
    sparse = (out / "synthetic-trained.md").read_text()
    assert "**Protocol**: contexts carry points only" in sparse
    assert "crop=0.5" not in sparse.split("Left out")[-1].split("| Method")[-1]

    # The report has a section per table, the protocol in its title.
    res = shapebench("report", "-d", "synthetic", "--out", str(out), "--reference", "gauss")
    assert res.returncode == 0, res.stdout + res.stderr
    page = (out / "synthetic-report.html").read_text()
    assert 'id="split-trained-crop-0_5"' in page and "synthetic / trained, crop-0.5:" in page

    bad = tmp_path / "bad.yaml"
    bad.write_text("methods: [gauss]\ndatasets: [synthetic]\nprotocol: crop\n")
    res = shapebench("sweep", str(bad))
    assert res.returncode == 2 and "needs a crop fraction" in res.stderr
