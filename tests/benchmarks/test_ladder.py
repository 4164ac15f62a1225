"""Rung (a) of the sanity ladder (benchmarks/ladder.py) at toy size: a tiny IGR overfits one
synthetic training shape and then completes it far better than its untrained network does."""

from __future__ import annotations

import math

import pytest
from conftest import load_benchmark

pytestmark = pytest.mark.slow  # trains IGR for 150 steps


def test_rung_a_igr_learns_one_shape(data_cache):
    data = [
        "surface_candidates=3000",
        "gt_points=2000",
        "train_per_category=1",
        "test_per_category=1",
    ]
    net = [
        "latent_dim=8",
        "width=64",
        "depth=2",
        "surface_points=256",
        "mesh_resolution=32",
        "opt_steps=10",
    ]
    tiny = [a for d in data for a in ("-D", d)] + [a for o in net for a in ("-O", o)]
    ladder = load_benchmark("ladder")
    (result,) = ladder.main(
        [
            "-m",
            "igr",
            "--rungs",
            "a",
            "--steps",
            "150",
            "--category",
            "bottle",
            "--eval-objects",
            "1",
            "--accelerator",
            "cpu",
            "--cache-dir",
            str(data_cache),
            *tiny,
        ]
    )
    assert result.steps == 150 and result.failures == 0
    assert not math.isnan(result.trained)
    # The untrained decoder is a unit sphere, far from a bottle; a network that does not learn
    # stays there.
    assert result.trained <= 0.5 * result.initial
    assert result.trained < 10 * result.gauss  # and the trained one is in Gauss's league
    # the code training learned for the shape decodes to it as well
    assert result.trained_code <= 0.5 * result.initial
