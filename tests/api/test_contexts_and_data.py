"""Contexts are nested, stored and identical across runs; the synthetic splits are sound."""

from __future__ import annotations

import numpy as np
import pytest
from shapebench_gauss.method import GaussDensification, GaussOptions
from shapebench_synthetic.dataset import SyntheticDataset, SyntheticOptions

from shapebench.api.contexts import ContextStore
from shapebench.api.errors import ConfigError
from shapebench.api.options import build, parse_assignments
from shapebench.api.types import NOVEL, TRAIN, TRAINED, Context, ObjectData, ObjectRef


def _data(n: int = 3000) -> ObjectData:
    rng = np.random.default_rng(0)
    pts = rng.normal(size=(n, 3)).astype(np.float32)
    return ObjectData(ObjectRef("cat/obj-1", "cat"), pts, pts, pts)


def test_contexts_are_nested_stored_and_reproducible(tmp_path):
    data = _data()
    store = ContextStore(tmp_path, "fingerprint-a")
    c50, c100, c1000 = (store.context(data, k, run_seed=0) for k in (50, 100, 1000))
    np.testing.assert_array_equal(c100.points[:50], c50.points)
    np.testing.assert_array_equal(c1000.points[:100], c100.points)
    assert len(np.unique(c1000.points, axis=0)) == 1000  # drawn without replacement
    assert list((tmp_path / "contexts-v1").glob("*.npy"))
    # A fresh store (another process, another run) reads the same points back.
    again = ContextStore(tmp_path, "fingerprint-a").context(data, 100, run_seed=0)
    np.testing.assert_array_equal(again.points, c100.points)
    # Another dataset version draws other points; another run seed keeps the points.
    other = ContextStore(tmp_path / "b", "fingerprint-b").context(data, 100, run_seed=0)
    assert not np.array_equal(other.points, c100.points)
    assert store.context(data, 100, run_seed=1).seed != c100.seed
    with pytest.raises(ValueError, match="exceeds the 3000 visible points"):
        store.context(data, 3001, run_seed=0)


def test_synthetic_splits_follow_the_paper(tmp_path):
    ds = SyntheticDataset(SyntheticOptions(test_per_category=2, train_per_category=3), tmp_path)
    cats = ds.categories()
    trained = {c.name for c in cats if c.split == TRAINED}
    novel = {c.name for c in cats if c.split == NOVEL}
    assert len(cats) >= 12 and trained and novel and not trained & novel
    train, test_trained, test_novel = (ds.objects(s) for s in (TRAIN, TRAINED, NOVEL))
    assert {o.category for o in train} == trained == {o.category for o in test_trained}
    assert {o.category for o in test_novel} == novel
    assert len(train) == 3 * len(trained) and len(test_novel) == 2 * len(novel)
    ids = [o.id for o in train + test_trained + test_novel]
    assert len(ids) == len(set(ids))  # no object in two splits
    a = ds.mesh(test_trained[0])
    b = SyntheticDataset(SyntheticOptions(), tmp_path).mesh(test_trained[0])
    np.testing.assert_array_equal(a.vertices, b.vertices)  # same seed, same object


def test_gauss_fills_up_to_n_points_around_the_context():
    pts = np.random.default_rng(1).normal(size=(50, 3)).astype(np.float32)
    ctx = Context(ObjectRef("a", "c"), pts, pts, seed=5)
    method = GaussDensification(GaussOptions(sigma=0.01))
    out = method.complete(ctx, 30_000)
    assert out.points.shape == (30_000, 3)
    np.testing.assert_array_equal(out.points, method.complete(ctx, 30_000).points)
    # Every sample lies near its context point: distances follow a chi(3) scaled by sigma.
    d = np.linalg.norm(out.points[:, None, :] - pts[None], axis=2).min(axis=1)
    assert np.isclose(np.sqrt((d**2).mean() / 3), 0.01, rtol=0.05)


def test_option_parsing_and_validation():
    assert parse_assignments(["sigma=0.02", "name=x", "flag=true"], "-O") == {
        "sigma": 0.02,
        "name": "x",
        "flag": True,
    }
    assert build(GaussOptions, {"sigma": 1}, "gauss").sigma == 1.0
    with pytest.raises(ConfigError, match="sigma"):
        build(GaussOptions, {"sigma": "wide"}, "gauss")
    with pytest.raises(ConfigError, match="expects KEY=VALUE"):
        parse_assignments(["sigma"], "-O")


def test_training_samples_are_cached_apart_and_leave_evaluation_data_alone(tmp_path):
    from shapebench.api.types import Supervision

    small = SyntheticOptions(
        test_per_category=1,
        train_per_category=1,
        surface_candidates=2000,
        gt_points=1000,
        sdf_samples=5000,
        complete_points=512,
    )
    ds = SyntheticDataset(small, tmp_path)
    ref = ds.objects(TRAIN)[0]
    data = ds.load(ref, need=frozenset({Supervision.SDF_SAMPLES, Supervision.COMPLETE_POINTS}))
    sdf = data.extra["sdf"]
    assert sdf.shape[1] == 4 and 4500 < len(sdf) <= 5000
    assert (sdf[:, 3] < 0).any() and (sdf[:, 3] > 0).any()  # both sides of the surface
    assert data.extra["complete_points"].shape == (512, 3)
    # The training sizes are not part of the evaluation data: same fingerprint, same contexts.
    bigger = SyntheticDataset(SyntheticOptions(**{**small.__dict__, "sdf_samples": 9000}), tmp_path)
    assert bigger.fingerprint() == ds.fingerprint()
    assert bigger.training_fingerprint() != ds.training_fingerprint()
    np.testing.assert_array_equal(bigger.load(ref).surface_points, data.surface_points)
