"""``shapebench export`` (issue 60): the contexts a run completes, as files, the same each time."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import trimesh

from shapebench.api.contexts import ContextStore
from shapebench.api.errors import ConfigError, ShapebenchError
from shapebench.api.protocol import Protocol
from shapebench.config import make_settings
from shapebench.exchange.export import export_contexts
from shapebench.exchange.manifest import MANIFEST, read_manifest
from shapebench.registry.discovery import get_registry
from shapebench.registry.resolve import resolve_dataset

#: conftest.TINY as options: one test object per category, 2,000 ground-truth points.
TINY = {
    "test_per_category": 1,
    "train_per_category": 1,
    "surface_candidates": 3000,
    "gt_points": 2000,
}


def _dataset(tmp_path: Path, cache: Path, **more):
    settings = make_settings(f"sqlite:///{tmp_path}/m.db", cache, "quick", tmp_path)
    return resolve_dataset(get_registry(), "synthetic", settings, None, {**TINY, **more})


def _files(root: Path) -> dict[str, bytes]:
    return {p.relative_to(root).as_posix(): p.read_bytes() for p in root.rglob("*") if p.is_file()}


@pytest.mark.slow  # preprocesses the tiny benchmark's novel objects (shared cache)
def test_two_exports_are_byte_identical_and_hold_what_a_run_completes(tmp_path, data_cache):
    ds = _dataset(tmp_path, data_cache)
    protocol = Protocol(context_normals=True)
    one = export_contexts(ds, protocol, ["novel"], [100, 50], [1, 0], tmp_path / "a")
    export_contexts(ds, protocol, ["novel"], [50, 100], [0, 1], tmp_path / "b")
    a, b = _files(tmp_path / "a"), _files(tmp_path / "b")
    assert a == b  # same names, same bytes (sizes and seeds in any order)

    manifest = read_manifest(tmp_path / "a")
    refs = ds.objects("novel")
    assert manifest == one.manifest
    assert (manifest.contexts, manifest.seeds, manifest.splits) == ([50, 100], [0, 1], ["novel"])
    assert len(manifest.entries) == len(refs) * 2 * 2
    assert manifest.data_fingerprint == ds.data_fingerprint()
    assert manifest.fingerprint == ds.fingerprint()
    raw = json.loads(a[MANIFEST])
    assert raw["protocol"]["name"] == "sparse" and raw["protocol"]["context_normals"] is True
    assert raw["frame"]["name"] == "dataset"
    store = ContextStore(ds.cache_root, ds.data_fingerprint())
    for entry in manifest.entries:
        ref = next(r for r in refs if r.id == entry.object)
        ctx = store.context(ds.load(ref), entry.size, entry.seed, protocol=protocol)
        stem = f"novel/{ref.category}/{ref.id.replace('/', '__')}/n{entry.size}-s{entry.seed}"
        assert entry.context == f"contexts/{stem}.npy"
        assert entry.completion == f"completions/{stem}"
        points = np.load(tmp_path / "a" / entry.context)
        assert points.dtype == np.float32 and np.array_equal(points, ctx.points)
        assert np.array_equal(np.load(tmp_path / "a" / entry.normals), ctx.normals)
        assert entry.context_seed == ctx.seed
        assert entry.n_points == len(ds.load(ref).gt_points)
        ply = trimesh.load(tmp_path / "a" / f"contexts/{stem}.ply", process=False)
        assert np.array_equal(np.asarray(ply.vertices, dtype=np.float32), ctx.points)
    # The sizes are nested, as in a run: the 50 points are the first 50 of the 100.
    first = manifest.entries[0]
    small = np.load(tmp_path / "a" / first.context)
    large = np.load(tmp_path / "a" / first.context.replace("n50-", "n100-"))
    assert np.array_equal(large[:50], small)
    assert (tmp_path / "a" / "completions").is_dir()


@pytest.mark.slow  # preprocesses the tiny benchmark's novel objects (shared cache)
def test_crop_contexts_are_exported_as_the_protocol_draws_them(tmp_path, data_cache):
    ds = _dataset(tmp_path, data_cache)
    crop = Protocol(context="crop", crop_fraction=0.5, context_noise=0.005)
    report = export_contexts(ds, crop, ["novel"], [50], [0], tmp_path / "crop")
    store = ContextStore(ds.cache_root, ds.data_fingerprint())
    entry = report.manifest.entries[0]
    ref = next(r for r in ds.objects("novel") if r.id == entry.object)
    ctx = store.context(ds.load(ref), 50, 0, protocol=crop)
    assert np.array_equal(np.load(tmp_path / "crop" / entry.context), ctx.points)
    assert read_manifest(tmp_path / "crop").protocol == crop


@pytest.mark.slow  # preprocesses the tiny benchmark's novel objects (shared cache)
def test_impossible_requests_are_refused_before_anything_is_written(tmp_path, data_cache):
    ds = _dataset(tmp_path, data_cache)
    with pytest.raises(ShapebenchError, match="has no evaluation split train"):
        export_contexts(ds, Protocol(), ["train"], [50], [0], tmp_path / "x")
    with pytest.raises(ShapebenchError, match="context size 5000 exceeds the"):
        export_contexts(ds, Protocol(), ["novel"], [5000], [0], tmp_path / "x")
    assert not (tmp_path / "x").exists()


def test_a_folder_without_a_manifest_or_with_a_damaged_one_is_one_line(tmp_path):
    with pytest.raises(ConfigError, match="manifest.json does not exist"):
        read_manifest(tmp_path)
    (tmp_path / MANIFEST).write_text("{not json")
    with pytest.raises(ConfigError, match="cannot be read as JSON"):
        read_manifest(tmp_path)
    (tmp_path / MANIFEST).write_text(json.dumps({"format": "something-else"}))
    with pytest.raises(ConfigError, match="is not a shapebench export manifest"):
        read_manifest(tmp_path)
