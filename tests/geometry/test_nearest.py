"""The CPU nearest-neighbour paths give the same distances to the last bit.

Committed leaderboards are reproduced from a fresh clone, with pykdtree installed or not, so
``shapebench.geometry.nearest``'s pykdtree path must return exactly what scipy's cKDTree returns
(and both exactly what the distance formula gives: the three squared coordinate differences
summed in order, then the square root), on ordinary clouds and on degenerate ones. Inputs that
pykdtree does not handle like cKDTree (an empty reference, NaN or infinite coordinates) go to
cKDTree, so they behave as before.
"""

from __future__ import annotations

import pickle
import subprocess
import sys

import numpy as np
import pytest
import torch
from conftest import load_benchmark
from scipy.spatial import cKDTree

from shapebench.geometry import nearest
from shapebench.geometry.nearest import (
    PointTree,
    brute_force_nearest,
    kdtree,
    nearest_distances,
    torch_nearest,
)

needs_pykdtree = pytest.mark.skipif(
    nearest.DEFAULT_BACKEND != "pykdtree", reason="pykdtree is not installed"
)


def exact_nearest(query: np.ndarray, reference: np.ndarray) -> np.ndarray:
    """The distance formula both KD-trees evaluate, on every pair: a bitwise reference."""
    q = np.asarray(query, dtype=np.float64)[:, None, :]
    r = np.asarray(reference, dtype=np.float64)[None, :, :]
    d = q - r
    squared = d[..., 0] * d[..., 0] + d[..., 1] * d[..., 1] + d[..., 2] * d[..., 2]
    return np.sqrt(squared.min(axis=1))


