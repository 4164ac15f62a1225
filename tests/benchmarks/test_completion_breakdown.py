"""benchmarks/completion_breakdown.py: every stage of a completion is timed, exclusively, and the
method's code is left as it was."""

from __future__ import annotations

import math

import pytest
from conftest import load_benchmark

import shapebench.geometry.meshing as meshing
import shapebench.implicit.completion as completion

#: A small untrained IGR (its geometric initialisation is a sphere, so it meshes): a few latent
#: steps and a coarse grid, so that every stage runs in seconds.
SMALL = ["-O", "width=32", "-O", "depth=2", "-O", "latent_dim=8"]
SMALL += ["-O", "opt_steps=5", "-O", "mesh_resolution=24"]


def test_the_stages_of_one_completion_add_up_to_its_time(data_cache, capsys):
    bench = load_benchmark("completion_breakdown")
    originals = (meshing.extract_mesh, completion.optimise_latents, completion.sample_mesh_points)
    args = ["--rows", "igr", "--objects", "1", "--contexts", "50", "--profile", "quick"]
    [row] = bench.main([*args, "--untrained", "--cache-dir", str(data_cache), *SMALL])
    assert row.origin == "untrained" and row.failures == 0
    shares = row.shares()
    assert math.fsum(shares.values()) == pytest.approx(1.0)
    assert all(row.per_object(stage) >= 0.0 for stage in bench.STAGES)
    # each stage an IGR completion goes through was seen by its wrapper
    for stage in ("encoder/posterior", "latent optimisation", "field evaluations"):
        assert row.per_object(stage) > 0.0, stage
    for stage in ("marching cubes", "mesh components", "surface sampling", "scoring"):
        assert row.per_object(stage) > 0.0, stage
    assert row.per_object(None) == pytest.approx(math.fsum(map(row.per_object, bench.STAGES)))
    # the wrappers are gone: the modules hold their own functions again
    now = (meshing.extract_mesh, completion.optimise_latents, completion.sample_mesh_points)
    assert now == originals and completion.extract_mesh is meshing.extract_mesh
    out = capsys.readouterr().out
    assert (
        "igr (untrained; 1 objects x 1 sizes) opt_steps 5" in out and "latent optimisation" in out
    )


def test_a_row_without_a_shipped_reference_is_refused(data_cache):
    bench = load_benchmark("completion_breakdown")
    args = ["--rows", "igr", "--objects", "1", "--contexts", "50", "--profile", "quick"]
    with pytest.raises(SystemExit, match="no shipped reference checkpoint"):
        bench.main([*args, "--cache-dir", str(data_cache), *SMALL])
