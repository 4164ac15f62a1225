"""Bad input from docs/bad-input.md not covered elsewhere: config files (syntax, keys, types),
mesh folders (flat, degenerate and unreadable meshes, files that are not meshes), a missing
optional dependency, a full disk and a tracking server that dies in the middle of a sweep. Each
ends in one clear line or a per-object failure naming the object, and loses nothing."""

from __future__ import annotations

import pytest
from conftest import TINY

pytestmark = pytest.mark.slow  # every test runs the CLI in a subprocess


def _clean_error(res, *needles: str) -> None:
    assert res.returncode == 2, (res.stdout, res.stderr)
    assert "Traceback" not in res.stderr, res.stderr
    assert res.stderr.startswith("Error: "), res.stderr
    for n in needles:
        assert n in res.stderr, res.stderr


def _sweep(tmp_path, text: str):
    path = tmp_path / "sweep.yaml"
    path.write_text(text)
    return path


# -- config files ------------------------------------------------------------------------------


def test_a_yaml_syntax_error_names_the_file_and_line(shapebench, tmp_path):
    bad = _sweep(tmp_path, "methods: [gauss]\ndatasets: [synthetic\ncontexts: [50]\n")
    res = shapebench("sweep", str(bad))
    _clean_error(res, f"config file {bad}, line 3, column 9 is not valid YAML")
    assert len(res.stderr.strip().splitlines()) <= 2, res.stderr  # the error and its hint

    # A user's profile, found through $SHAPEBENCH_CONFIG_DIR, is read the same way.
    profiles = tmp_path / "mine" / "profiles"
    profiles.mkdir(parents=True)
    (profiles / "broken.yaml").write_text("trainer:\n  max_steps: 10\n   accelerator: cpu\n")
    shapebench.extra_env = {"SHAPEBENCH_CONFIG_DIR": str(tmp_path / "mine")}
    res = shapebench("run", "-m", "gauss", "-d", "synthetic", *TINY, "--profile", "broken")
    _clean_error(res, f"config file {profiles / 'broken.yaml'}, line 3", "is not valid YAML")


def test_a_sweep_file_with_an_unknown_key_or_a_wrong_type_is_named(shapebench, tmp_path):
    bad = _sweep(tmp_path, "methods: [gauss]\ndatasets: [synthetic]\ncontext: [50]\n")
    _clean_error(shapebench("sweep", str(bad)), str(bad), "context")
    bad = _sweep(tmp_path, "methods: gauss\ndatasets: [synthetic]\nseeds: [0, true]\n")
    _clean_error(
        shapebench("sweep", str(bad)),
        f"{bad}: 'seeds' must be a non-empty list of ints, got [0, True]",
        "e.g. seeds: [0, 1, 2]",
    )
    bad = _sweep(tmp_path, "methods: gauss\ndatasets: [synthetic]\nframe: 1.5\n")
    _clean_error(shapebench("sweep", str(bad)), f"{bad}: 'frame' must be a str, got 1.5")


def test_a_sweep_naming_a_method_that_is_not_installed_fails_before_any_work(shapebench, tmp_path):
    bad = _sweep(tmp_path, "methods: [gauss, pointr-not-installed]\ndatasets: [synthetic]\n")
    res = shapebench("sweep", str(bad), "-q")
    _clean_error(res, "unknown method 'pointr-not-installed'", "available: ")
    assert shapebench.cell_runs("synthetic-trained", status=None) == []