def both_paths(query: np.ndarray, reference: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    fast = kdtree(reference, backend="pykdtree").distances(query)
    scipy = kdtree(reference, backend="scipy").distances(query)
    return fast, scipy


def surface(n: int, rng: np.random.Generator, noise: float = 0.0) -> np.ndarray:
    """Float32 points near a unit sphere, as completions and ground truths are stored."""
    d = rng.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    return (d + rng.normal(scale=noise, size=d.shape)).astype(np.float32)


def grid(n_side: int, spacing: float = 0.1) -> np.ndarray:
    ax = np.arange(n_side) * spacing
    return np.stack(np.meshgrid(ax, ax, ax, indexing="ij"), axis=-1).reshape(-1, 3)


RANDOM_CASES = {
    "normal": lambda rng: (rng.normal(size=(2000, 3)), rng.normal(size=(1500, 3))),
    "surfaces": lambda rng: (surface(2000, rng), surface(1800, rng, noise=0.005)),
    "far from origin": lambda rng: (
        rng.uniform(size=(1000, 3)) + 1e4,
        rng.uniform(size=(1200, 3)) + 1e4,
    ),
}


@needs_pykdtree
@pytest.mark.parametrize("seed", [0, 1, 2])
@pytest.mark.parametrize("case", sorted(RANDOM_CASES))
def test_pykdtree_equals_ckdtree_equals_brute_force(case: str, seed: int) -> None:
    query, reference = RANDOM_CASES[case](np.random.default_rng(seed))
    fast, scipy = both_paths(query, reference)
    assert fast.dtype == scipy.dtype == np.float64
    np.testing.assert_array_equal(fast, scipy)
    np.testing.assert_array_equal(fast, exact_nearest(query, reference))
    if case != "far from origin":  # there |q|^2 + |r|^2 - 2 q.r cancels to ~1e-3 relative
        # The matrix-product form of torch.cdist is only close.
        bf = brute_force_nearest(query, reference)
        np.testing.assert_allclose(fast, bf, rtol=1e-9, atol=1e-6)


def duplicates(rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Each reference point 15 times; the query holds them all (distance exactly 0) and others."""
    reference = np.repeat(rng.normal(size=(20, 3)), 15, axis=0)
    return np.concatenate([reference, rng.normal(size=(50, 3))]), reference


DEGENERATE_CASES = {
    "duplicates": duplicates,
    "single reference point": lambda rng: (rng.normal(size=(300, 3)), rng.normal(size=(1, 3))),
    "single query point": lambda rng: (rng.normal(size=(1, 3)), rng.normal(size=(300, 3))),
    "all reference points equal": lambda rng: (rng.normal(size=(200, 3)), np.ones((40, 3))),
    # Every query point equidistant from 2, 4 or 8 grid points: ties everywhere.
    "ties on a grid": lambda rng: (grid(6) + 0.05, grid(7)),
    "empty query": lambda rng: (np.zeros((0, 3)), rng.normal(size=(100, 3))),
}


@needs_pykdtree
@pytest.mark.parametrize("case", sorted(DEGENERATE_CASES))
def test_paths_agree_on_degenerate_inputs(case: str) -> None:
    query, reference = DEGENERATE_CASES[case](np.random.default_rng(3))
    fast, scipy = both_paths(query, reference)
    assert fast.shape == scipy.shape == (len(query),)
    np.testing.assert_array_equal(fast, scipy)
    np.testing.assert_array_equal(fast, exact_nearest(query, reference))
    if len(query):
        bf = brute_force_nearest(query, reference)
        np.testing.assert_allclose(fast, bf, rtol=1e-9, atol=1e-6)


def test_duplicates_are_at_distance_zero() -> None:
    rng = np.random.default_rng(4)
    reference = np.repeat(rng.normal(size=(10, 3)), 5, axis=0)
    assert not nearest_distances(reference[::-1], reference).any()


@pytest.mark.parametrize("backend", ["pykdtree", "scipy"])
def test_empty_reference_gives_inf_as_ckdtree(backend: str) -> None:
    if backend == "pykdtree" and nearest.DEFAULT_BACKEND != "pykdtree":
        pytest.skip("pykdtree is not installed")
    out = kdtree(np.zeros((0, 3)), backend=backend).distances(np.ones((4, 3)))
    np.testing.assert_array_equal(out, cKDTree(np.zeros((0, 3))).query(np.ones((4, 3)))[0])
    assert np.isinf(out).all()


@pytest.mark.parametrize("where", ["query", "reference"])
@pytest.mark.parametrize("bad", [np.nan, np.inf])
def test_non_finite_points_raise_as_ckdtree(where: str, bad: float) -> None:
    """pykdtree would return numbers for these; cKDTree refuses them, and so do we."""
    rng = np.random.default_rng(5)
    query, reference = rng.normal(size=(30, 3)), rng.normal(size=(20, 3))
    (query if where == "query" else reference)[3, 1] = bad
    with pytest.raises(ValueError, match="finite"):
        nearest_distances(query, reference)


def test_inputs_of_other_layouts_and_types() -> None:
    """float32, non-contiguous, Fortran-ordered and CPU tensors: the float64 values."""
    rng = np.random.default_rng(6)
    query, reference = surface(900, rng), surface(700, rng, noise=0.01)
    expected = exact_nearest(query, reference)
    for q, r in [
        (query, reference),
        (np.asfortranarray(query), reference[::-1]),
        (torch.from_numpy(query), torch.from_numpy(reference).double()),
    ]:
        np.testing.assert_array_equal(nearest_distances(q, r), expected)


def test_given_tree_is_used_and_equal() -> None:
    rng = np.random.default_rng(7)
    query, reference = rng.normal(size=(400, 3)), rng.normal(size=(300, 3))
    without = nearest_distances(query, reference)
    for tree in (kdtree(reference), cKDTree(reference), kdtree(reference, backend="scipy")):
        np.testing.assert_array_equal(
            nearest_distances(query, np.empty((0, 3)), tree=tree), without
        )


def test_query_is_ckdtree_query() -> None:
    """``PointTree.query`` (k neighbours and indices, preprocess/samples.py) is cKDTree's."""
    rng = np.random.default_rng(8)
    query, reference = rng.normal(size=(500, 3)), rng.normal(size=(400, 3))
    dist, idx = kdtree(reference).query(query, k=8, workers=-1)
    want_dist, want_idx = cKDTree(reference).query(query, k=8, workers=-1)
    np.testing.assert_array_equal(dist, want_dist)
    np.testing.assert_array_equal(idx, want_idx)


@pytest.mark.parametrize("backend", nearest.BACKENDS)
def test_indices_name_the_point_at_the_nearest_distance(backend: str) -> None:
    """``PointTree.indices`` (the training losses' pairs) comes from the search that gives
    ``distances``, and the brute force on tensors (their GPU path) finds the same points."""
    if backend == "pykdtree" and nearest.DEFAULT_BACKEND != "pykdtree":
        pytest.skip("pykdtree is not installed")
    rng = np.random.default_rng(10)
    query, reference = surface(700, rng), surface(900, rng, noise=0.01)
    tree = kdtree(reference, backend=backend)
    index = tree.indices(query)
    assert index.dtype == np.int64 and index.shape == (700,)
    gap = query.astype(np.float64) - reference.astype(np.float64)[index]
    np.testing.assert_array_equal(np.sqrt((gap * gap).sum(axis=1)), tree.distances(query))
    np.testing.assert_array_equal(index, kdtree(reference, backend="scipy").indices(query))
    dist, brute = torch_nearest(torch.from_numpy(query), torch.from_numpy(reference), chunk=128)
    np.testing.assert_array_equal(brute.numpy(), index)  # no ties among random points
    np.testing.assert_allclose(dist.numpy(), tree.distances(query), rtol=1e-6, atol=1e-7)


def test_tree_pickles_and_builds_each_kind_once() -> None:
    rng = np.random.default_rng(9)
    query, reference = rng.normal(size=(200, 3)), rng.normal(size=(150, 3))
    tree = kdtree(reference)
    first = tree.distances(query)
    fast, scipy = tree._fast, tree._scipy
    np.testing.assert_array_equal(tree.distances(query), first)
    assert tree._fast is fast and tree._scipy is scipy  # built once, not per query
    copy = pickle.loads(pickle.dumps(tree))
    np.testing.assert_array_equal(copy.distances(query), first)
    np.testing.assert_array_equal(copy.data, reference)


def test_unknown_backend_is_refused() -> None:
    with pytest.raises(ValueError, match="backend"):
        PointTree(np.zeros((3, 3)), backend="faiss")


def test_without_pykdtree_falls_back_to_ckdtree() -> None:
    """An install without pykdtree imports, uses cKDTree and gets the same distances."""
    code = (
        "import sys; sys.modules['pykdtree'] = None\n"
        "import numpy as np\n"
        "from shapebench.geometry import nearest\n"
        "assert nearest.DEFAULT_BACKEND == 'scipy', nearest.DEFAULT_BACKEND\n"
        "rng = np.random.default_rng(0)\n"
        "q, r = rng.normal(size=(50, 3)), rng.normal(size=(40, 3))\n"
        "sys.stdout.write(nearest.nearest_distances(q, r).tobytes().hex())\n"
    )
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert res.returncode == 0, res.stderr
    rng = np.random.default_rng(0)
    q, r = rng.normal(size=(50, 3)), rng.normal(size=(40, 3))
    assert bytes.fromhex(res.stdout) == nearest_distances(q, r).tobytes()


def test_bench_chamfer_runs_and_checks_bitwise_equality(capsys: pytest.CaptureFixture) -> None:
    bench = load_benchmark("bench_chamfer")
    bench.main(["--points", "400", "--repeat", "1", "--brute-repeat", "1"])
    out = capsys.readouterr().out
    assert "bitwise identical to cKDTree's: yes" in out
