"""Bad input: one clear message (exit status 2), no traceback, nothing lost."""

from __future__ import annotations

import time

import pytest
from conftest import TINY, free_port

pytestmark = pytest.mark.slow  # every test runs the CLI in a subprocess


def _clean_error(res, *needles: str) -> None:
    assert res.returncode == 2, (res.stdout, res.stderr)
    assert "Traceback" not in res.stderr
    assert res.stderr.startswith("Error: ")
    for n in needles:
        assert n in res.stderr, res.stderr


def test_unknown_method_lists_available(shapebench):
    res = shapebench("run", "--method", "nope", "--dataset", "synthetic")
    _clean_error(
        res, "unknown method 'nope'", "available: convonet, deepsdf, files, gauss, igr, msc,"
    )


def test_unknown_dataset_lists_available(shapebench):
    res = shapebench("run", "--method", "gauss", "--dataset", "shapenet-typo")
    _clean_error(res, "unknown dataset 'shapenet-typo'", "synthetic")


def test_unknown_option_names_valid_ones(shapebench):
    res = shapebench("run", "-m", "gauss", "-d", "synthetic", "-O", "sigmaa=0.1")
    _clean_error(res, "sigmaa", "valid options: sigma")


def test_missing_data_root_names_the_path(shapebench, tmp_path):
    missing = tmp_path / "no-such-folder"
    res = shapebench("run", "-m", "gauss", "-d", "synthetic", "--data-root", str(missing))
    _clean_error(res, str(missing), "does not exist")


def test_context_larger_than_sampled_points_fails_before_any_work(shapebench, tmp_path):
    shapebench.cache = tmp_path / "untouched-cache"
    res = shapebench("run", "-m", "gauss", "-d", "synthetic", *TINY, "--contexts", "50,5000")
    _clean_error(res, "context size 5000", "3000 surface points")
    assert not shapebench.cache.exists()


def test_context_larger_than_visible_points_fails_before_any_run(shapebench):
    # 2999 of 3000 sampled points is more than any synthetic object shows to the viewpoints.
    res = shapebench("run", "-m", "gauss", "-d", "synthetic", *TINY, "--contexts", "50,2999")
    assert res.returncode == 2 and "Traceback" not in res.stderr
    assert "Error: context size 2999 is larger than the" in res.stderr
    assert "visible surface points of object" in res.stderr
    assert shapebench.cell_runs("synthetic-trained", status=None) == []


def test_unreachable_tracking_server_fails_fast_before_any_work(shapebench, tmp_path):
    uri = f"http://127.0.0.1:{free_port()}"
    shapebench.cache = tmp_path / "untouched-cache"
    start = time.monotonic()
    res = shapebench("run", "-m", "gauss", "-d", "synthetic", "--tracking-uri", uri)
    _clean_error(res, f"cannot reach the MLflow tracking server at {uri}")
    assert time.monotonic() - start < 30
    assert not shapebench.cache.exists()  # no dataset was generated


def test_bad_sweep_file_is_named(shapebench, tmp_path):
    bad = tmp_path / "bad.yaml"
    bad.write_text("methods: [gauss]\ndatasets: [synthetic]\ncontexts: [fifty]\n")
    _clean_error(shapebench("sweep", str(bad)), str(bad), "contexts")
    _clean_error(shapebench("sweep", str(tmp_path / "missing.yaml")), "not found")


def test_trainable_method_on_a_dataset_without_training_objects(shapebench, tmp_path):
    import trimesh

    root = tmp_path / "scans"
    root.mkdir()
    trimesh.creation.icosphere().export(root / "ball.obj")
    res = shapebench(
        "run",
        "-m",
        "igr",
        "-d",
        "meshes",
        "--data-root",
        str(root),
        "--contexts",
        "50",
        "-D",
        "surface_candidates=2000",
        "-D",
        "gt_points=1000",
    )
    _clean_error(res, "method 'igr' needs training", "has no training objects", "--checkpoint")


def test_a_profile_extends_another_and_states_only_what_differs(tmp_path, monkeypatch):
    from shapebench.api.errors import ConfigError
    from shapebench.config import load_profile

    profiles = tmp_path / "profiles"
    profiles.mkdir()
    (profiles / "bigger.yaml").write_text(
        "extends: quick\n"
        "datasets:\n  synthetic:\n    train_per_category: 200\n"
        "methods:\n  msc:\n    steps: 10800\n"
    )
    monkeypatch.setenv("SHAPEBENCH_CONFIG_DIR", str(tmp_path))
    quick, bigger = load_profile("quick"), load_profile("bigger")
    assert "extends" not in bigger
    assert bigger["datasets"]["synthetic"]["train_per_category"] == 200
    assert bigger["methods"]["msc"]["steps"] == 10800
    # Everything else is the extended profile's, key by key inside the mappings.
    assert bigger["methods"]["msc"]["latent_dim"] == quick["methods"]["msc"]["latent_dim"]
    synthetic = bigger["datasets"]["synthetic"]
    assert synthetic["gt_points"] == quick["datasets"]["synthetic"]["gt_points"]
    assert bigger["methods"]["igr"] == quick["methods"]["igr"]
    assert bigger["trainer"] == quick["trainer"]

    (profiles / "a.yaml").write_text("extends: b\n")
    (profiles / "b.yaml").write_text("extends: a\n")
    with pytest.raises(ConfigError, match=r"circle \(a -> b -> a\)"):
        load_profile("a")
